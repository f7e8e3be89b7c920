"""Content masks: the user's label PNGs for any subset of views, or automatic ones, lifted onto Gaussians.

Automatic masks need no downloaded network: k-means (OpenCV) on the CIELAB colour and the rendered depth
of a reference view, followed by a small morphological clean-up. (SAM checkpoints cannot be fetched on
the project's machines; a user with SAM masks saves them as label PNGs under ``<scene>/masks/``.)
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel, render
from abcgs.io.images import load_labels
from abcgs.style.lifting import LiftParams, lift_labels, render_label_map

log = logging.getLogger(__name__)


class AutoMaskParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    n_labels: int = Field(3, ge=1, le=16, description="k-means clusters = content labels")
    depth_weight: float = Field(2.0, ge=0, description="weight of normalised depth against Lab colour")
    reference_view: int = Field(0, ge=0, description="index of the view that is clustered")
    seed: int = 0


class MaskParams(BaseModel):
    """``params.yaml``: ``masks``."""

    model_config = ConfigDict(extra="forbid")

    source: Literal["auto", "given", "clustering"] = Field(
        "auto", description="given: the scene's masks/ (error if none); clustering: k-means; auto: given if present"
    )
    lift: LiftParams = Field(default_factory=LiftParams)
    clustering: AutoMaskParams = Field(default_factory=AutoMaskParams)
    backend: str = "auto"


@dataclass
class ContentMasks:
    """Lifted labels and the re-rendered per-view label maps."""

    gaussian_labels: torch.Tensor  # (N,) int64
    n_labels: int
    view_labels: list[np.ndarray]  # per camera (H, W) int64
    source: str
    input_views: list[str]
    agreement: float | None  # pixel agreement of re-rendered vs given masks on the masked views


def find_given_masks(masks_dir: Path, cameras: list[Camera]) -> dict[int, np.ndarray]:
    """Label PNGs in ``masks_dir`` whose stem matches a camera's image stem → {camera index: labels}."""
    if not masks_dir.is_dir():
        return {}
    by_stem = {Path(c.name).stem: i for i, c in enumerate(cameras)}
    out = {}
    for p in sorted(masks_dir.glob("*.png")):
        i = by_stem.get(p.stem)
        if i is None:
            log.warning("mask %s matches no registered view; ignored", p.name)
            continue
        out[i] = load_labels(p, expect_hw=(cameras[i].height, cameras[i].width))
    return out


def cluster_view(model: GaussianModel, camera: Camera, params: AutoMaskParams, backend: str = "auto") -> np.ndarray:
    """k-means labels 1..n of one rendered view from Lab colour + depth ``(H, W) int64``."""
    with torch.no_grad():
        img, alpha, meta = render(model, camera, backend=backend, render_depth=True, normalize_depth=True)
    rgb = img.clamp(0, 1).numpy().astype(np.float32)
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB) / np.array([100.0, 127.0, 127.0], np.float32)
    depth = meta.depth[..., 0].numpy()
    valid = alpha[..., 0].numpy() > 0.5
    if valid.sum() < params.n_labels:
        raise InputError(f"view {camera.name} renders almost empty; cannot cluster it into {params.n_labels} labels")
    d = (depth - depth[valid].mean()) / (depth[valid].std() + 1e-6)
    feats = np.concatenate([lab, params.depth_weight * d[..., None]], -1).reshape(-1, 4).astype(np.float32)
    cv2.setRNGSeed(params.seed)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    _, lbl, _ = cv2.kmeans(feats[valid.reshape(-1)], params.n_labels, None, crit, 3, cv2.KMEANS_PP_CENTERS)
    out = np.zeros(depth.shape, np.int64)
    out[valid] = lbl[:, 0] + 1
    # clean-up: a median filter removes speckle without moving boundaries much
    return cv2.medianBlur(out.astype(np.uint8), 5).astype(np.int64)


def make_content_masks(
    model: GaussianModel, cameras: list[Camera], masks_dir: Path | None, params: MaskParams
) -> ContentMasks:
    """Given or automatic masks → per-Gaussian labels → re-rendered masks for every view."""
    given = find_given_masks(masks_dir, cameras) if masks_dir is not None else {}
    if params.source == "given" and not given:
        raise InputError(f"masks.source is 'given' but no label PNG in {masks_dir} matches a view")
    if given and params.source in ("auto", "given"):
        source = "given"
        idx = sorted(given)
        maps = [given[i] for i in idx]
    else:
        source = "clustering"
        i = params.clustering.reference_view
        if i >= len(cameras):
            raise InputError(f"masks.clustering.reference_view {i} is out of range (scene has {len(cameras)} views)")
        idx, maps = [i], [cluster_view(model, cameras[i], params.clustering, params.backend)]
    n_labels = int(max(m.max() for m in maps))
    if n_labels == 0:
        raise InputError("the content masks contain no label > 0 (0 means unassigned); nothing to lift")
    lifted = lift_labels(model, [cameras[i] for i in idx], maps, n_labels, params.lift, backend=params.backend)
    views = [
        render_label_map(model, lifted.labels, n_labels, c, threshold=params.lift.render_threshold, backend=params.backend)
        for c in cameras
    ]
    agree = [float((views[i] == m)[m > 0].mean()) for i, m in zip(idx, maps) if (m > 0).any()]
    counts = lifted.counts()
    log.info("lifted %s masks of %d view(s) onto %d Gaussians: %s", source, len(idx), len(lifted.labels), counts)
    return ContentMasks(lifted.labels, n_labels, views, source, [cameras[i].name for i in idx],
                        float(np.mean(agree)) if agree else None)


def colorize_labels(labels: np.ndarray) -> np.ndarray:
    """``(H, W)`` labels → ``(H, W, 3) uint8`` with a fixed palette (0 = black)."""
    palette = np.array(
        [[0, 0, 0], [230, 25, 75], [60, 180, 75], [255, 225, 25], [0, 130, 200], [245, 130, 48], [145, 30, 180],
         [70, 240, 240], [240, 50, 230], [210, 245, 60], [250, 190, 212], [0, 128, 128], [220, 190, 255],
         [170, 110, 40], [255, 250, 200], [128, 0, 0], [170, 255, 195]], np.uint8)
    return palette[np.clip(labels, 0, len(palette) - 1)]
