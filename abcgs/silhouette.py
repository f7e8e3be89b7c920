"""Where an object scene's object is: the original scene's own alpha, rendered per view.

A scene whose :class:`~abcgs.types.Background` says ``object`` is a thing on nothing (a bare splat, NeRF-synthetic RGBA
views, a capture with masks). Its original Gaussians, rendered into a view, cover the object and leave the rest
empty; that alpha ``α_ref`` decides, per pixel, what the colour match, the stylization and the evaluation act on:

- **object** pixels, ``α_ref ≥`` :data:`OBJECT_ALPHA`: the colour statistics, the style loss's features and the
  object metrics are taken there;
- **empty** pixels, ``α_ref <`` :data:`EMPTY_ALPHA`: the render must keep the background there
  (:func:`abcgs.losses.terms.background_loss`) and the evaluation counts those that moved;
- the silhouette, all of ``α_ref``, is held by :func:`abcgs.losses.terms.silhouette_loss`;
- the object's Gaussians are those whose blending weight falls mostly on object pixels (:func:`object_gaussians`);
  only they are recoloured and stylized, the rest (faint haze, floaters) stay exactly as they were.

A frame-filling scene has every pixel covered, so these masks select everything and nothing changes for it; the
stages still take the frame-filling path for such scenes (``object`` false) so that their numbers stay bit-identical.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from abcgs.cameras import Camera
from abcgs.gaussians import GaussianModel, render
from abcgs.render import accumulate_weights
from abcgs.types import Backend, Background

OBJECT_ALPHA = 0.5
"""A pixel whose original alpha is at least this is on the object."""
EMPTY_ALPHA = 0.02
"""A pixel whose original alpha is below this is empty space (the background shows through unchanged)."""


@dataclass(frozen=True)
class Silhouette:
    """One view's original alpha and the masks it gives.

    Attributes:
        alpha: ``(H, W, 1) float32`` the original scene's alpha in ``[0, 1]``.
    """

    alpha: Tensor

    @property
    def object(self) -> Tensor:
        """``(H, W)`` bool: object pixels (:data:`OBJECT_ALPHA`)."""
        return self.alpha[..., 0] >= OBJECT_ALPHA

    @property
    def empty(self) -> Tensor:
        """``(H, W)`` bool: empty pixels (:data:`EMPTY_ALPHA`)."""
        return self.alpha[..., 0] < EMPTY_ALPHA


def background_tensor(background: Background, like: Tensor | None = None) -> Tensor:
    """``(3,) float32`` the background colour, on ``like``'s device."""
    return torch.tensor(background.color, dtype=torch.float32, device=None if like is None else like.device)


@torch.no_grad()
def silhouettes(model: GaussianModel, cameras: Sequence[Camera], backend: Backend = "auto") -> list[Silhouette]:
    """The original scene ``model``'s alpha in each of ``cameras``."""
    return [Silhouette(render(model, cam, backend=backend)[1].float()) for cam in cameras]


def composite_rgba(image: np.ndarray, alpha: np.ndarray, background: Background) -> np.ndarray:
    """What a render is written as: ``(H, W, 4)`` straight-alpha RGBA for a transparent background (``image`` was
    composited on black: colour = image / alpha), else ``image`` ``(H, W, 3)`` as it is (composited on the colour)."""
    if not background.transparent:
        return image
    a = np.clip(alpha.reshape(image.shape[:2] + (1,)), 0.0, 1.0)
    rgb = np.where(a > 1e-6, image / np.maximum(a, 1e-6), 0.0)
    return np.concatenate([np.clip(rgb, 0.0, 1.0), a], axis=-1).astype(np.float32)


def unpremultiply(image: Tensor, alpha: Tensor, background: Tensor) -> Tensor:
    """The object's own colour ``(H, W, 3)`` in ``[0, 1]`` under a render ``image`` ``(H, W, 3)`` composited on
    ``background`` ``(3,)`` with alpha ``(H, W, 1)``: ``(image − (1 − α)·background) / α`` (the background itself
    where ``α`` is below :data:`EMPTY_ALPHA`)."""
    a = alpha.clamp(0.0, 1.0)
    fg = (image - (1.0 - a) * background) / a.clamp_min(EMPTY_ALPHA)
    return torch.where(a >= EMPTY_ALPHA, fg.clamp(0.0, 1.0), background.expand_as(image))


def over(color: Tensor, alpha: Tensor, background: Tensor) -> Tensor:
    """``α·color + (1 − α)·background``: an object's colour ``(H, W, 3)`` with alpha ``(H, W, 1)`` on ``background``."""
    a = alpha.clamp(0.0, 1.0)
    return a * color + (1.0 - a) * background


WEIGHT_RAMP = (0.25, 0.75)
"""Original alphas over which a pixel's colour turns from the background's to the object's (:func:`object_weight`)."""


def object_weight(alpha: Tensor) -> Tensor:
    """How much a pixel's colour is the object's, from the original alpha ``(H, W, 1)``: 0 below
    ``WEIGHT_RAMP[0]``, 1 from ``WEIGHT_RAMP[1]``, linear between. A scene fitted on a plain background holds faint
    haze of that colour around the object (invisible there, alpha 0.1–0.5); it is left as it is, not recoloured
    into a visible fog."""
    lo, hi = WEIGHT_RAMP
    return ((alpha - lo) / (hi - lo)).clamp(0.0, 1.0)


@torch.no_grad()
def object_gaussians(model: GaussianModel, cameras: Sequence[Camera], views: Sequence[Silhouette],
                     backend: Backend = "auto") -> Tensor:
    """``(N,)`` bool: the Gaussians of the object. The object pixels of every view are lifted onto the Gaussians as
    content masks are (ABC-GS Eq. 2, :func:`abcgs.render.accumulate_weights`): a Gaussian is on the object when at
    least half of its blending weight over all views falls on object pixels, or when no view sees it (inside the
    object). The others (haze, floaters, what renders only at the faint edge) are kept as they are by the colour
    match and the stylization of an object scene."""
    on = torch.zeros(model.num_gaussians, dtype=torch.float32, device=model.device)
    total = torch.zeros_like(on)
    for cam, sil in zip(cameras, views):
        maps = torch.stack([sil.object.float(), torch.ones_like(sil.alpha[..., 0])], dim=-1).to(model.device)
        w = accumulate_weights(model.means, model.quats, model.scales, model.opacities, cam.torch_viewmat(model.device),
                               cam.torch_K(model.device), maps, backend=backend)
        on += w[:, 0]
        total += w[:, 1]
    return (on >= 0.5 * total) | (total <= 1e-8)
