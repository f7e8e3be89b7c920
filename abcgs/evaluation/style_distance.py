"""Gram-matrix style distance between stylized renders and the painting(s) (Gatys et al. 2016).

For VGG-16 taps ``l`` (default relu1_2, relu2_2, relu3_3) with features ``F_l`` ``(C_l, N_l)``, the Gram
matrix is ``G_l = F_l F_lᵀ / N_l`` (normalised by the number of positions, so images of different sizes
compare). The distance of one render is the mean over taps of the relative Frobenius error

    d = mean_l ‖G_l(render) − G_l(style)‖_F / ‖G_l(style)‖_F

and the reported ``gram_distance`` is its mean over renders. 0 means the render has the painting's
second-order feature statistics; a photo of a different scene is typically 0.5–0.8 from a painting.
Renders are downsampled ×0.5 first and paintings are used at the stylization's style height (256), i.e.
both at the scale the style losses see them. Several style images (compositional transfer) pool their
positions into one Gram matrix. Relative errors make the number independent of the VGG weights'
activation scale (``feature_scale``), so it compares across weight sources better than an absolute Gram loss.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from abcgs.errors import InputError
from abcgs.evaluation.content import nan_mean
from abcgs.evaluation.parallel import ordered_map
from abcgs.features.isolation import downsample_mask
from abcgs.features.matching import resize_to_height
from abcgs.features.vgg import VGG16Features, downsample_half

GRAM_LAYERS = ("relu1_2", "relu2_2", "relu3_3")
GRAM_DEFINITION = "mean over renders and taps of ||G(render) - G(style)||_F / ||G(style)||_F, G = F F^T / N"


def _bchw(img: np.ndarray) -> torch.Tensor:
    a = np.asarray(img, np.float32)
    if a.ndim != 3 or a.shape[2] != 3:
        raise InputError(f"expected an (H, W, 3) RGB image, got shape {a.shape}")
    return torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)[None].clamp(0, 1)


def _gram_sum(f: torch.Tensor) -> tuple[torch.Tensor, int]:
    """``(1, C, h, w)`` features → unnormalised Gram ``F Fᵀ`` ``(C, C)`` in float64 and the position count ``h·w``."""
    f2 = f[0].reshape(f.shape[1], -1).double()
    return f2 @ f2.t(), f2.shape[1]


class GramDistance:
    """``gram_distance(renders)`` against fixed style image(s); see the module docstring.

    Args:
        vgg_state: torchvision-layout VGG-16 state dict. style_images: ``(H, W, 3)`` float RGB in [0, 1],
            already at the scale to compare (the pipeline's style height). layers: VGG taps.
        downsample_renders: halve renders before VGG (as the stylization losses do).
    """

    def __init__(self, vgg_state: dict, style_images: Sequence[np.ndarray], layers: Sequence[str] = GRAM_LAYERS, *,
                 downsample_renders: bool = True, device: torch.device | str = "cpu") -> None:
        if not style_images:
            raise InputError("Gram distance needs at least one style image")
        self.layers = tuple(layers)
        self.downsample = downsample_renders
        self.device = torch.device(device)
        self._vgg = VGG16Features(vgg_state, self.layers).to(self.device)
        with torch.no_grad():
            sums = {k: None for k in self.layers}
            counts = dict.fromkeys(self.layers, 0)
            for img in style_images:
                for k, f in self._vgg(_bchw(img).to(self.device)).items():
                    g, n = _gram_sum(f)
                    sums[k] = g if sums[k] is None else sums[k] + g
                    counts[k] += n
            self._style = {k: sums[k] / counts[k] for k in self.layers}

    @torch.no_grad()
    def per_image(self, img: np.ndarray) -> float:
        x = _bchw(img).to(self.device)
        if self.downsample:
            x = downsample_half(x)
        d = []
        for k, f in self._vgg(x).items():
            g, n = _gram_sum(f)
            g = g / n
            d.append(float((g - self._style[k]).norm() / self._style[k].norm()))
        return float(np.mean(d))

    @torch.no_grad()
    def per_region(self, img: np.ndarray, mask: np.ndarray) -> float:
        """:meth:`per_image` over the positions of ``mask`` ``(H, W)`` bool only (the render's part a painting styles,
        at each tap's resolution: :func:`abcgs.features.isolation.downsample_mask`); nan for an empty mask."""
        if not np.any(mask):
            return float("nan")
        x = _bchw(img).to(self.device)
        if self.downsample:
            x = downsample_half(x)
        d = []
        for k, f in self._vgg(x).items():
            cells = downsample_mask(np.asarray(mask, bool), tuple(f.shape[-2:])).to(self.device)
            cols = f[0][:, cells].double()
            g = cols @ cols.t() / cols.shape[1]
            d.append(float((g - self._style[k]).norm() / self._style[k].norm()))
        return float(np.mean(d))

    def __call__(self, renders: Sequence[np.ndarray]) -> float:
        if not renders:
            raise InputError("Gram distance: no renders")
        return float(np.mean([self.per_image(r) for r in renders]))

    @property
    def info(self) -> dict:
        return {"name": "gram_distance", "layers": list(self.layers), "downsample_renders": self.downsample,
                "definition": GRAM_DEFINITION}


@dataclass(frozen=True)
class GramScores:
    """The Gram style distance of each stylized render to the style image(s) (module docstring)."""

    per_view: tuple[float, ...]
    """``(n_views,)`` relative Gram distance per render, >= 0 (unitless; 0 = the painting's statistics)."""
    layers: tuple[str, ...]
    """The VGG-16 taps compared."""
    downsample_renders: bool
    """Renders were halved before VGG (as the stylization losses see them)."""
    style_height: int
    """Height in px the style images were resized to."""

    @property
    def mean(self) -> float:
        """``gram_distance``: the mean over the renders (NaNs left out)."""
        return nan_mean(self.per_view)


def gram_scores(vgg_state: dict, stylized: Sequence[np.ndarray], style_images: Sequence[np.ndarray],
                layers: Sequence[str] = GRAM_LAYERS, style_height: int = 256, *, workers: int = 1,
                device: torch.device | str = "cpu") -> GramScores:
    """:class:`GramDistance` of every stylized render to ``style_images`` resized to ``style_height``, on ``workers``
    threads (the same numbers for any count)."""
    gram = GramDistance(vgg_state, [resize_to_height(s, style_height) for s in style_images], layers, device=device)
    return GramScores(tuple(ordered_map(gram.per_image, list(stylized), workers)), gram.layers, gram.downsample,
                      style_height)
