"""LLFF ``poses_bounds.npy``: independent camera poses (to check a COLMAP reconstruction against, or to use a
capture's views without reconstructing it)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from abcgs.cameras import Camera, intrinsics
from abcgs.errors import InputError


def llff_camera_centres(path: str | os.PathLike) -> np.ndarray:
    """Camera centres ``(N, 3)`` from an LLFF ``poses_bounds.npy`` (``N × 17``).

    Each row is a camera-to-world ``3 × 5`` matrix ``[R | t | hwf]`` (LLFF axes: down, right, back)
    followed by near/far bounds. Column 3 is the camera centre, which is independent of the axis
    convention; rows are in the order of the sorted image file names.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path} does not exist; expected LLFF's poses_bounds.npy")
    arr = np.load(path)
    if arr.ndim != 2 or arr.shape[1] != 17:
        raise InputError(f"{path} has shape {arr.shape}; LLFF poses_bounds.npy is N x 17")
    return arr[:, :15].reshape(-1, 3, 5)[:, :, 3].astype(np.float64)


def llff_cameras(path: str | os.PathLike, names: list[str], size: tuple[int, int]) -> list[Camera]:
    """Pinhole cameras from an LLFF ``poses_bounds.npy``, one per name (rows in the order of ``names``, the sorted
    image file names), for images of ``size = (width, height)``.

    ``viewmat`` is world→camera with OpenCV axes (x right, y down, z forward): LLFF's camera-to-world columns
    (down, right, back) become (right, down, −back). The focal length of the row's ``hwf`` (at the full-size
    capture) is scaled to ``size``; the principal point is the image centre, as LLFF assumes.
    """
    path = Path(path)
    arr = np.load(path) if path.is_file() else None
    if arr is None or arr.ndim != 2 or arr.shape[1] != 17:
        raise InputError(f"{path}: expected LLFF's poses_bounds.npy (N x 17)")
    if len(arr) != len(names):
        raise InputError(f"{path} holds {len(arr)} poses for {len(names)} images")
    width, height = size
    cams = []
    for name, row in zip(names, arr[:, :15].reshape(-1, 3, 5).astype(np.float64)):
        h, w, f = row[:, 4]
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = row[:, 1], row[:, 0], -row[:, 2], row[:, 3]
        K = intrinsics(f * width / w, width, height)
        K[1, 1] = f * height / h
        cams.append(Camera(name, K, np.linalg.inv(c2w), int(width), int(height)))
    return cams
