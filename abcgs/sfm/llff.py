"""LLFF ``poses_bounds.npy``: independent camera poses to check a COLMAP reconstruction against."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

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
