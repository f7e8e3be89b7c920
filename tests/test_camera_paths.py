"""Camera paths: spiral for forward-facing captures, orbit for object-centred ones, and the detection."""

from __future__ import annotations

import numpy as np
import pytest

from abcgs.camera_paths import camera_path, capture_layout, orbit_path, spiral_path
from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.scene.params import TinySceneParams
from abcgs.scene.synthetic import grid_cameras


def ring_cameras(n: int = 24, arc_deg: float = 300.0, radius: float = 3.0, height: float = 1.0,
                 center=(0.5, -0.2, 2.0), seed: int = 0) -> list[Camera]:
    """Cameras on an arc around ``center`` (world y down, so 'up' is −y), looking at it, with a little jitter."""
    rng = np.random.default_rng(seed)
    c = np.asarray(center, float)
    K = intrinsics(100.0, 160, 120)
    cams = []
    for i, a in enumerate(np.radians(np.linspace(0.0, arc_deg, n))):
        eye = c + np.array([radius * np.cos(a), -height, radius * np.sin(a)]) + rng.normal(0, 0.03, 3)
        cams.append(Camera(f"{i:03d}.png", K, look_at(eye, c + rng.normal(0, 0.03, 3), up=np.array([0.0, 1.0, 0.0])),
                           160, 120))
    return cams


def project(cam: Camera, p: np.ndarray) -> np.ndarray:
    q = cam.viewmat[:3, :3] @ p + cam.viewmat[:3, 3]
    return (cam.K @ (q / q[2]))[:2]


def test_object_centred_capture_is_detected_and_gets_an_orbit() -> None:
    cams = ring_cameras()
    lay = capture_layout(cams)
    assert lay.kind == "orbit" and lay.span_deg > 250
    np.testing.assert_allclose(lay.center, [0.5, -0.2, 2.0], atol=0.05)
    np.testing.assert_allclose(lay.down, [0.0, 1.0, 0.0], atol=0.05)  # the cameras' image-down is world +y
    assert abs(lay.radius - 3.0) < 0.05 and abs(lay.height - 1.0) < 0.05
    path, kind = camera_path(cams, "auto", n_frames=36)
    assert kind == "orbit" and len(path) == 36
    for cam in path:  # every frame looks at the centre, from the capture's radius and height
        np.testing.assert_allclose(project(cam, lay.center), [80.0, 60.0], atol=1e-6)
        off = cam.center - lay.center
        assert abs(-(off @ lay.down) - lay.height) < 1e-6
        assert abs(np.linalg.norm(off + (-(off @ lay.down)) * lay.down) - lay.radius) < 1e-6
    # starts where the capture starts and turns the way it turns
    assert np.linalg.norm(path[0].center - cams[0].center) < 0.25  # jitter: camera 0 is 0.15 above the median height
    assert np.linalg.norm(path[1].center - cams[1].center) < np.linalg.norm(path[-1].center - cams[1].center)


def test_forward_facing_capture_keeps_the_spiral() -> None:
    cams = grid_cameras(TinySceneParams(), np.random.default_rng(0))
    lay = capture_layout(cams)
    assert lay.kind == "spiral" and lay.span_deg < 60
    path, kind = camera_path(cams, "auto", n_frames=12)
    assert kind == "spiral"
    ref = spiral_path(cams, 12)
    assert all(np.allclose(a.viewmat, b.viewmat) for a, b in zip(path, ref))


def test_a_short_arc_is_not_an_orbit_and_the_kind_can_be_forced() -> None:
    cams = ring_cameras(n=10, arc_deg=40.0)
    assert capture_layout(cams).kind == "spiral"
    path, kind = camera_path(cams, "orbit", n_frames=8)
    assert kind == "orbit" and len(path) == 8
    assert len(orbit_path(cams, 5)) == 5
    with pytest.raises(ValueError, match="unknown camera path"):
        camera_path(cams, "helix")
    with pytest.raises(ValueError, match="at least two"):
        capture_layout(cams[:1])
