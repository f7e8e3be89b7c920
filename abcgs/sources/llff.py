"""Reader ``llff``: LLFF's ``poses_bounds.npy`` beside the images (no structure from motion).

``poses_bounds.npy`` is ``N × 17``: per image (in the order of the sorted file names) a camera-to-world ``3 × 5``
matrix ``[R | t | hwf]`` with LLFF's camera axes (down, right, back) and the height, width and focal length of the
full-size capture, then the near/far depth bounds of the scene points. The poses are COLMAP's, in COLMAP's world
frame, which stays the scene frame. The principal point is the image centre (LLFF's assumption) and the focal length
is scaled from ``hwf`` to the images used (``images/`` or ``images_4``/``images_8`` via the scene's `images:`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from abcgs.cameras import Camera, check_intrinsics, check_rotation, intrinsics
from abcgs.errors import InputError
from abcgs.sources.base import ReadOptions
from abcgs.sources.detect import DEFAULT_IMAGES, image_files
from abcgs.sources.lens import fit_to_image, image_size
from abcgs.sources.validate import check_count
from abcgs.types import SourceScene, View

POSES_FILE = "poses_bounds.npy"


def load_poses_bounds(path: str | os.PathLike) -> np.ndarray:
    """The ``(N, 17) float64`` array of an LLFF ``poses_bounds.npy``; :class:`InputError` naming the file when it is
    missing or not ``N × 17``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path} does not exist; expected LLFF's poses_bounds.npy")
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as exc:  # numpy raises OSError, ValueError, EOFError, tokenize.TokenError, … for a corrupt header
        raise InputError(f"{path} is not a numpy array file ({exc}); expected LLFF's poses_bounds.npy") from None
    if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "fiu":
        raise InputError(f"{path} is not an array of numbers; expected LLFF's poses_bounds.npy (N x 17 floats)")
    if arr.ndim != 2 or arr.shape[1] != 17 or not len(arr):
        raise InputError(f"{path} has shape {arr.shape}; LLFF poses_bounds.npy is N x 17 (N > 0)")
    check_count(len(arr), str(path))
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        rows = np.flatnonzero(~np.isfinite(arr).all(axis=1))
        raise InputError(f"{path}: rows {', '.join(map(str, rows[:5]))} hold NaN or infinite values; re-export the poses")
    return arr


def llff_camera_centres(path: str | os.PathLike) -> np.ndarray:
    """Camera centres ``(N, 3)`` from an LLFF ``poses_bounds.npy`` (column 3 of each pose: independent of the axis
    convention), rows in the order of the sorted image file names."""
    return load_poses_bounds(path)[:, :15].reshape(-1, 3, 5)[:, :, 3]


def _calibrated_camera(name: str, row: np.ndarray, where: str = "poses_bounds.npy") -> Camera:
    """One row's camera at the full-size capture (``hwf``), OpenCV axes: LLFF's columns (down, right, back) become
    (right, down, −back). :class:`InputError` naming ``where`` when the columns are not such a rotation."""
    pose = row[:15].reshape(3, 5)
    h, w, f = pose[:, 4]
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = pose[:, 1], pose[:, 0], -pose[:, 2], pose[:, 3]
    check_rotation(c2w[:3, :3], f"{where}: the pose's columns 0-2 as LLFF's (down, right, back) camera axes",
                   "re-export the poses in LLFF's convention")
    if not (f > 0 and w >= 1 and h >= 1):
        raise InputError(f"{where}: hwf is ({h:g}, {w:g}, {f:g}); LLFF writes the capture's height, width and focal")
    check_intrinsics(f, f, round(w) / 2, round(h) / 2, round(w), round(h), where,
                     "LLFF writes the capture's height, width and focal length in pixels; re-export the poses")
    return Camera(name, intrinsics(f, round(w), round(h)), np.linalg.inv(c2w), int(round(w)), int(round(h)))


def llff_cameras(path: str | os.PathLike, names: list[str], size: tuple[int, int]) -> list[Camera]:
    """Pinhole cameras from an LLFF ``poses_bounds.npy``, one per name (rows in the order of ``names``, the sorted
    image file names), for images of ``size = (width, height)`` (the full-size ``hwf`` scaled to it)."""
    arr = load_poses_bounds(path)
    if len(arr) != len(names):
        raise InputError(f"{path} holds {len(arr)} poses for {len(names)} images")
    return [fit_to_image(_calibrated_camera(n, row, f"{path} row {i}"), None, size, f"{path} row {i} ({n})")[0]
            for i, (n, row) in enumerate(zip(names, arr))]


def read_llff_source(folder: str | os.PathLike, images: str | None = None) -> SourceScene:
    """``folder/poses_bounds.npy`` and the images of ``folder/images`` (module docstring)."""
    folder = Path(folder)
    path = folder / POSES_FILE
    arr = load_poses_bounds(path)
    images_dir = folder / (images or DEFAULT_IMAGES)
    files = image_files(images_dir)
    if len(files) != len(arr):
        raise InputError(
            f"{path} holds {len(arr)} poses but {images_dir} holds {len(files)} images; LLFF pairs the rows with the "
            "sorted image files one to one: use the image folder of the same capture (`images:` in the scene entry), "
            "with no image added or removed")
    views = []
    for i, (p, row) in enumerate(zip(files, arr)):
        cam, _ = fit_to_image(_calibrated_camera(p.name, row, f"{path} row {i}"), None, image_size(p),
                              f"{path} row {i} and {p}")
        views.append(View(p.name, p, cam))
    near, far = float(arr[:, 15].min()), float(arr[:, 16].max())
    if not (0 < near < far):
        raise InputError(f"{path}: the depth bounds (columns 15, 16) are {near:g} .. {far:g}; LLFF writes 0 < near < far")
    return SourceScene.from_views(views, format="llff", depth_range=(near, far))


def read(folder: Path, options: ReadOptions) -> SourceScene:
    """The ``llff`` format's reading (its ``READER``: :mod:`abcgs.sources.formats.llff`)."""
    return read_llff_source(folder, options.images)
