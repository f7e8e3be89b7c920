"""The per-view targets of the style pass: each view's content features (of the colour-matched render), the
original scene's depth, the per-group feature masks and, for an object scene, its silhouette and backdrop.

Shapes: renders ``(H, W, 3)``; VGG features ``(C, h, w)`` at 1/4 of the (×0.5 downsampled) render;
per-group features ``(C, N)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from abcgs.cameras import Camera
from abcgs.features.isolation import downsample_mask
from abcgs.features.params import ALL_PIXELS
from abcgs.features.vgg import VGG16Features, downsample_half, extract_features
from abcgs.gaussians import GaussianModel, render_each
from abcgs.silhouette import Silhouette, background_tensor
from abcgs.stylize.params import StylizeParams
from abcgs.types import Background, MatchingGroup


@dataclass
class ViewTargets:
    """Per-view fixed targets: content features, original depth, per-group feature masks."""

    camera: Camera
    content_feats: Tensor  # (C, h, w)
    depth: Tensor  # (H, W, 1)
    group_masks: list[Tensor] = field(default_factory=list)  # per group (h, w) bool; object pixels only (object scene)
    content_image: Tensor | None = None  # (H, W, 3) the colour-matched render
    silhouette: Silhouette | None = None  # object scenes: the original scene's alpha in this view


@dataclass(frozen=True)
class Backdrop:
    """How the loop composites and what it holds: the scene's :class:`~abcgs.types.Background`, as a tensor.

    ``color`` ``(3,)`` is composited behind every render of an object scene; ``None`` for a frame-filling scene,
    which renders as it always has (on black, no silhouette or background terms). ``gaussians`` ``(N,)`` bool: an
    object scene's object (:func:`abcgs.silhouette.object_gaussians`), the only Gaussians that change."""

    color: Tensor | None
    gaussians: Tensor | None = None

    @classmethod
    def of(cls, background: Background, device: torch.device) -> Backdrop:
        return cls(background_tensor(background).to(device) if background.object else None)

    @property
    def object(self) -> bool:
        return self.color is not None


def group_pixel_masks(groups: list[MatchingGroup], label_map: np.ndarray) -> list[np.ndarray]:
    """Per group, the ``(H, W)`` bool pixels it covers in one view's (rendered) label map."""
    return [np.ones_like(label_map, bool) if g.content_label == ALL_PIXELS else label_map == g.content_label for g in groups]


def view_features(vgg: VGG16Features, img_hw3: Tensor, params: StylizeParams) -> Tensor:
    x = img_hw3.permute(2, 0, 1)[None]
    if params.downsample_render:
        x = downsample_half(x)
    return extract_features(vgg, x, params.layers)[0]


def prepare_targets(
    model_content: GaussianModel,
    model_original: GaussianModel,
    cameras: list[Camera],
    label_maps: list[np.ndarray],
    groups: list[MatchingGroup],
    vgg: VGG16Features,
    params: StylizeParams,
    backdrop: Backdrop = Backdrop(None),
) -> list[ViewTargets]:
    """Content features (from the colour-matched scene), depth (from the original scene), group masks; for an object
    scene (``backdrop``) also the original scene's silhouette, and the group masks keep its object pixels only."""
    targets = []
    backend = params.compute.backend
    with torch.no_grad():
        # one render gives both when the depth comes from the content scene itself
        same = model_original is model_content
        contents = render_each(model_content, cameras, backend=backend, background=backdrop.color,
                               render_mode="RGB+D" if same else "RGB")
        originals = None if same else render_each(model_original, cameras, backend=backend, render_mode="RGB+D")
        for cam, lab, (img, alpha, meta) in zip(cameras, label_maps, contents):
            if originals is not None:
                _, alpha, meta = next(originals)
            feats = view_features(vgg, img.clamp(0, 1), params)
            hw = tuple(feats.shape[-2:])
            pixel_masks = group_pixel_masks(groups, lab)
            sil = None
            if backdrop.object:
                sil = Silhouette(alpha.float())
                on_object = sil.object.numpy(force=True)
                pixel_masks = [m & on_object for m in pixel_masks]
            masks = [downsample_mask(m, hw).to(feats.device) if m.any() else torch.zeros(hw, dtype=torch.bool, device=feats.device)
                     for m in pixel_masks]
            targets.append(ViewTargets(cam, feats, meta.depth, masks, img, sil))
    return targets


def group_features(feats: Tensor, mask: Tensor) -> Tensor:
    """The ``(C, n)`` columns of ``feats`` ``(C, h, w)`` under ``mask`` ``(h, w)`` bool, in row-major order: a view of
    all columns when the mask covers every cell (single-image transfer), so that neither the forward nor the backward
    copies the features through the mask."""
    return feats.flatten(1) if bool(mask.all()) else feats[:, mask]
