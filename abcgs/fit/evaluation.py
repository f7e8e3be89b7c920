"""Scoring a model against held-out photos: PSNR (dB) and SSIM per view and their means (as 3DGS reports), and the
``target | render`` comparison grid the fit stage writes."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import torch
from torch import Tensor

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.fit import metrics as M
from abcgs.gaussians import GaussianModel, render_each


@dataclass
class ViewEval:
    """One evaluated view: metrics and (optionally) the images as ``(H, W, 3) float32`` numpy arrays."""

    name: str
    psnr: float
    ssim: float
    render: np.ndarray | None = None
    target: np.ndarray | None = None


@dataclass
class Evaluation:
    """Mean metrics over views (PSNR averaged per view in dB, as 3DGS reports) and the per-view list."""

    psnr: float
    ssim: float
    views: list[ViewEval]

    def to_dict(self) -> dict:
        return {
            "psnr": self.psnr,
            "ssim": self.ssim,
            "n_views": len(self.views),
            "per_view": {v.name: {"psnr": v.psnr, "ssim": v.ssim} for v in self.views},
        }


@torch.no_grad()
def evaluate(
    model: GaussianModel,
    cameras: Sequence[Camera],
    images: Sequence[Tensor | np.ndarray],
    backend: str = "auto",
    *,
    background: Tensor | None = None,
    keep_images: bool = False,
) -> Evaluation:
    """Render ``cameras`` and compare with ``images`` ``(H, W, 3)`` in ``[0, 1]``: PSNR (dB) and SSIM.

    Renders are clamped to ``[0, 1]`` before scoring. With ``keep_images`` each :class:`ViewEval` keeps
    the render and the target as numpy arrays.
    """
    if len(cameras) != len(images):
        raise InputError(f"evaluate: {len(cameras)} cameras but {len(images)} images")
    views = []
    renders = render_each(model, cameras, backend=backend, background=background)
    for cam, gt, (img, _, _) in zip(cameras, images, renders):
        gt_t = torch.as_tensor(gt, dtype=torch.float32, device=model.device)
        img = img.clamp(0.0, 1.0)
        views.append(
            ViewEval(
                cam.name, M.psnr(img, gt_t), M.ssim(img, gt_t),
                img.cpu().numpy() if keep_images else None, gt_t.cpu().numpy() if keep_images else None,
            )
        )
    if not views:
        return Evaluation(math.nan, math.nan, [])
    return Evaluation(float(np.mean([v.psnr for v in views])), float(np.mean([v.ssim for v in views])), views)


def comparison_grid(pairs: Sequence[tuple[np.ndarray, np.ndarray]], max_tile_width: int = 400, gap: int = 4) -> np.ndarray:
    """Rows of ``target | render`` tiles (``(H, W, 3)`` floats in [0, 1]) on white, tiles downscaled to ``max_tile_width``."""
    rows = []
    for target, rendered in pairs:
        tiles = []
        for img in (target, rendered):
            img = np.clip(np.asarray(img, np.float32), 0.0, 1.0)
            if img.shape[1] > max_tile_width:
                h = max(1, round(img.shape[0] * max_tile_width / img.shape[1]))
                img = cv2.resize(img, (max_tile_width, h), interpolation=cv2.INTER_AREA)
            tiles.append(img)
        h = max(t.shape[0] for t in tiles)
        w = sum(t.shape[1] for t in tiles) + gap
        row = np.ones((h, w, 3), np.float32)
        row[: tiles[0].shape[0], : tiles[0].shape[1]] = tiles[0]
        row[: tiles[1].shape[0], tiles[0].shape[1] + gap :] = tiles[1]
        rows.append(row)
    if not rows:
        return np.ones((1, 1, 3), np.float32)
    width = max(r.shape[1] for r in rows)
    out = np.ones((sum(r.shape[0] for r in rows) + gap * (len(rows) - 1), width, 3), np.float32)
    y = 0
    for r in rows:
        out[y : y + r.shape[0], : r.shape[1]] = r
        y += r.shape[0] + gap
    return out
