"""Camera paths for videos: a spiral through a forward-facing capture (LLFF-style render path)."""

from __future__ import annotations

import numpy as np

from abcgs.cameras import Camera, look_at


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
