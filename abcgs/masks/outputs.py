"""What the ``masks`` stage writes for one scene.

Layout of ``out/<scene>/masks/``: ``gaussian_labels.npy`` ``(N,) int64`` (the lifted label of every Gaussian, 0 =
unassigned), ``views/<view>.png`` (the label map rendered back for every view), ``overlay.png`` (the first views,
their lifted labels and both blended) and ``masks.json`` (source, label counts, agreement, held-out IoU, the share of unlabelled Gaussians and, per view, of
unlabelled pixels, and a warning for each view above ``masks.warn_unlabelled``). For a scene whose content labels
no colour match reads, :func:`write_unread_masks` writes the same files but the overlay, all 0.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.io.atomic import atomic_path, write_json
from abcgs.io.images import load_image, load_labels, save_image, save_labels
from abcgs.layout import MasksDir
from abcgs.types import CalibratedScene, SceneMasks
from abcgs.viz import colorize_labels, image_grid

if TYPE_CHECKING:  # the writer takes the computed masks; the stages that only read them do not import that code
    from abcgs.masks.content import ContentMasks

OVERLAY_ROWS = 4
"""Views shown in ``overlay.png``."""


def write_content_masks(out: Path, result: ContentMasks, cameras: list[Camera], image_paths: list[Path]) -> None:
    """Write ``out/`` (a folder, atomically) from the lifted masks ``result`` of the scene's ``cameras``."""
    with atomic_path(out, is_dir=True) as tmp:
        d = MasksDir(tmp)
        np.save(d.gaussian_labels, result.gaussian_labels.numpy(force=True).astype(np.int64))
        d.views.mkdir()
        rows = []
        for cam, path, lab in zip(cameras, image_paths, result.view_labels):
            save_labels(d.views / f"{Path(cam.name).stem}.png", lab)
            if len(rows) < OVERLAY_ROWS:
                img = load_image(path)
                over = (0.5 * img + 0.5 * colorize_labels(lab) / 255.0).astype(np.float32)
                rows.append([img, colorize_labels(lab), over])
        save_image(d.overlay, image_grid(rows, ["view", "lifted labels", "overlay"]))
        labels, counts = np.unique(result.gaussian_labels.numpy(force=True), return_counts=True)
        write_json(d.record, {
            "source": result.source, "input_views": result.input_views, "n_labels": result.n_labels,
            "gaussians_per_label": {str(k): int(v) for k, v in zip(labels, counts)},
            "agreement_with_input_masks": result.agreement,
            "heldout_views": result.heldout_views,
            "heldout_iou_per_label": {str(k): v for k, v in result.heldout_iou.items()},
            "heldout_agreement": result.heldout_agreement,
            "colour_palette": {str(k): list(v) for k, v in result.palette.items()},
            "gaussians_propagated": result.propagated,
            "unlabelled_gaussians": result.unlabelled_gaussians,
            "unlabelled_pixels_per_view": result.unlabelled_pixels,
            "warnings": result.warnings,
            "warned_views": result.warned_views,
            "refinement": None if result.refinement is None else {
                "views_recut": len(result.refinement.views), "per_view": result.refinement.views,
            },
        })


UNREAD_SOURCE = "none: no colour match reads content labels"
"""``masks.json``'s ``source`` when the stage wrote no labels (:func:`write_unread_masks`)."""


def write_unread_masks(out: Path, n_gaussians: int, cameras: list[Camera]) -> None:
    """Write ``out/`` (a folder, atomically) for a scene whose content labels nothing reads (every colour match of
    it is single-image transfer, which styles every pixel alike): every Gaussian and every view pixel 0, and a
    record that says so. Nothing is lifted or re-cut, and ``overlay.png`` is not drawn; the stages that load the
    masks (:func:`load_scene_masks`) read these as they read computed ones."""
    with atomic_path(out, is_dir=True) as tmp:
        d = MasksDir(tmp)
        np.save(d.gaussian_labels, np.zeros(n_gaussians, np.int64))
        d.views.mkdir()
        for cam in cameras:
            save_labels(d.views / f"{Path(cam.name).stem}.png", np.zeros((cam.height, cam.width), np.int64))
        write_json(d.record, {
            "source": UNREAD_SOURCE, "n_labels": 0,
            "gaussians_per_label": {"0": n_gaussians}, "warnings": [], "warned_views": [],
        })


def load_scene_masks(masks_dir: Path, scene: CalibratedScene, n_gaussians: int, *,
                     device: torch.device | str = "cpu") -> SceneMasks:
    """The masks stage's output: Gaussian labels on ``device``, view label maps as host arrays."""
    d = MasksDir(masks_dir)
    labels = torch.from_numpy(np.load(d.gaussian_labels)).long().to(device)
    if labels.shape[0] != n_gaussians:
        raise InputError(
            f"{d.gaussian_labels} has {labels.shape[0]} labels but the scene has {n_gaussians} Gaussians; "
            "re-run the masks stage (dvc repro)"
        )
    views = [load_labels(d.views / f"{Path(c.name).stem}.png", expect_hw=(c.height, c.width)) for c in scene.cameras]
    return SceneMasks(labels, views)
