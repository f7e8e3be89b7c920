"""A fit's training data: a scene's views loaded once at the training resolution, the train/test split (LLFF: every
8th view held out) and the scene's extent."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import torch
from torch import Tensor

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.io.images import load_image
from abcgs.types import CalibratedScene


@dataclass
class Views:
    """Training data in memory: cameras at the training resolution and ``(H, W, 3) float32`` image tensors (and an
    object's ``(H, W, 1) float32`` alpha maps, when the dataset gave them: ``alphas``)."""

    cameras: list[Camera]
    images: list[Tensor]
    train: list[int]
    test: list[int]
    alphas: list[Tensor] | None = None

    def pick(self, indices: Sequence[int]) -> tuple[list[Camera], list[Tensor]]:
        """The cameras and images of the views ``indices``."""
        return [self.cameras[i] for i in indices], [self.images[i] for i in indices]


def split_views(n: int, test_every: int) -> tuple[list[int], list[int]]:
    """``(train, test)`` indices: views ``0, k, 2k, …`` are held out (LLFF convention); ``k = 0`` holds none."""
    if test_every <= 0:
        return list(range(n)), []
    test = [i for i in range(n) if i % test_every == 0]
    train = [i for i in range(n) if i % test_every != 0]
    if not train:
        raise InputError(f"with {n} view(s) and test_every={test_every} no view is left for training; set test_every: 0")
    return train, test


def load_views(scene: CalibratedScene, resolution_scale: float = 1.0, test_every: int = 8, device: str | torch.device = "cpu") -> Views:
    """Load every image once, downscaled by ``resolution_scale`` with ``cv2.INTER_AREA``.

    Each image must have its camera's size (the undistorted images of the reconstruct stage do);
    a mismatch raises :class:`InputError` with both sizes.
    """
    if len(scene.cameras) != len(scene.image_paths):
        raise InputError(f"scene has {len(scene.cameras)} cameras but {len(scene.image_paths)} image paths")
    if not scene.cameras:
        raise InputError("scene has no cameras")
    cams, imgs = [], []
    alpha_paths = getattr(scene, "alpha_paths", None)
    alphas: list[Tensor] | None = None if alpha_paths is None else []
    for k, (cam, path) in enumerate(zip(scene.cameras, scene.image_paths)):
        img = load_image(path)
        if img.shape[:2] != (cam.height, cam.width):
            raise InputError(
                f"image {path} is {img.shape[1]}x{img.shape[0]} but its camera {cam.name} is {cam.width}x{cam.height}; "
                "use the undistorted images written with the COLMAP model"
            )
        alpha = None if alphas is None else load_image(alpha_paths[k])[..., :1]
        if alpha is not None and alpha.shape[:2] != img.shape[:2]:
            raise InputError(f"alpha map {alpha_paths[k]} is not the size of its image {path}")
        if resolution_scale != 1.0:
            cam = cam.scaled(resolution_scale)
            img = cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
            if alpha is not None:
                alpha = cv2.resize(alpha, (cam.width, cam.height), interpolation=cv2.INTER_AREA)[..., None]
        cams.append(cam)
        imgs.append(torch.from_numpy(np.ascontiguousarray(img, dtype=np.float32)).to(device))
        if alphas is not None:
            alphas.append(torch.from_numpy(np.ascontiguousarray(alpha, dtype=np.float32)).to(device))
    train, test = split_views(len(cams), test_every)
    return Views(cams, imgs, train, test, alphas)


def scene_extent(camera_centers: Tensor | Any, points: Tensor | Any | None = None) -> float:
    """3DGS's ``cameras_extent``: 1.1 × the largest distance of a camera centre from their centroid.

    Falls back to the point cloud's spread (same formula) for a single camera or co-located cameras, and
    to 1 when both are degenerate.
    """
    for pts in (camera_centers, points):
        if pts is None:
            continue
        c = torch.as_tensor(pts, dtype=torch.float64).reshape(-1, 3)
        if len(c) > 1:
            radius = float((c - c.mean(0)).norm(dim=-1).max()) * 1.1
            if radius > 1e-9 and math.isfinite(radius):
                return radius
    return 1.0
