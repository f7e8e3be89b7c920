"""ABC-GS colour match: per matching group, a linear map p' = A p + b that gives the content colours the
style's mean and covariance (paper appendix), applied to the training images and to the Gaussians' DC
colours, followed by a short re-fit of the Gaussians to the recoloured images with the reconstruction
loss, densifying every ``colormatch.refine_every`` steps where that is set (authors' code: 400 iterations on LLFF,
densifying every 50). Each re-fitted Gaussian carries the row of the fitted one it descends from
(:data:`~abcgs.gaussians.FITTED_ROW`), which the later stages use to give it that Gaussian's content label and SH
bands.
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
from abcgs.fit.params import FitParams, StrategyParams
from abcgs.fit.training import fit
from abcgs.gaussians import FITTED_ROW, GaussianModel
from abcgs.gaussians.ply import write_ply
from abcgs.io.atomic import atomic_path, write_json
from abcgs.io.images import resized_labels, save_image
from abcgs.layout import ColorMatchDir
from abcgs.silhouette import (
    Silhouette,
    background_tensor,
    object_gaussians,
    object_weight,
    over,
    silhouettes,
    unpremultiply,
)
from abcgs.stylize.color import apply_group_transforms, color_match_model
from abcgs.stylize.params import ColorMatchParams
from abcgs.stylize.schedule import choose_schedule
from abcgs.stylize.targets import group_pixel_masks
from abcgs.types import FRAME_FILLING, Backend, Background, CalibratedScene, MatchingGroup
from abcgs.viz import image_grid


@dataclass
class ColorMatchResult:
    model: GaussianModel  # its FITTED_ROW attribute: each Gaussian's row in the fitted scene
    transforms: dict[int, tuple[Tensor, Tensor]]
    images: list[Tensor]  # recoloured training images (H, W, 3)
    history: list[dict]
    schedule: dict | None = None  # the re-fit's step count and why (abcgs.stylize.schedule.Schedule.to_dict)


@dataclass(frozen=True)
class ObjectViews:
    """An object scene's views as the colour match sees them: each image's object colour and alpha.

    ``colors[i]`` ``(H, W, 3)``: the object's own colour under view ``i`` (:func:`abcgs.silhouette.unpremultiply` of
    the image on ``background`` ``(3,)``); ``silhouettes[i]``: the fitted scene's alpha there; ``gaussians``
    ``(N,)`` bool: the object's Gaussians (:func:`abcgs.silhouette.object_gaussians`), the only ones recoloured."""

    colors: list[Tensor]
    silhouettes: list[Silhouette]
    background: Tensor
    gaussians: Tensor

    @classmethod
    def of(cls, model: GaussianModel, cameras: list, images: list[Tensor], background: Background,
           backend: Backend = "auto") -> ObjectViews:
        sils = silhouettes(model, cameras, backend)
        bg = background_tensor(background, images[0])
        return cls([unpremultiply(img, s.alpha.to(img), bg) for img, s in zip(images, sils)], sils, bg,
                   object_gaussians(model, cameras, sils, backend))


def content_pixels_by_group(images: list[Tensor], view_labels: list[np.ndarray], groups: list[MatchingGroup],
                            objects: ObjectViews | None = None) -> dict[int, np.ndarray]:
    """Pixels of the training images covered by each group (all pixels for single transfer); of an object scene
    (``objects``), the object's own colour on its object pixels only."""
    out: dict[int, list[np.ndarray]] = {g.content_label: [] for g in groups}
    for k, (img, lab) in enumerate(zip(images, view_labels)):
        arr = (img if objects is None else objects.colors[k]).numpy(force=True)
        on_object = None if objects is None else objects.silhouettes[k].object.numpy(force=True)
        for g, m in zip(groups, group_pixel_masks(groups, lab)):
            out[g.content_label].append(arr[m if on_object is None else m & on_object])
    return {k: np.concatenate(v) for k, v in out.items()}


def recolor_images(images: list[Tensor], view_labels: list[np.ndarray], groups: list[MatchingGroup],
                   transforms: dict[int, tuple[Tensor, Tensor]], objects: ObjectViews | None = None) -> list[Tensor]:
    """Each training image ``(H, W, 3)`` with every group's transform on the pixels its label map gives the group,
    clipped to [0, 1]. Of an object scene (``objects``) the object's own colour is transformed and composited back
    with its alpha, blended in by :func:`abcgs.silhouette.object_weight`: object pixels take it whole, empty pixels
    keep the background, the faint edge and haze between stay nearly as they were."""
    per_group = [transforms[g.content_label] for g in groups]
    out = []
    for k, (img, lab) in enumerate(zip(images, view_labels)):
        masks = [torch.from_numpy(m).to(img.device) for m in group_pixel_masks(groups, lab)]
        if objects is None:
            out.append(apply_group_transforms(img, masks, per_group, clip=(0.0, 1.0)))
            continue
        sil = objects.silhouettes[k]
        covered = ~sil.empty.to(img.device)
        color = apply_group_transforms(objects.colors[k], [m & covered for m in masks], per_group, clip=(0.0, 1.0))
        w = object_weight(sil.alpha.to(img))
        out.append(img + w * (over(color, sil.alpha.to(img), objects.background) - img))
    return out


def color_match_and_refit(
    model: GaussianModel, scene: CalibratedScene, gaussian_labels: Tensor, view_labels: list[np.ndarray],
    groups: list[MatchingGroup], params: ColorMatchParams, *, progress: bool = True,
    background: Background = FRAME_FILLING, color_only: bool = False,
) -> ColorMatchResult:
    """Colour-match ``model`` and its training images per group, then re-fit; everything on ``model``'s device
    (``gaussian_labels`` ``(N,)`` too). The re-fit densifies every ``params.refine_every`` steps (0: never); the
    result's :data:`~abcgs.gaussians.FITTED_ROW` attribute gives each of its Gaussians the row of ``model`` it
    descends from. An object scene (``background``) is matched on its object pixels, keeps its empty pixels and
    re-fits on its background colour, and its Gaussians off the object are frozen (never densified); ``color_only``
    re-fits the colours alone (``stylize.color_only``: the geometry stays bit-identical, nothing is densified)."""
    views = load_views(scene, params.resolution_scale, test_every=0, device=model.device)
    if params.resolution_scale != 1.0:
        view_labels = [resized_labels(v, (c.height, c.width)) for v, c in zip(view_labels, views.cameras)]
    rows = torch.arange(model.num_gaussians, device=model.device)
    model = GaussianModel(**model.params(), attributes={**model.attributes, FITTED_ROW: rows})
    if not params.enabled:
        return ColorMatchResult(model.detach(), {}, views.images, [])
    objects = None
    if background.object:
        objects = ObjectViews.of(model, views.cameras, views.images, background, params.backend)
    pix = content_pixels_by_group(views.images, view_labels, groups, objects)
    for g in groups:
        if len(pix[g.content_label]) < 2:
            label = "the scene" if g.content_label == ALL_PIXELS else f"content label {g.content_label}"
            raise InputError(f"colour match: {label} covers no pixel of the training images")
    recolored, transforms = color_match_model(model, gaussian_labels, groups, pix,
                                              gaussians=None if objects is None else objects.gaussians)
    images = recolor_images(views.images, view_labels, groups, transforms, objects)
    history: list[dict] = []
    schedule = choose_schedule(views.cameras, refit=params.refit_iterations)
    if schedule.steps["refit"] > 0:
        # densifying every refine_every steps to the end, never resetting; clones and split children carry their
        # parent's FITTED_ROW, an object scene's frozen rest is never densified
        steps = schedule.steps["refit"]
        strategy = StrategyParams(refine_start=0, refine_every=max(params.refine_every, 1), refine_stop=steps,
                                  reset_every=steps + 1)
        fp = FitParams(iterations=steps, test_every=0, densify=params.refine_every > 0, strategy=strategy,
                       seed=params.seed, backend=params.backend, resolution_scale=params.resolution_scale,
                       lr_means=1.6e-6, lr_means_final=1.6e-6, background=background.color, color_only=color_only)
        res = fit(scene, fp, progress, views=Views(views.cameras, images, views.train, [], views.alphas), initial=recolored,
                  frozen=None if objects is None else ~objects.gaussians)
        recolored, history = res.model, res.history
    return ColorMatchResult(recolored, transforms, images, history, schedule.to_dict())


def write_colormatch(out: Path, name: str, spec: TransferSpec, result: ColorMatchResult, groups: list[MatchingGroup],
                     vgg_weights: dict) -> None:
    """Write ``out/`` (a folder, atomically): ``point_cloud.ply`` (the colour-matched, re-fitted Gaussians),
    ``fitted_rows.npy`` (``(N,)`` int64: each Gaussian's row in the fitted scene), ``colormatch.json`` (the
    transforms ``A``, ``b`` per group, the re-fit's length, final loss and Gaussian counts, the VGG weights'
    provenance) and ``recolored.png`` (the first recoloured training images)."""
    rows = result.model.attributes[FITTED_ROW].numpy(force=True).astype(np.int64)
    with atomic_path(out, is_dir=True) as tmp:
        d = ColorMatchDir(tmp)
        write_ply(d.ply, result.model)
        np.save(d.fitted_rows, rows)
        write_json(d.record, {
            "colormatch": name, **spec.model_dump(mode="json"), "groups": [g.style_name for g in groups],
            "transforms": {str(k): {"A": A.tolist(), "b": b.tolist()} for k, (A, b) in result.transforms.items()},
            "refit_steps": len(result.history), "schedule": result.schedule,
            "refit_final_loss": result.history[-1]["loss"] if result.history else None,
            "n_gaussians": len(rows), "fitted_rows_kept": len(np.unique(rows)),  # themselves or by descendants
            "vgg_weights": vgg_weights,
        })
        save_image(d.recolored, image_grid([[img.numpy(force=True) for img in result.images[:4]]]))
