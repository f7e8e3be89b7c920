"""Structure from motion (pycolmap), reading a reconstructed scene's model and similarity alignment."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from abcgs.errors import InputError, ReconstructionError
from abcgs.io.images import list_images, load_image, load_labels, save_image
from abcgs.scene.synthetic import cameras_from_json
from abcgs.sfm.align import alignment_residual, umeyama
from abcgs.sfm.colmap import reconstruct
from abcgs.sfm.model import read_scene
from abcgs.sfm.params import ReconstructParams
from abcgs.sources.llff import llff_camera_centres
from abcgs.sources.photos import reconstruct_photos

FERN = Path(__file__).resolve().parents[2] / "shared" / "data" / "scenes" / "fern"  # ../shared next to the repo


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


# ---------------------------------------------------------------------------------- alignment


def test_umeyama_recovers_known_similarity() -> None:
    rng = np.random.default_rng(0)
    src = rng.normal(size=(20, 3))
    R, s, t = _random_rotation(rng), 2.7, np.array([1.0, -3.0, 0.5])
    sim = umeyama(src, s * src @ R.T + t)
    assert sim.scale == pytest.approx(s, rel=1e-10)
    np.testing.assert_allclose(sim.R, R, atol=1e-10)
    np.testing.assert_allclose(sim.t, t, atol=1e-10)


def test_alignment_residual_is_relative_to_extent() -> None:
    rng = np.random.default_rng(1)
    dst = rng.normal(size=(50, 3))
    src = (dst + rng.normal(scale=0.01, size=dst.shape)) * 0.3  # noisy and scaled copy
    rms, rel, sim = alignment_residual(src, dst)
    extent = np.sqrt(((dst - dst.mean(0)) ** 2).sum(1).mean())
    assert sim.scale == pytest.approx(1 / 0.3, rel=0.02)
    assert rms == pytest.approx(0.01 * np.sqrt(3), rel=0.2)  # the injected noise, in dst units
    assert rel == pytest.approx(rms / extent)


def test_umeyama_rejects_bad_shapes() -> None:
    with pytest.raises(InputError, match="at least 3"):
        umeyama(np.zeros((2, 3)), np.zeros((2, 3)))


def test_llff_centres(tmp_path: Path) -> None:
    poses = np.zeros((4, 3, 5))
    poses[:, :, 3] = np.arange(12).reshape(4, 3)
    np.save(tmp_path / "poses_bounds.npy", np.concatenate([poses.reshape(4, 15), np.ones((4, 2))], axis=1))
    np.testing.assert_array_equal(llff_camera_centres(tmp_path / "poses_bounds.npy"), np.arange(12).reshape(4, 3))


# ---------------------------------------------------------------------------------- tiny scene


def test_tiny_registers_all_views(tiny_scene: Path, tiny_colmap: Path) -> None:
    metrics = json.loads((tiny_colmap / "metrics.json").read_text())
    n = len(list_images(tiny_scene / "images"))
    assert metrics["registered"] == metrics["total"] == n and metrics["unregistered"] == []
    assert metrics["points"] > 200 and metrics["mean_reprojection_error_px"] < 1.0
    assert "seconds" not in metrics  # the folder is every later stage's dep: no wall time in it
    for name in ("cameras.bin", "images.bin", "points3D.bin"):
        assert (tiny_colmap / "sparse" / name).is_file()


def test_tiny_poses_match_ground_truth(tiny_scene: Path, tiny_colmap: Path) -> None:
    data = read_scene(tiny_colmap)
    gt = {c.name: c for c in cameras_from_json(json.loads((tiny_scene / "cameras.json").read_text()))}
    src = np.array([c.center for c in data.cameras])
    dst = np.array([gt[c.name].center for c in data.cameras])
    _, rel, _ = alignment_residual(src, dst)
    assert rel < 0.03, f"camera centres off by {rel:.1%} of the rig extent"
    # Focal length is recovered too (undistorted PINHOLE keeps COLMAP's focal).
    assert data.cameras[0].K[0, 0] == pytest.approx(gt[data.cameras[0].name].K[0, 0], rel=0.05)


def test_reconstruct_is_repeatable(tiny_scene: Path, tiny_colmap: Path, tmp_path: Path) -> None:
    reconstruct(tiny_scene / "images", tmp_path / "again", ReconstructParams())
    for name in ("cameras.bin", "images.bin", "points3D.bin"):
        assert (tmp_path / "again" / "sparse" / name).read_bytes() == (tiny_colmap / "sparse" / name).read_bytes()


def _layout_with_model(tiny_colmap: Path, root: Path, rec: Any, text: bool = False) -> Path:
    """A copy of the layout ``tiny_colmap`` (images, label maps, ``scene.json``) whose ``sparse/`` is the pycolmap
    reconstruction ``rec`` (written as text or binary; ``None``: no model at all)."""
    shutil.copytree(tiny_colmap, root, ignore=shutil.ignore_patterns("sparse"))
    if rec is not None:
        (root / "sparse").mkdir()
        (rec.write_text if text else rec.write_binary)(str(root / "sparse"))
    return root


def test_read_scene_gives_the_models_views_and_points(tiny_colmap: Path) -> None:
    data = read_scene(tiny_colmap)
    names = [c.name for c in data.cameras]
    assert names == sorted(names) and [p.name for p in data.image_paths] == names
    for cam, path in zip(data.cameras, data.image_paths):
        assert load_image(path).shape[:2] == (cam.height, cam.width)
        assert cam.K[0, 1] == 0 and cam.K[2, 2] == 1 and cam.viewmat.shape == (4, 4)
    assert data.points.dtype == np.float32 and data.points.shape[1] == 3
    assert data.colors.dtype == np.float32 and data.colors.shape == data.points.shape
    assert 0.0 <= data.colors.min() and data.colors.max() <= 1.0
    # Most SfM points lie in front of the cameras that see them.
    cam = data.cameras[0]
    depth = data.points @ cam.viewmat[:3, :3].T[:, 2] + cam.viewmat[2, 3]
    assert (depth > 0).mean() > 0.99


@pytest.mark.parametrize("fmt", ["bin", "txt"])
def test_read_scene_equals_pycolmaps_reading(tiny_colmap: Path, tmp_path: Path, fmt: str) -> None:
    """A layout's scene (its model read by abcgs.io.colmap) holds pycolmap's cameras, poses and points (by id), from
    a binary model and from a text one."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(tiny_colmap / "sparse"))
    layout = tiny_colmap
    if fmt == "txt":
        layout = _layout_with_model(tiny_colmap, tmp_path / "txt", rec, text=True)
        assert not list((layout / "sparse").glob("*.bin"))
    data = read_scene(layout)
    images = sorted((im for im in rec.images.values() if im.has_pose), key=lambda im: im.name)
    assert [c.name for c in data.cameras] == [im.name for im in images]
    for cam, im in zip(data.cameras, images):
        pc = rec.cameras[im.camera_id]
        np.testing.assert_allclose(cam.K, pc.calibration_matrix(), rtol=0, atol=1e-9)
        np.testing.assert_allclose(cam.viewmat[:3], im.cam_from_world().matrix(), rtol=0, atol=1e-9)
        assert (cam.width, cam.height) == (pc.width, pc.height)
    pts = [rec.points3D[i] for i in sorted(rec.points3D)]  # the canonical order: by point id
    np.testing.assert_array_equal(data.points, np.array([p.xyz for p in pts], np.float32))
    np.testing.assert_allclose(data.colors, np.array([p.color for p in pts], np.float32) / 255.0, atol=1e-7)


def test_read_scene_refuses_a_distorted_model(tiny_colmap: Path, tmp_path: Path) -> None:
    import pycolmap

    rec = pycolmap.Reconstruction(str(tiny_colmap / "sparse"))
    for cam in rec.cameras.values():
        cam.model = pycolmap.CameraModelId.SIMPLE_RADIAL
        cam.params = [cam.focal_length, cam.principal_point_x, cam.principal_point_y, 0.01]
    layout = _layout_with_model(tiny_colmap, tmp_path / "layout", rec)
    with pytest.raises(InputError, match="SIMPLE_RADIAL camera.*undistorted"):
        read_scene(layout)


def test_masks_are_undistorted_with_the_images(tiny_colmap: Path) -> None:
    for img in list_images(tiny_colmap / "images"):
        h, w = load_image(img).shape[:2]
        labels = load_labels(tiny_colmap / "masks" / f"{img.stem}.png", expect_hw=(h, w))
        assert set(np.unique(labels)) <= {0, 1, 2, 3} and (labels == 3).any()


def test_read_scene_rejects_a_layout_without_its_model(tiny_colmap: Path, tmp_path: Path) -> None:
    layout = _layout_with_model(tiny_colmap, tmp_path / "layout", None)
    with pytest.raises(InputError, match="sparse is not a COLMAP model"):
        read_scene(layout)


# ---------------------------------------------------------------------------------- failure paths


def _copy_views(tiny_scene: Path, dst: Path, count: int) -> Path:
    dst.mkdir(parents=True)
    for p in list_images(tiny_scene / "images")[:count]:
        shutil.copy(p, dst / p.name)
    return dst


def test_fewer_than_three_images(tiny_scene: Path, tmp_path: Path) -> None:
    images = _copy_views(tiny_scene, tmp_path / "images", 2)
    with pytest.raises(InputError, match="2 image"):
        reconstruct(images, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_corrupt_image_is_named(tiny_scene: Path, tmp_path: Path) -> None:
    images = _copy_views(tiny_scene, tmp_path / "images", 4)
    (images / "zz_broken.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 50)
    with pytest.raises(InputError, match="zz_broken.png"):
        reconstruct(images, tmp_path / "out")


def test_mixed_sizes_with_forced_single_camera(tiny_scene: Path, tmp_path: Path) -> None:
    images = _copy_views(tiny_scene, tmp_path / "images", 4)
    save_image(images / "zz_small.png", load_image(images / "000.png")[:100, :120])
    with pytest.raises(InputError, match="different sizes"):
        reconstruct(images, tmp_path / "out", ReconstructParams(single_camera=True))


def test_too_few_registered_names_counts_and_images(tiny_scene: Path, tmp_path: Path) -> None:
    images = _copy_views(tiny_scene, tmp_path / "images", 6)
    rng = np.random.default_rng(0)
    for i in range(3):  # unrelated pictures: smooth random blobs
        noise = rng.random((12, 16, 3)).astype(np.float32)
        save_image(images / f"noise_{i}.png", np.kron(noise, np.ones((10, 10, 1), np.float32)))
    with pytest.raises(ReconstructionError) as err:
        reconstruct(images, tmp_path / "out", ReconstructParams(min_registered_fraction=0.9))
    msg = str(err.value)
    assert "6 of 9" in msg and "noise_0.png" in msg and "overlap" in msg
    assert not (tmp_path / "out").exists()
    # A lower threshold keeps the partial model and lists what is missing.
    report = reconstruct(images, tmp_path / "out", ReconstructParams(min_registered_fraction=0.5))
    assert report.registered == 6 and report.unregistered == [f"noise_{i}.png" for i in range(3)]
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["unregistered"] == report.unregistered


def test_params_reject_unknown_fields() -> None:
    with pytest.raises(ValueError):
        ReconstructParams(matcher="vocab")
    with pytest.raises(ValueError):
        ReconstructParams(min_registered=0.5)


def test_sift_options_reach_the_extractor(tiny_scene: Path, tmp_path: Path) -> None:
    """``sift_peak_threshold`` and ``sift_domain_size_pooling`` are what COLMAP extracts with: a lower peak threshold
    finds more keypoints on the same views, and DSP gives other descriptors."""
    import pycolmap

    from abcgs.sfm.colmap import extract_features

    names = [p.name for p in list_images(tiny_scene / "images")][:2]

    def extracted(**kw) -> tuple[int, np.ndarray]:
        db = tmp_path / f"{len(list(tmp_path.iterdir()))}.db"
        extract_features(db, tiny_scene / "images", names, ReconstructParams(**kw), True)
        with pycolmap.Database.open(db) as d:
            image_id = d.read_all_images()[0].image_id
            return sum(d.num_keypoints_for_image(im.image_id) for im in d.read_all_images()), d.read_descriptors(image_id)

    n_default, desc_default = extracted()
    n_low, _ = extracted(sift_peak_threshold=0.001)
    assert n_low > n_default > 0
    n_dsp, desc_dsp = extracted(sift_domain_size_pooling=True)
    a, b = np.asarray(desc_dsp.data), np.asarray(desc_default.data)
    assert a.shape != b.shape or not np.array_equal(a, b)


# ---------------------------------------------------------------------------------- real data


@pytest.mark.shared_data
def test_fern_registers_all_and_matches_llff_poses(tmp_path: Path) -> None:
    if not (FERN / "images").is_dir():
        pytest.skip(f"real data not available at {FERN}")
    report = reconstruct_photos(FERN, tmp_path / "colmap", ReconstructParams())
    assert report.registered == report.total == 20
    data = read_scene(tmp_path / "colmap")
    names = [p.name for p in list_images(FERN / "images")]
    llff = dict(zip(names, llff_camera_centres(FERN / "poses_bounds.npy")))
    src = np.array([c.center for c in data.cameras])
    dst = np.array([llff[c.name] for c in data.cameras])
    _, rel, _ = alignment_residual(src, dst)
    assert rel < 0.05, f"fern camera centres differ from LLFF's by {rel:.1%} of the extent"
