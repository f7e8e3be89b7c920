"""The calibrated scene every stage after ``reconstruct`` reads: a :class:`~abcgs.types.Scene` from the undistorted
COLMAP model that stage writes (``out/<scene>/colmap/sparse/``, PINHOLE cameras, read by :mod:`abcgs.io.colmap`:
no pycolmap needed, so the stages that only read a scene run where no pycolmap wheel exists). Its points come in the
reader's canonical order, by point id.
"""

from __future__ import annotations

import os
from pathlib import Path

from abcgs.errors import InputError
from abcgs.io.colmap import read_model
from abcgs.types import CAMERA_MODELS, Scene


def read_colmap_scene(model_dir: str | os.PathLike, images_dir: str | os.PathLike) -> Scene:
    """Read an undistorted COLMAP model (``sparse/``: ``*.bin`` or ``*.txt``, PINHOLE or SIMPLE_PINHOLE cameras) and
    its images into a :class:`~abcgs.types.Scene` (views sorted by image name; ``alpha_paths`` from ``alpha/``
    beside ``images/`` when the reconstruct stage wrote it)."""
    model_dir, images_dir = Path(model_dir), Path(images_dir)
    model = read_model(model_dir)
    if not model.images:
        raise InputError(f"COLMAP model {model_dir} has no registered images")
    for im in model.images:
        cam = model.cameras_by_id[im.camera_id]
        if cam.model_id not in (0, 1):
            raise InputError(
                f"image {im.name} uses a {CAMERA_MODELS[cam.model_id][0]} camera; read_colmap_scene needs an "
                "undistorted (PINHOLE) model, i.e. the sparse/ folder written by the reconstruct stage")
    cameras = model.cameras()
    paths = tuple(images_dir / name for name in cameras.names)
    missing = [p.name for p in paths if not p.is_file()]
    if missing:
        raise InputError(f"{len(missing)} image(s) of the model are missing from {images_dir}: {', '.join(missing[:10])}")
    alpha_dir = images_dir.parent / "alpha"
    alphas = tuple(alpha_dir / name for name in cameras.names) if alpha_dir.is_dir() else None
    if alphas is not None and not all(p.is_file() for p in alphas):
        raise InputError(f"{alpha_dir} lacks the alpha map of some views; re-run the reconstruct stage")
    return Scene(cameras, paths, model.points.astype("float32"), (model.colors / 255.0).astype("float32"),
                 alpha_paths=alphas)
