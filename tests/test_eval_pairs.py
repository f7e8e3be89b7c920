"""Consistency pairs by camera pose (abcgs/evaluation/pairs.py): the pose distance, the path through the cameras,
and pairs that do not depend on the order the views come in."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.errors import InputError
from abcgs.evaluation.consistency import FlowCache, FlowEstimator, consistency
from abcgs.evaluation.pairs import (
    MIN_ANGLE_SCALE,
    consistency_pairs,
    index_pairs,
    path_pairs,
    pose_distances,
    pose_path,
)
from abcgs.evaluation.reference import compute_floor
from abcgs.scene.params import TinySceneParams
from abcgs.scene.synthetic import grid_cameras, ring_cameras


def cam(name: str, eye, target=(0.0, 0.0, 10.0)) -> Camera:
    return Camera(name, intrinsics(50.0, 64, 48), look_at(np.asarray(eye, float), np.asarray(target, float)), 64, 48)


def named_pairs(cams: list[Camera], pairs: list[tuple[int, int]]) -> list[tuple[str, str]]:
    return [(cams[i].name, cams[j].name) for i, j in pairs]


def shuffled(cams: list[Camera], seed: int) -> list[Camera]:
    return [cams[k] for k in np.random.default_rng(seed).permutation(len(cams))]


def scattered(n: int, seed: int = 0) -> list[Camera]:
    """A hand-held forward-facing capture: centres scattered in a plane, all looking at one point."""
    rng = np.random.default_rng(seed)
    return [cam(f"IMG_{k:04d}.jpg", (*rng.uniform(-2, 2, 2), 0.0)) for k in range(n)]


def test_pose_distance_is_the_stated_formula() -> None:
    """d = sqrt((|Δc| / s)² + (θ / s_θ)²), s and s_θ the medians of the nearest-neighbour distance and angle."""
    cams = [cam("a.png", (0, 0, 0)), cam("b.png", (1, 0, 0)), cam("c.png", (3, 0, 0))]
    d = pose_distances(cams)
    c = np.array([x.center for x in cams])
    v = np.array([x.viewmat[2, :3] for x in cams])
    dc = np.linalg.norm(c[:, None] - c[None], axis=-1)
    theta = np.arccos(np.clip(v @ v.T, -1, 1))
    s = np.median([1.0, 1.0, 2.0])  # nearest other centre of a, b, c
    nn_theta = [np.sort(row)[1] for row in theta]
    s_theta = max(np.median(nn_theta), MIN_ANGLE_SCALE)
    np.testing.assert_allclose(d, np.sqrt((dc / s) ** 2 + (theta / s_theta) ** 2), atol=1e-6)
    assert np.allclose(d, d.T) and np.all(np.diag(d) == 0)


def test_degenerate_captures_use_the_term_that_varies() -> None:
    """All cameras at one place (a panorama): the angle alone orders them; all looking one way: the centres alone."""
    pano = [cam(f"p{k}.png", (0, 0, 0), (10 * math.sin(a), 0, 10 * math.cos(a)))
            for k, a in enumerate(np.deg2rad([0, 40, 10, 30, 20]))]
    assert [pano[k].name for k in pose_path(pano)] == ["p0.png", "p2.png", "p4.png", "p3.png", "p1.png"]
    dolly = [Camera(f"d{k}.png", intrinsics(50.0, 64, 48), _translate(-x), 64, 48)
             for k, x in enumerate([0.0, 2.0, 1.0, 4.0, 3.0])]
    assert [dolly[k].name for k in pose_path(dolly)] == ["d0.png", "d2.png", "d1.png", "d4.png", "d3.png"]
    assert np.isfinite(pose_distances(dolly)).all() and np.isfinite(pose_distances(pano)).all()
    # views taken twice from the same place: the scale is the nearest *distinct* centre's, the centres still count
    twice = [cam(f"t{k}{r}.png", (x, 0, 0), (x, 0, 10)) for k, x in enumerate([0.0, 1.0, 2.0, 3.0]) for r in "ab"]
    d = pose_distances(twice)
    assert d[0, 2] == pytest.approx(1.0, rel=1e-6) and d[0, 1] == 0


def _translate(x: float) -> np.ndarray:
    m = np.eye(4)
    m[0, 3] = x
    return m


def test_a_straight_line_capture_gives_consecutive_pairs_in_any_file_order() -> None:
    eyes = [(0.3 * k, 0.01 * math.sin(k), 0.0) for k in range(12)]  # a dolly along x, slightly wobbly
    line = [cam(f"v{k:02d}.png", e) for k, e in enumerate(eyes)]
    for seed in range(3):
        cams = shuffled(line, seed)
        p = consistency_pairs(cams, "pose", 1, 7)
        short = named_pairs(cams, p.short)
        assert short == [(f"v{k:02d}.png", f"v{k + 1:02d}.png") for k in range(11)]
        assert named_pairs(cams, p.long) == [(f"v{k:02d}.png", f"v{k + 7:02d}.png") for k in range(5)]
        assert (p.short_gap, p.long_gap) == (1, 7)


@pytest.mark.parametrize("layout", ["forward", "orbit"])
def test_tiny_scene_pairs_do_not_depend_on_the_view_order(layout: str) -> None:
    """The tiny scene's camera layouts (a jittered serpentine grid, a ring): shuffling the cameras gives the same
    pairs of the same views, in the same direction; in file order the index pairs do change."""
    p = TinySceneParams(layout=layout)
    make = ring_cameras if layout == "orbit" else grid_cameras
    cams = make(p, np.random.default_rng(0))
    ref = consistency_pairs(cams, "pose", 1, 7)
    want = (named_pairs(cams, ref.short), named_pairs(cams, ref.long))
    for seed in range(4):
        perm = shuffled(cams, seed)
        got = consistency_pairs(perm, "pose", 1, 7)
        assert (named_pairs(perm, got.short), named_pairs(perm, got.long)) == want
        assert [perm[k].name for k in got.order] == [cams[k].name for k in ref.order]
    perm = shuffled(cams, 0)
    assert named_pairs(perm, consistency_pairs(perm, "index", 1, 7).short) != want[0]
    # every view is on the path once, and consecutive views are close: no step longer than 2.5 neighbour spacings
    d = pose_distances(cams)
    assert sorted(ref.order) == list(range(len(cams)))
    assert max(d[i, j] for i, j in ref.short) < 2.5
    if layout == "orbit":  # a ring is walked round: each short pair is a pair of ring neighbours
        ring = {frozenset((k, (k + 1) % len(cams))) for k in range(len(cams))}
        assert all(frozenset(pr) in ring for pr in ref.short)


def test_names_only_orient_the_path_and_break_ties() -> None:
    """Renaming the views of a generic capture keeps the same pairs up to direction."""
    cams = scattered(15, seed=3)
    pairs = {frozenset(p) for p in consistency_pairs(cams, "pose", 1, 7).short}
    renamed = [Camera(f"x{(7 * k) % 15:02d}.jpg", c.K, c.viewmat, c.width, c.height) for k, c in enumerate(cams)]
    assert {frozenset(p) for p in consistency_pairs(renamed, "pose", 1, 7).short} == pairs
    path = pose_path(cams)
    assert cams[path[0]].name < cams[path[-1]].name


def test_pose_path_is_shorter_than_file_order_for_scattered_photos() -> None:
    cams = scattered(20, seed=1)
    d = pose_distances(cams)
    path = pose_path(cams)

    def length(order):
        return sum(d[a, b] for a, b in zip(order[:-1], order[1:]))

    assert length(path) < 0.5 * length(list(range(20)))


def test_index_mode_is_list_order_and_gaps_clip() -> None:
    cams = scattered(5)
    p = consistency_pairs(cams, "index", 1, 7)
    assert p.short == [(0, 1), (1, 2), (2, 3), (3, 4)] and p.long == [(0, 4)] and p.long_gap == 4
    assert index_pairs(5, 1, 7) == p
    assert path_pairs([3, 1, 0, 2], 2) == [(3, 0), (1, 2)]
    with pytest.raises(InputError, match="at least 2 views"):
        consistency_pairs(cams[:1], "pose", 1, 7)
    with pytest.raises(InputError, match="pose | index"):
        consistency_pairs(cams, "random", 1, 7)
    assert p.to_json()["short"][0] == [0, 1]


# ---------------------------------------------------------------------------------------------- real capture
FERN = Path(__file__).resolve().parents[2] / "shared" / "data" / "scenes" / "fern"  # ../shared next to the repo


def fern_consistency(cams: list[Camera], photos: list[np.ndarray], mode: str) -> dict[str, float]:
    """Short/long warp RMSE of a view-consistent "stylization" (a fixed colour map of the photos), the floor (the
    photos against themselves) and the valid fractions, over ``mode`` pairs with DIS flow on the photos."""
    stylized = [np.ascontiguousarray(np.sqrt(p[..., ::-1])) for p in photos]
    pairs = consistency_pairs(cams, mode, 1, 7)
    flows = FlowCache(photos, FlowEstimator("dis"))
    floor = compute_floor(photos, pairs, flows)
    out = {}
    for kind in ("short", "long"):
        summary = consistency(photos, stylized, pairs.of(kind), flows, None)
        out |= {f"{kind}_rmse": summary.rmse, f"{kind}_valid": summary.valid_fraction,
                f"{kind}_floor": floor.of(kind).rmse}
    return out


def fern_views(scale: float = 0.5) -> tuple[list[Camera], list[np.ndarray]]:
    """Fern's 20 photos (504 × 378 in ../shared, resized by ``scale``) as the "renders", with LLFF's poses."""
    import cv2

    from abcgs.io.images import load_image
    from abcgs.sources.llff import llff_cameras

    paths = sorted(p for p in (FERN / "images").iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png"))
    photos = [load_image(p) for p in paths]
    h, w = photos[0].shape[:2]
    size = (round(w * scale), round(h * scale))
    photos = [cv2.resize(p, size, interpolation=cv2.INTER_AREA) for p in photos]
    return llff_cameras(FERN / "poses_bounds.npy", [p.name for p in paths], size), photos


@pytest.mark.shared_data
def test_shuffled_fern_equals_ordered_fern() -> None:
    """LLFF fern's photos and poses, in file order and shuffled: pose pairs give the same short/long warp RMSE
    (within 5 %; the pairs are the same, so in fact equal), index pairs do not."""
    if not (FERN / "images").is_dir() or not (FERN / "poses_bounds.npy").is_file():
        pytest.skip(f"real data not available at {FERN}")
    cams, photos = fern_views()
    perm = np.random.default_rng(0).permutation(len(cams))
    cams_s, photos_s = [cams[k] for k in perm], [photos[k] for k in perm]
    ordered, shuffled_ = fern_consistency(cams, photos, "pose"), fern_consistency(cams_s, photos_s, "pose")
    for key in ("short_rmse", "long_rmse", "short_floor", "long_floor"):
        assert shuffled_[key] == pytest.approx(ordered[key], rel=0.05), (key, ordered, shuffled_)
    assert np.isfinite(ordered["short_floor"]) and ordered["short_valid"] > 0.5
    index, index_s = fern_consistency(cams, photos, "index"), fern_consistency(cams_s, photos_s, "index")
    assert abs(index_s["short_rmse"] / index["short_rmse"] - 1) > 0.05  # file order matters for index pairs
    assert index_s["short_valid"] < ordered["short_valid"]


def test_llff_cameras_have_opencv_axes(tmp_path: Path) -> None:
    """LLFF's camera-to-world columns are (down, right, back); the viewmat is world→camera in OpenCV axes."""
    from abcgs.sources.llff import llff_cameras

    row = np.zeros((3, 5))
    row[:, 0], row[:, 1], row[:, 2] = (0, -1, 0), (1, 0, 0), (0, 0, 1)  # world y up, the camera looks along −z
    row[:, 3] = (0.5, 0.0, 0.0)
    row[:, 4] = (3024, 4032, 3260)
    np.save(tmp_path / "poses_bounds.npy", np.concatenate([row.reshape(-1), [1.0, 10.0]])[None])
    (c,) = llff_cameras(tmp_path / "poses_bounds.npy", ["a.jpg"], (504, 378))
    np.testing.assert_allclose(c.center, [0.5, 0, 0])
    to_cam = lambda p: (c.viewmat @ np.array([*p, 1.0]))[:3]  # noqa: E731
    np.testing.assert_allclose(to_cam((0.5, 0, -5)), [0, 0, 5])  # in front
    assert to_cam((1.5, 0, -5))[0] > 0 and to_cam((0.5, 1, -5))[1] < 0  # right is +x, up is −y
    assert c.K[0, 0] == pytest.approx(3260 * 504 / 4032) and c.K[1, 1] == pytest.approx(3260 * 378 / 3024)
    assert (c.width, c.height, c.K[0, 2], c.K[1, 2]) == (504, 378, 252, 189)
    with pytest.raises(InputError, match="1 poses for 2 images"):
        llff_cameras(tmp_path / "poses_bounds.npy", ["a.jpg", "b.jpg"], (504, 378))
