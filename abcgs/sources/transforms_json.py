"""The ``transforms.json`` conventions that the nerfstudio and Blender (NeRF-synthetic) formats share: reading the
file, its ``frames`` list, camera-to-world matrices in OpenGL camera axes, and checked numbers. Used by
:mod:`abcgs.sources.nerfstudio` and :mod:`abcgs.sources.blender`.
"""

from __future__ import annotations

import posixpath
from pathlib import Path

import numpy as np

from abcgs.cameras import check_rotation
from abcgs.errors import InputError
from abcgs.io import guarded
from abcgs.sources.validate import check_count, check_file_name, check_unique

OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
"""Right-multiplied onto a camera-to-world matrix: OpenGL camera axes (y up, z back) → OpenCV's (y down, z forward)."""

MAX_JSON_BYTES = 256 << 20
"""Largest transforms file read (bytes): 20 000 frames of nerfstudio's JSON take about 30 MB."""


def load_json(path: Path) -> dict:
    """A JSON object from ``path`` (:func:`abcgs.io.guarded.load_json`); :class:`InputError` naming the file when it
    is not a regular file, not one, is larger than :data:`MAX_JSON_BYTES` or nested deeper than
    :data:`abcgs.io.guarded.MAX_JSON_DEPTH`."""
    data = guarded.load_json(path, "transforms file", MAX_JSON_BYTES)
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object at the top level")
    return data


def frames_of(path: Path, meta: dict) -> list[dict]:
    """``meta["frames"]``, checked to be a non-empty list of objects with ``file_path`` and ``transform_matrix``."""
    frames = meta.get("frames")
    if not isinstance(frames, list) or not frames:
        raise InputError(f"{path}: no `frames` list (or it is empty); a transforms file lists one frame per image")
    check_count(len(frames), str(path))
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict) or "file_path" not in fr or "transform_matrix" not in fr:
            raise InputError(f"{path}: frames[{i}] lacks `file_path` or `transform_matrix`")
        check_file_name(fr["file_path"], f"{path}: frames[{i}].file_path")
    check_unique([posixpath.normpath(fr["file_path"].replace("\\", "/")) for fr in frames], str(path))
    return frames


def camera_to_world(path: Path, where: str, matrix) -> np.ndarray:
    """A ``(4, 4)`` camera-to-world matrix from a 3 × 4 or 4 × 4 nested list, with a rotation block checked to be a
    rotation (orthonormal, det +1): a scaled or mirrored block means another convention."""
    m = number_array(path, f"{where}.transform_matrix", matrix)
    if m.shape not in ((3, 4), (4, 4)):
        raise InputError(f"{path}: {where}.transform_matrix is not a finite 3x4 or 4x4 matrix")
    out = np.eye(4)
    out[:3] = m[:3]
    check_rotation(out[:3, :3], f"{path}: {where}.transform_matrix", "transforms hold camera-to-world poses "
                   "with a rotation block (a scaled or mirrored one is another convention); re-export them")
    return out


def number_array(path: Path, where: str, value) -> np.ndarray:
    """``value`` (a JSON number or nested list of numbers) as a finite ``float64`` array; :class:`InputError` naming
    ``path`` and ``where`` otherwise."""
    try:
        out = np.asarray(value, np.float64)
    except (TypeError, ValueError, OverflowError):
        out = None
    if out is None or not np.isfinite(out).all() or isinstance(value, bool):
        raise InputError(f"{path}: {where} is {str(value)[:60]!r}, not a finite number (or matrix of numbers)")
    return out


def number(path: Path, where: str, value) -> float:
    """``value`` as a finite ``float`` (a JSON number); :class:`InputError` naming ``path`` and ``where`` otherwise."""
    out = number_array(path, where, value)
    if out.ndim:
        raise InputError(f"{path}: {where} is {str(value)[:60]!r}, not a number")
    return float(out)
