"""Checks of what a reader found, before any image is decoded.

Files: a dataset lists at most :data:`MAX_VIEWS` views, each file once (:func:`check_unique`), and every file it
names lies inside the scene's folder (:func:`check_inside`), which is what DVC tracks for the stages that read it.

Cameras must make sense as a capture: a wrong axis convention
(OpenGL poses read as OpenCV ones, or the reverse) or a wrong world frame shows here as cameras that look away from
the scene.

- With points (a COLMAP model, nerfstudio's ``ply_file_path``): most cameras must see some of the points in front of
  them and inside their image.
- Without points: where the cameras' optical axes converge (the least-squares point nearest to all of them, when
  the axes are not all parallel), that point must lie in front of most cameras.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.types import SourceScene

OUTSIDE_FIX = ("DVC tracks only the scene's folder, so an edit to a file elsewhere would not re-run the stages that "
               "read it: copy the file into the scene's folder and name it relative to it")

MAX_VIEWS = 20_000
"""Most views a dataset may list (the largest public captures have a few thousand)."""
MIN_VISIBLE = 0.02
"""A camera sees a scene when at least this fraction of its points lie in front of it and inside its image."""
MAX_CHECKED_POINTS = 20_000
"""The visibility check looks at this many of a model's points at most."""
MIN_CONVERGENCE = 1e-3
"""Axes whose spread (smallest eigenvalue of the mean of ``I - d dᵀ``) is below this are taken as parallel (a
forward-facing capture): where they meet is then not defined and not checked."""


def visible_fraction(scene: SourceScene) -> np.ndarray:
    """Per view: the fraction of the scene's points in front of the camera and inside its image, ``(N,)`` (on every
    k-th point of large models: at most :data:`MAX_CHECKED_POINTS`)."""
    pts = np.asarray(scene.points, np.float64)
    pts = pts[:: max(1, len(pts) // MAX_CHECKED_POINTS)]
    out = []
    for cam in scene.cameras:
        p = pts @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
        front = p[:, 2] > 1e-9
        uv = p[front] @ cam.K.T
        uv = uv[:, :2] / uv[:, 2:3]
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        out.append(float(inside.sum()) / max(len(pts), 1))
    return np.asarray(out)


def axes_meeting_point(cameras: list[Camera]) -> np.ndarray | None:
    """The point nearest (least squares) to every camera's optical axis, or ``None`` when the axes are parallel."""
    centres = np.array([c.center for c in cameras])
    dirs = np.array([c.viewmat[2, :3] for c in cameras])  # camera +z in world
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c, d in zip(centres, dirs):
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c
    A /= len(centres)
    b /= len(centres)
    if np.linalg.eigvalsh(A)[0] < MIN_CONVERGENCE:
        return None
    return np.linalg.solve(A, b)


def check_cameras(scene: SourceScene, what: str) -> None:
    """Raise :class:`InputError` naming ``what`` (the dataset's file) when the cameras look away from the scene
    (module docstring)."""
    n = len(scene.cameras)
    if scene.points is not None and len(scene.points) >= 10:
        vis = visible_fraction(scene)
        blind = int((vis < MIN_VISIBLE).sum())
        if blind > n / 2:
            raise InputError(
                f"{what}: {blind} of {n} cameras see (almost) none of the dataset's {len(scene.points)} points in front "
                "of them, so the poses do not fit the points: a wrong axis convention (OpenGL vs OpenCV camera axes) "
                "or world frame; re-export the dataset, or set the scene's `format:` to the kind it really is")
        return
    if n < 2:
        return
    meet = axes_meeting_point(scene.cameras)
    if meet is None:
        return
    depth = np.array([(c.viewmat @ np.append(meet, 1.0))[2] for c in scene.cameras])
    behind = int((depth <= 0).sum())
    if behind > n / 2:
        raise InputError(
            f"{what}: the cameras' viewing axes meet behind {behind} of the {n} cameras, so they look away from what "
            "they all see: a wrong axis convention (OpenGL vs OpenCV camera axes, z flipped); re-export the poses in "
            "the format's convention, or set the scene's `format:` to the kind the file really is")


def check_count(n: int, what: str) -> None:
    """Raise :class:`InputError` naming ``what`` when a dataset lists more than :data:`MAX_VIEWS` views."""
    if n > MAX_VIEWS:
        raise InputError(f"{what} lists {n} views, more than the {MAX_VIEWS} abcgs reads; split the capture or "
                         "keep a subset of its frames")


def check_unique(names: list[str], what: str, item: str = "frames[{}]") -> None:
    """Raise :class:`InputError` naming ``what`` and the two records (``item`` formatted with their indices) when
    two of ``names`` (the files the records name, normalised) are the same."""
    first: dict[str, int] = {}
    for i, name in enumerate(names):
        j = first.setdefault(name, i)
        if j != i:
            raise InputError(f"{what}: {item.format(j)} and {item.format(i)} both name {name!r}; each view needs its "
                             "own image: remove the repeated one")


def check_file_name(value, where: str) -> str:
    """``value`` when it can name a file (a non-empty string without NUL, each part at most 255 characters, 4096 in
    all); else :class:`InputError` naming ``where``."""
    if not isinstance(value, str) or not value.strip() or "\0" in value or len(value) > 4096 or any(
            len(part) > 255 for part in value.replace("\\", "/").split("/")):
        raise InputError(f"{where} is {str(value)[:60]!r}{'…' if len(str(value)) > 60 else ''}, not a file name")
    return value


def check_inside(folder: Path, path: Path, where: str) -> Path:
    """``path`` when it lies inside ``folder`` (compared as written, ``..`` resolved, symbolic links not followed:
    a linked image folder is the scene's); else :class:`InputError` naming ``where`` and why."""
    base = os.path.normpath(os.path.abspath(folder))
    target = os.path.normpath(os.path.abspath(path))
    if os.path.commonpath([base, target]) != base:
        raise InputError(f"{where} names {path}, outside the scene folder {folder}; {OUTSIDE_FIX}")
    return path
