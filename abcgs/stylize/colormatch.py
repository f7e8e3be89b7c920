"""ABC-GS colour match: per matching group, a linear map p' = A p + b that gives the content colours the
style's mean and covariance (paper appendix), applied to the training images and to the Gaussians' DC
colours, followed by a short re-fit of the Gaussians to the recoloured images with the reconstruction
loss (authors' code: 400 iterations on LLFF).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from abcgs.errors import InputError
from abcgs.features.params import ALL_PIXELS, TransferSpec
from abcgs.fit.data import Views, load_views
from abcgs.fit.params import FitParams
from abcgs.fit.training import fit
from abcgs.gaussians import GaussianModel
from abcgs.io.atomic import atomic_path, write_json
from abcgs.io.images import save_image
from abcgs.io.ply import write_ply
from abcgs.layout import ColorMatchDir
from abcgs.sfm.model import SceneData
from abcgs.stylize.color import apply_group_transforms
from abcgs.stylize.loop import color_match_model, group_pixel_masks
from abcgs.stylize.params import ColorMatchParams
from abcgs.types import MatchingGroup
from abcgs.viz import image_grid


@dataclass
class ColorMatchResult:
    model: GaussianModel
    transforms: dict[int, tuple[Tensor, Tensor]]
    images: list[Tensor]  # recoloured training images (H, W, 3)
    history: list[dict]


def content_pixels_by_group(images: list[Tensor], view_labels: list[np.ndarray], groups: list[MatchingGroup]) -> dict[int, np.ndarray]:
    """Pixels of the training images covered by each group (all pixels for single transfer)."""
    out: dict[int, list[np.ndarray]] = {g.content_label: [] for g in groups}
    for img, lab in zip(images, view_labels):
        arr = img.numpy(force=True)
        for g, m in zip(groups, group_pixel_masks(groups, lab)):
            out[g.content_label].append(arr[m])
    return {k: np.concatenate(v) for k, v in out.items()}


def recolor_images(images: list[Tensor], view_labels: list[np.ndarray], groups: list[MatchingGroup],
                   transforms: dict[int, tuple[Tensor, Tensor]]) -> list[Tensor]:
    """Each training image ``(H, W, 3)`` with every group's transform on the pixels its label map gives the group,
    clipped to [0, 1]."""
    per_group = [transforms[g.content_label] for g in groups]
    return [apply_group_transforms(img, [torch.from_numpy(m).to(img.device) for m in group_pixel_masks(groups, lab)],
                                   per_group, clip=(0.0, 1.0))
            for img, lab in zip(images, view_labels)]


def color_match_and_refit(
    model: GaussianModel, scene: SceneData, gaussian_labels: Tensor, view_labels: list[np.ndarray],
    groups: list[MatchingGroup], params: ColorMatchParams, *, progress: bool = True,
) -> ColorMatchResult:
    """Colour-match ``model`` and its training images per group, then re-fit; everything on ``model``'s device
    (``gaussian_labels`` ``(N,)`` too)."""
    views = load_views(scene, params.resolution_scale, test_every=0, device=model.device)
    if params.resolution_scale != 1.0:
        import cv2

        view_labels = [cv2.resize(v.astype(np.int32), (c.width, c.height), interpolation=cv2.INTER_NEAREST).astype(np.int64)
                       for v, c in zip(view_labels, views.cameras)]
    if not params.enabled:
        return ColorMatchResult(model.detach(), {}, views.images, [])
    pix = content_pixels_by_group(views.images, view_labels, groups)
    for g in groups:
        if len(pix[g.content_label]) < 2:
            label = "the scene" if g.content_label == ALL_PIXELS else f"content label {g.content_label}"
            raise InputError(f"colour match: {label} covers no pixel of the training images")
    recolored, transforms = color_match_model(model, gaussian_labels, groups, pix)
    images = recolor_images(views.images, view_labels, groups, transforms)
    history: list[dict] = []
    if params.refit_iterations > 0:
        # No densification: the Gaussians keep their lifted labels (the authors densify every 50 steps and
        # keep per-view 2-D masks instead; with 3-D labels the set of Gaussians must stay fixed).
        fp = FitParams(iterations=params.refit_iterations, test_every=0, densify=False, seed=params.seed,
                       backend=params.backend, resolution_scale=params.resolution_scale, lr_means=1.6e-6,
                       lr_means_final=1.6e-6)
        res = fit(scene, fp, progress, views=Views(views.cameras, images, views.train, []), initial=recolored)
        recolored, history = res.model, res.history
    return ColorMatchResult(recolored, transforms, images, history)


def write_colormatch(out: Path, name: str, spec: TransferSpec, result: ColorMatchResult, groups: list[MatchingGroup],
                     vgg_weights: dict) -> None:
    """Write ``out/`` (a folder, atomically): ``point_cloud.ply`` (the colour-matched, re-fitted Gaussians),
    ``colormatch.json`` (the transforms ``A``, ``b`` per group, the re-fit's length and final loss, the VGG weights'
    provenance) and ``recolored.png`` (the first recoloured training images)."""
    with atomic_path(out, is_dir=True) as tmp:
        d = ColorMatchDir(tmp)
        write_ply(d.ply, result.model)
        write_json(d.record, {
            "colormatch": name, **spec.model_dump(mode="json"), "groups": [g.style_name for g in groups],
            "transforms": {str(k): {"A": A.tolist(), "b": b.tolist()} for k, (A, b) in result.transforms.items()},
            "refit_steps": len(result.history),
            "refit_final_loss": result.history[-1]["loss"] if result.history else None,
            "vgg_weights": vgg_weights,
        })
        save_image(d.recolored, image_grid([[img.numpy(force=True) for img in result.images[:4]]]))
