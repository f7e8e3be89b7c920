"""Camera paths for videos and the viewer: a spiral through a forward-facing capture (LLFF-style render
path) or an orbit around an object-centred one, and the detection of which of the two a capture is.

Conventions: world→camera ``viewmat`` with OpenCV axes (x right, y down, z forward), as
:class:`abcgs.cameras.Camera`; positions in world units.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from abcgs.cameras import Camera, look_at
from abcgs.types import PathKind


def spiral_path(cameras: list[Camera], n_frames: int = 60, focus_depth: float | None = None, rots: float = 1.0) -> list[Camera]:
    """Cameras on an ellipse-spiral around the mean pose of ``cameras``, looking at a focus point.

    The mean pose's axes are averaged from the input views; the spiral's radii are the 90th percentile of
    the centres' spread along the mean x/y axes; ``focus_depth`` (world units along the mean viewing
    direction) defaults to 4× the largest radius. Intrinsics and size are those of the first camera.
    """
    if not cameras:
        raise ValueError("spiral_path needs at least one camera")
    centers = np.stack([c.center for c in cameras])
    rots_w = np.stack([c.viewmat[:3, :3].T for c in cameras])  # camera→world rotations; columns = axes
    x_axis, y_axis, z_axis = (rots_w[:, :, i].mean(0) for i in range(3))
    z_axis /= np.linalg.norm(z_axis)
    x_axis -= z_axis * (x_axis @ z_axis)
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(z_axis, x_axis)
    c0 = centers.mean(0)
    off = centers - c0
    rx = max(float(np.percentile(np.abs(off @ x_axis), 90)), 1e-3)
    ry = max(float(np.percentile(np.abs(off @ y_axis), 90)), 1e-3)
    focus = c0 + z_axis * (focus_depth if focus_depth is not None else 4.0 * max(rx, ry))
    ref = cameras[0]
    out = []
    for i, t in enumerate(np.linspace(0.0, 2.0 * np.pi * rots, n_frames, endpoint=False)):
        eye = c0 + rx * np.cos(t) * x_axis + ry * np.sin(t) * y_axis + 0.25 * rx * np.sin(0.5 * t) * z_axis
        out.append(Camera(f"spiral_{i:03d}", ref.K.copy(), look_at(eye, focus, up=y_axis), ref.width, ref.height))
    return out


ORBIT_MIN_SPAN_DEG = 100.0
"""A capture whose cameras surround their common look-at point over at least this azimuth span (seen along
the mean up axis) is object-centred; forward-facing LLFF captures span 5–30°."""


@dataclass(frozen=True)
class CaptureLayout:
    """How the cameras of a capture are arranged.

    Attributes:
        kind: ``"orbit"`` (cameras around an object) or ``"spiral"`` (forward-facing).
        center: ``(3,)`` the point closest to all optical axes (least squares), world units.
        down: ``(3,)`` unit mean image-down direction of the cameras in world coordinates.
        span_deg: azimuth range the camera centres cover around ``center`` about the ``down`` axis, degrees.
        radius: median horizontal distance of the camera centres from ``center``, world units.
        height: median offset of the camera centres from ``center`` along ``-down`` (up), world units.
    """

    kind: Literal["orbit", "spiral"]
    center: np.ndarray
    down: np.ndarray
    span_deg: float
    radius: float
    height: float


def _axes_meeting_point(centers: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Least-squares point closest to the lines ``centers[i] + t dirs[i]`` (a tiny ridge toward the mean centre
    keeps near-parallel axes, as in forward-facing captures, well posed)."""
    eye = np.eye(3)
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for c, d in zip(centers, dirs):
        proj = eye - np.outer(d, d)
        a += proj
        b += proj @ c
    ridge = 1e-6 * np.trace(a)
    return np.linalg.solve(a + ridge * eye, b + ridge * centers.mean(0))


def _azimuth_span_deg(angles: np.ndarray) -> float:
    """Smallest arc (degrees) containing all ``angles`` (radians): 360° minus the largest gap between them."""
    if len(angles) < 2:
        return 0.0
    a = np.sort(np.mod(angles, 2 * np.pi))
    gaps = np.diff(np.concatenate([a, a[:1] + 2 * np.pi]))
    return float(np.degrees(2 * np.pi - gaps.max()))


def _plane_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def capture_layout(cameras: list[Camera]) -> CaptureLayout:
    """Classify a capture as object-centred (``orbit``) or forward-facing (``spiral``) from its camera poses.

    The cameras' optical axes are intersected in the least-squares sense; the capture is object-centred when
    that point lies in front of at least 80 % of the cameras and the camera centres surround it over at
    least :data:`ORBIT_MIN_SPAN_DEG` of azimuth about the mean up axis.
    """
    if len(cameras) < 2:
        raise ValueError("capture_layout needs at least two cameras")
    centers = np.stack([c.center for c in cameras])
    dirs = np.stack([c.viewmat[2, :3] for c in cameras])  # camera +z (forward) in world
    down = np.stack([c.viewmat[1, :3] for c in cameras]).mean(0)
    down /= max(np.linalg.norm(down), 1e-12)
    center = _axes_meeting_point(centers, dirs)
    in_front = float(np.mean(((center - centers) * dirs).sum(1) > 0))
    off = centers - center
    up_part = -(off @ down)
    flat = off + np.outer(up_part, down)  # components perpendicular to the up axis
    e1, e2 = _plane_basis(down)
    span = _azimuth_span_deg(np.arctan2(flat @ e2, flat @ e1))
    kind = "orbit" if in_front >= 0.8 and span >= ORBIT_MIN_SPAN_DEG else "spiral"
    return CaptureLayout(kind, center, down, span, float(np.median(np.linalg.norm(flat, axis=1))),
                         float(np.median(up_part)))


def orbit_path(cameras: list[Camera], n_frames: int = 60, layout: CaptureLayout | None = None) -> list[Camera]:
    """Cameras on a full circle around the capture's look-at point, at the cameras' median radius and height,
    starting at the first camera's azimuth and turning the way the capture goes. Intrinsics and size are
    those of the first camera."""
    if not cameras:
        raise ValueError("orbit_path needs at least one camera")
    lay = layout or capture_layout(cameras)
    e1, e2 = _plane_basis(lay.down)
    off = np.stack([c.center for c in cameras]) - lay.center
    ang = np.unwrap(np.arctan2(off @ e2, off @ e1))
    turn = 1.0 if len(ang) < 2 or ang[-1] >= ang[0] else -1.0
    ref = cameras[0]
    out = []
    for i, t in enumerate(np.linspace(0.0, 2.0 * np.pi, n_frames, endpoint=False)):
        a = ang[0] + turn * t
        eye = lay.center - lay.height * lay.down + lay.radius * (np.cos(a) * e1 + np.sin(a) * e2)
        out.append(Camera(f"orbit_{i:03d}", ref.K.copy(), look_at(eye, lay.center, up=lay.down), ref.width, ref.height))
    return out


def camera_path(cameras: list[Camera], kind: PathKind = "auto", n_frames: int = 60) -> tuple[list[Camera], str]:
    """The video/viewer path for a capture: ``(cameras, kind used)``; ``auto`` follows :func:`capture_layout`."""
    used = capture_layout(cameras).kind if kind == "auto" else kind
    if used == "orbit":
        return orbit_path(cameras, n_frames), used
    if used == "spiral":
        return spiral_path(cameras, n_frames), used
    raise ValueError(f"unknown camera path {kind!r} (auto | spiral | orbit)")
