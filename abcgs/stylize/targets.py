"""The per-view targets of the style pass: each view's content features (of the colour-matched render), the
original scene's depth, the per-group feature masks, the λ maps of the content labels that have their own (an
experiment's ``content_weights`` / ``structure_weights``: :class:`LabelWeights`) and, for an object scene, its
silhouette and backdrop.

Shapes: renders ``(H, W, 3)``; VGG features ``(C, h, w)`` at 1/4 of the (×0.5 downsampled) render;
per-group features ``(C, N)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F
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
    content_weight: Tensor | None = None  # (h, w) λ_c per feature cell; None: stylize.weights.content everywhere
    structure_weight: Tensor | None = None  # (H, W) λ_st per pixel; None: stylize.weights.structure everywhere


@dataclass(frozen=True)
class LabelWeights:
    """The λ of the content and structure terms that content labels have of their own (``experiments.<name>``:
    ``content_weights``, ``structure_weights``); every other pixel keeps ``stylize.weights``'. Empty: one λ each."""

    content: Mapping[int, float] = field(default_factory=dict)
    structure: Mapping[int, float] = field(default_factory=dict)

    def pixel_map(self, term: str, default: float, label_map: np.ndarray) -> np.ndarray | None:
        """``(H, W)`` float32 λ of ``term`` (``content`` or ``structure``) per pixel of one view's ``label_map``:
        ``default`` but on the labels with their own; ``None`` when no label has one."""
        own = getattr(self, term)
        if not own:
            return None
        lam = np.full(label_map.shape, default, np.float32)
        for label, value in own.items():
            lam[label_map == label] = value
        return lam

    def maps(self, defaults: Mapping[str, float], label_map: np.ndarray, feature_hw: tuple[int, int],
             device: torch.device) -> tuple[Tensor | None, Tensor | None]:
        """One view's λ maps: content at the feature cells ``feature_hw`` (each cell the mean λ of its pixels, area
        interpolation) and structure per pixel; ``None`` for a term no label has its own λ of."""
        content = self.pixel_map("content", defaults["content"], label_map)
        structure = self.pixel_map("structure", defaults["structure"], label_map)
        if content is not None:
            content = F.interpolate(torch.from_numpy(content)[None, None], size=feature_hw, mode="area")[0, 0]
            content = content.to(device)
        return content, None if structure is None else torch.from_numpy(structure).to(device)


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
    label_weights: LabelWeights = LabelWeights(),  # noqa: B008 (a frozen dataclass)
) -> list[ViewTargets]:
    """Content features (from the colour-matched scene), depth (from the original scene), group masks, the λ maps of
    ``label_weights``; for an object scene (``backdrop``) also the original scene's silhouette, and the group masks
    keep its object pixels only."""
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
            lam_c, lam_st = label_weights.maps(params.weights.model_dump(), lab, hw, feats.device)
            targets.append(ViewTargets(cam, feats, meta.depth, masks, img, sil, lam_c, lam_st))
    return targets


def group_features(feats: Tensor, mask: Tensor) -> Tensor:
    """The ``(C, n)`` columns of ``feats`` ``(C, h, w)`` under ``mask`` ``(h, w)`` bool, in row-major order: a view of
    all columns when the mask covers every cell (single-image transfer), so that neither the forward nor the backward
    copies the features through the mask."""
    return feats.flatten(1) if bool(mask.all()) else feats[:, mask]
