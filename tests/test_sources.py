"""Scene readers (abcgs/sources): the tiny scene written out in each dataset format re-imports to its own cameras.

"Same cameras" is measured the way it matters: the tiny scene's ground truth (its ray caster) rendered through the
re-imported camera against the render through the original camera, >= 40 dB PSNR (identical cameras give identical
renders). A wrong axis convention, a model that does not fit its images, and mismatched image folders fail at import
with a message naming the file.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.fit.metrics import psnr
from abcgs.io.images import load_image, load_labels, save_image
from abcgs.scene.params import TinySceneParams
from abcgs.scene.synthetic import _textures, cameras_from_json, render_view, scene_layout
from abcgs.sfm.model import read_scene
from abcgs.sfm.params import ReconstructParams
from abcgs.sources.detect import detect_format
from abcgs.sources.model import write_source_model
from abcgs.sources.read import read_source

OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])
NERFSTUDIO_A = np.array([[0.0, 1.0, 0.0, 0.3], [1.0, 0.0, 0.0, -0.2], [0.0, 0.0, -1.0, 0.5]])
"""nerfstudio's ``applied_transform`` (its COLMAP axis swap) with a translation added."""


# ------------------------------------------------------------------------------------------ the tiny scene's truth


@pytest.fixture(scope="module")
def truth(tiny_scene: Path):
    """The tiny scene's cameras and a renderer of its ground truth (1 ray per pixel)."""
    data = json.loads((tiny_scene / "cameras.json").read_text())
    p = TinySceneParams(**data["params"])
    textures = _textures(np.random.default_rng(p.seed), p)  # the generator's first draws, as in generate_tiny_scene
    layout = scene_layout(p)
    return cameras_from_json(data), lambda cam: render_view(cam, layout, textures, 1)[0]


def assert_same_cameras(got: list[Camera], want: list[Camera], render, names: dict[str, str] | None = None) -> None:
    """Every 5th view: the ground truth through ``got`` within 40 dB of it through ``want`` (paired by name;
    ``names`` maps a re-imported name to the original's)."""
    by_name = {c.name: c for c in want}
    assert len(got) == len(want)
    for cam in got[::5]:
        ref = by_name[(names or {}).get(cam.name, cam.name)]
        assert (cam.width, cam.height) == (ref.width, ref.height)
        assert psnr(render(cam), render(ref)) >= 40.0, cam.name


def _gt_points(cams: list[Camera], n: int = 400, seed: int = 0) -> np.ndarray:
    """Points in front of the first camera, 3–6 units deep (inside every view of the forward-facing grid)."""
    rng = np.random.default_rng(seed)
    cam = cams[0]
    uv = np.stack([rng.uniform(0.2, 0.8, n) * cam.width, rng.uniform(0.2, 0.8, n) * cam.height, np.ones(n)], 1)
    p_cam = (uv @ np.linalg.inv(cam.K).T) * rng.uniform(3.0, 6.0, n)[:, None]
    return (p_cam - cam.viewmat[:3, 3]) @ cam.viewmat[:3, :3]


def _copy_images(src: Path, dst: Path, scale: float = 1.0) -> None:
    dst.mkdir(parents=True, exist_ok=True)
    for p in sorted(src.glob("*.png")):
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if scale != 1.0:
            img = cv2.resize(img, (round(img.shape[1] * scale), round(img.shape[0] * scale)), interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(dst / p.name), img)


# ------------------------------------------------------------------------------------------ writers of each format


def write_colmap(folder: Path, cams: list[Camera], *, k: float = 0.02, text: bool = False) -> Path:
    """A COLMAP model of ``cams`` with SIMPLE_RADIAL cameras (radial ``k``) and some points, in ``folder/sparse/0``."""
    rec = pycolmap.Reconstruction()
    for i, c in enumerate(cams, start=1):
        cam = pycolmap.Camera(model="SIMPLE_RADIAL", width=c.width, height=c.height,
                              params=[c.K[0, 0], c.K[0, 2], c.K[1, 2], k], camera_id=i)
        rec.add_camera_with_trivial_rig(cam)
        rec.add_image_with_trivial_frame(pycolmap.Image(name=c.name, camera_id=i, image_id=i),
                                         pycolmap.Rigid3d(c.viewmat[:3, :]))
    for p in _gt_points(cams):
        rec.add_point3D(p, pycolmap.Track(), np.array([128, 128, 128], np.uint8))
    model = folder / "sparse" / "0"
    model.mkdir(parents=True)
    rec.write_text(str(model)) if text else rec.write_binary(str(model))
    return model


def write_nerfstudio(folder: Path, tiny: Path, cams: list[Camera], *, scale: float = 2.0, opengl: bool = True) -> None:
    """``transforms.json`` in nerfstudio's frame (``applied_transform``, ``applied_scale``), OpenGL camera axes (or
    OpenCV ones: the deliberate mistake), intrinsics global and per frame, masks for the first views, a point PLY."""
    from plyfile import PlyData, PlyElement

    S = np.diag([scale, scale, scale, 1.0]) @ np.vstack([NERFSTUDIO_A, [0, 0, 0, 1]])
    _copy_images(tiny / "images", folder / "images")
    (folder / "masks").mkdir()
    frames = []
    for i, c in enumerate(cams):
        c2w = np.linalg.inv(c.viewmat) @ (OPENGL if opengl else np.eye(4))
        pose = np.eye(4)
        pose[:3, :3] = NERFSTUDIO_A[:, :3] @ c2w[:3, :3]
        pose[:3, 3] = (S @ np.append(c2w[:3, 3], 1.0))[:3]
        frame = {"file_path": f"images/{c.name}", "transform_matrix": pose.tolist()}
        if i % 2:  # per-frame intrinsics on odd frames, the file's on even ones
            frame.update(fl_x=c.K[0, 0], fl_y=c.K[1, 1], cx=c.K[0, 2], cy=c.K[1, 2], w=c.width, h=c.height)
        if i < 3:
            labels = load_labels(tiny / "masks" / c.name)
            cv2.imwrite(str(folder / "masks" / c.name), np.where(labels >= 2, 255, 0).astype(np.uint8))
            frame["mask_path"] = f"masks/{c.name}"
        frames.append(frame)
    c0 = cams[0]
    pts = _gt_points(cams) @ S[:3, :3].T + S[:3, 3]
    vertex = np.array([(*p, 200, 100, 50) for p in pts],
                      dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    PlyData([PlyElement.describe(vertex, "vertex")]).write(str(folder / "sparse_pc.ply"))
    meta = {"camera_model": "OPENCV", "fl_x": c0.K[0, 0], "fl_y": c0.K[1, 1], "cx": c0.K[0, 2], "cy": c0.K[1, 2],
            "w": c0.width, "h": c0.height, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
            "applied_transform": NERFSTUDIO_A.tolist(), "applied_scale": scale, "ply_file_path": "sparse_pc.ply",
            "frames": frames}
    (folder / "transforms.json").write_text(json.dumps(meta))


def write_blender(folder: Path, tiny: Path, cams: list[Camera], *, opengl: bool = True) -> None:
    """NeRF-synthetic layout: even views in train/, odd in test/, RGBA with the box and sphere opaque (labels 2, 3)
    and garbage colours under the transparent wall."""
    for split, part in (("train", cams[0::2]), ("test", cams[1::2])):
        (folder / split).mkdir(parents=True)
        frames = []
        for c in part:
            rgb = cv2.imread(str(tiny / "images" / c.name))
            alpha = np.where(load_labels(tiny / "masks" / c.name) >= 2, 255, 0).astype(np.uint8)
            rgb[alpha == 0] = (13, 200, 77)
            cv2.imwrite(str(folder / split / c.name), np.dstack([rgb, alpha]))
            c2w = np.linalg.inv(c.viewmat) @ (OPENGL if opengl else np.eye(4))
            frames.append({"file_path": f"./{split}/{Path(c.name).stem}", "rotation": 0.0, "transform_matrix": c2w.tolist()})
        angle = 2 * math.atan(part[0].width / (2 * part[0].K[0, 0]))
        (folder / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": angle, "frames": frames}))


def write_llff(folder: Path, tiny: Path, cams: list[Camera], *, full: int = 4) -> None:
    """``poses_bounds.npy`` for a capture ``full`` times the images' size (LLFF's ``hwf``) and the images."""
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for c in cams:
        c2w = np.linalg.inv(c.viewmat)
        pose = np.stack([c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3],
                         [c.height * full, c.width * full, c.K[0, 0] * full]], axis=1)
        rows.append(np.concatenate([pose.reshape(-1), [1.0, 12.0]]))
    np.save(folder / "poses_bounds.npy", np.array(rows))
    _copy_images(tiny / "images", folder / "images")


# ------------------------------------------------------------------------------------------ detection


def test_detect_format_from_the_folder_contents(tmp_path: Path, tiny_scene: Path, truth) -> None:
    cams, _ = truth
    assert detect_format(tiny_scene) == "photos"
    for name, write in (("c", lambda f: write_colmap(f, cams)), ("n", lambda f: write_nerfstudio(f, tiny_scene, cams)),
                        ("b", lambda f: write_blender(f, tiny_scene, cams)), ("l", lambda f: write_llff(f, tiny_scene, cams))):
        (tmp_path / name).mkdir()
        write(tmp_path / name)
    assert [detect_format(tmp_path / n) for n in "cnbl"] == ["colmap", "nerfstudio", "blender", "llff"]
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "scene.splat").write_bytes(b"\0" * 32)
    assert detect_format(tmp_path / "s") == "splat" and detect_format(tmp_path / "s" / "scene.splat") == "splat"
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"empty: no scene found \(it is empty\); put the photos in .*empty/images/"):
        detect_format(tmp_path / "empty")
    (tmp_path / "m" / "sparse").mkdir(parents=True)
    with pytest.raises(InputError, match=r"m/sparse has no cameras\.bin/cameras\.txt .*copy the COLMAP model there"):
        detect_format(tmp_path / "m")
    with pytest.raises(InputError, match="nowhere does not exist"):
        detect_format(tmp_path / "nowhere")


# ------------------------------------------------------------------------------------------ colmap


@pytest.mark.parametrize("text", [False, True], ids=["binary", "text"])
def test_colmap_simple_radial_at_full_and_quarter_size(tmp_path: Path, tiny_scene: Path, truth, text: bool) -> None:
    """SIMPLE_RADIAL at the full size with images/ and with images_4/ (¼ size): the pinhole part and the lens are
    scaled to the images, the poses kept."""
    cams, render = truth
    write_colmap(tmp_path, cams, text=text)
    _copy_images(tiny_scene / "images", tmp_path / "images")
    _copy_images(tiny_scene / "images", tmp_path / "images_4", scale=0.25)
    full = read_source(tmp_path, "colmap")
    assert_same_cameras(full.cameras, cams, render)
    assert all(v.distortion.model == "SIMPLE_RADIAL" and v.distortion.params[3] == pytest.approx(0.02) for v in full.views)
    quarter = read_source(tmp_path, "colmap", images="images_4")
    assert_same_cameras(quarter.cameras, [c.scaled(0.25) for c in cams], render)
    f, cx, cy, k = quarter.views[0].distortion.params
    assert (f, cx, cy, k) == pytest.approx((cams[0].K[0, 0] / 4, cams[0].K[0, 2] / 4, cams[0].K[1, 2] / 4, 0.02))
    assert any("scaled to the 40x30 images of images_4/" in n for n in quarter.notes)
    assert full.points.shape == (400, 3) and quarter.points is not None


def test_colmap_errors_name_the_file_and_the_fix(tmp_path: Path, tiny_scene: Path, truth) -> None:
    cams, _ = truth
    write_colmap(tmp_path, cams)
    _copy_images(tiny_scene / "images", tmp_path / "images_sq")
    for p in (tmp_path / "images_sq").iterdir():  # square: not the model's 4:3 picture at any scale
        cv2.imwrite(str(p), cv2.resize(cv2.imread(str(p)), (40, 40)))
    with pytest.raises(InputError, match=r"calibrated for 160x120 but the image is 40x40, which is not the same picture "
                                         r"at another scale .*`images:`"):
        read_source(tmp_path, "colmap", images="images_sq")
    (tmp_path / "other").mkdir()
    save_image(tmp_path / "other" / "IMG_0001.jpg", np.zeros((120, 160, 3), np.float32))
    with pytest.raises(InputError, match=r"none of the 16 images of the COLMAP model .*sparse/0 is in .*other "
                                         r"\(the model names 000\.png, .*the folder holds IMG_0001\.jpg\)"):
        read_source(tmp_path, "colmap", images="other")
    with pytest.raises(InputError, match=r"images holds no images, but the COLMAP model .* needs them"):
        read_source(tmp_path, "colmap")
    shutil.rmtree(tmp_path / "sparse")
    with pytest.raises(InputError, match=r"no COLMAP model \(looked for sparse/0/cameras\.bin"):
        read_source(tmp_path, "colmap")


def test_colmap_source_is_undistorted_into_the_reconstruct_layout(tmp_path: Path, tiny_scene: Path, truth) -> None:
    """A distorted model goes through COLMAP's undistorter: PINHOLE cameras with the same poses, the dataset's points
    kept, the scene's label maps undistorted beside the images."""
    cams, _ = truth
    scene = tmp_path / "scene"
    write_colmap(scene, cams, k=0.05)
    _copy_images(tiny_scene / "images", scene / "images")
    shutil.copytree(tiny_scene / "masks", scene / "masks")
    report = write_source_model(read_source(scene, "colmap"), tmp_path / "colmap", ReconstructParams(),
                                masks_dir=scene / "masks")
    assert report.undistorted and report.points_method == "dataset" and report.points == 400
    data = read_scene(tmp_path / "colmap")
    by_name = {c.name: c for c in cams}
    for cam in data.cameras:
        np.testing.assert_allclose(cam.viewmat, by_name[cam.name].viewmat, atol=1e-6)
        labels = load_labels(tmp_path / "colmap" / "masks" / cam.name, expect_hw=(cam.height, cam.width))
        assert set(np.unique(labels)) <= {0, 1, 2, 3}
    assert json.loads((tmp_path / "colmap" / "metrics.json").read_text())["points_method"] == "dataset"


def test_simple_radial_views_are_undistorted_onto_their_pinhole_cameras(tmp_path: Path, truth, monkeypatch) -> None:
    """Views rendered through a SIMPLE_RADIAL lens (k = 0.05) and written with it: the undistorted images the stage
    writes are the ground truth through the undistorted PINHOLE cameras it writes (≥ 30 dB, bilinear resampling of
    2×2-supersampled renders); the same images with the lens left out of the model stay far off (< 26 dB)."""
    import abcgs.scene.synthetic as synthetic

    cams = truth[0][::4]  # four views keep it quick
    pinhole_rays = synthetic._rays

    def lens_rays(cam: Camera):  # rays through the pixels of a SIMPLE_RADIAL camera (its k in cam.meta)
        if "k" not in cam.meta:
            return pinhole_rays(cam)
        lens = pycolmap.Camera(model="SIMPLE_RADIAL", width=cam.width, height=cam.height,
                               params=[cam.K[0, 0], cam.K[0, 2], cam.K[1, 2], cam.meta["k"]])
        u, v = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
        d = np.c_[lens.cam_from_img(np.stack([u.ravel(), v.ravel()], 1)), np.ones(u.size)] @ cam.viewmat[:3, :3]
        return cam.center, d / np.linalg.norm(d, axis=1, keepdims=True)

    monkeypatch.setattr(synthetic, "_rays", lens_rays)
    p = TinySceneParams()  # the tiny_scene fixture's
    layout, textures = scene_layout(p), _textures(np.random.default_rng(p.seed), p)
    scores = {}
    for k_model in (0.05, 0.0):
        folder = tmp_path / f"k{k_model}"
        write_colmap(folder, cams, k=k_model)
        for c in cams:
            lensed = Camera(c.name, c.K, c.viewmat, c.width, c.height, {"k": 0.05})
            save_image(folder / "images" / c.name, render_view(lensed, layout, textures, 2)[0])
        write_source_model(read_source(folder, "colmap"), folder / "out", ReconstructParams())
        data = read_scene(folder / "out")
        scores[k_model] = [psnr(load_image(path), render_view(cam, layout, textures, 2)[0])
                           for cam, path in zip(data.cameras, data.image_paths)]
    assert min(scores[0.05]) >= 30.0 and max(scores[0.0]) < 26.0, scores


# ------------------------------------------------------------------------------------------ nerfstudio


def test_nerfstudio_opengl_axes_and_applied_transform(tmp_path: Path, tiny_scene: Path, truth) -> None:
    cams, render = truth
    write_nerfstudio(tmp_path, tiny_scene, cams)
    scene = read_source(tmp_path, "nerfstudio")
    assert_same_cameras(scene.cameras, cams, render)
    np.testing.assert_allclose(scene.points, _gt_points(cams), atol=1e-4)  # the PLY brought back to the data's frame
    np.testing.assert_allclose(scene.colors[0], [200 / 255, 100 / 255, 50 / 255])
    S = np.diag([2.0, 2.0, 2.0, 1.0]) @ np.vstack([NERFSTUDIO_A, [0, 0, 0, 1]])
    np.testing.assert_allclose(scene.frame @ S, np.eye(4), atol=1e-12)
    masked = [v for v in scene.views if v.mask_path is not None]
    assert [v.name for v in masked] == ["000.png", "001.png", "002.png"]
    # the masks reach the reconstruct layout as labels: 1 where the mask keeps (box, sphere), 2 elsewhere
    report = write_source_model(scene, tmp_path / "colmap", ReconstructParams())
    assert report.points_method == "dataset"
    labels = load_labels(tmp_path / "colmap" / "masks" / "000.png")
    truth_labels = load_labels(tiny_scene / "masks" / "000.png")
    np.testing.assert_array_equal(labels, np.where(truth_labels >= 2, 1, 2))
    assert not (tmp_path / "colmap" / "masks" / "003.png").exists()


def test_nerfstudio_opencv_axes_fail_at_import(tmp_path: Path, tiny_scene: Path, truth) -> None:
    cams, _ = truth
    write_nerfstudio(tmp_path, tiny_scene, cams, opengl=False)
    with pytest.raises(InputError, match=r"transforms\.json\): 16 of 16 cameras see \(almost\) none of the dataset's "
                                         r"400 points .*wrong axis convention"):
        read_source(tmp_path, "nerfstudio")
    meta = json.loads((tmp_path / "transforms.json").read_text())
    del meta["ply_file_path"]  # without points: the optical axes meet behind the cameras
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"axes meet behind 16 of the 16 cameras, .*OpenGL vs OpenCV"):
        read_source(tmp_path, "nerfstudio")


def test_nerfstudio_downscaled_folder_and_missing_image(tmp_path: Path, tiny_scene: Path, truth) -> None:
    cams, render = truth
    write_nerfstudio(tmp_path, tiny_scene, cams)
    _copy_images(tiny_scene / "images", tmp_path / "images_2", scale=0.5)
    assert_same_cameras(read_source(tmp_path, "nerfstudio", images="images_2").cameras, [c.scaled(0.5) for c in cams],
                        render)
    meta = json.loads((tmp_path / "transforms.json").read_text())
    meta.update(k1=0.01, p1=0.001)  # OPENCV distortion, global: carried as the views' lens, scaled with the images
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    lens = read_source(tmp_path, "nerfstudio", images="images_2").views[0].distortion
    c = cams[0].scaled(0.5)
    assert lens.model == "OPENCV"
    assert lens.params == pytest.approx((c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2], 0.01, 0.0, 0.001, 0.0))
    (tmp_path / "images" / "005.png").unlink()
    with pytest.raises(InputError, match=r"frames\[5\]\.file_path 'images/005\.png' names .*005\.png, which does not "
                                         r"exist; copy the images beside transforms\.json"):
        read_source(tmp_path, "nerfstudio")


# ------------------------------------------------------------------------------------------ blender


def test_blender_rgba_composited_on_the_stated_background(tmp_path: Path, tiny_scene: Path, truth) -> None:
    cams, render = truth
    write_blender(tmp_path / "scene", tiny_scene, cams)
    scene = read_source(tmp_path / "scene", "blender", background=(0.0, 0.0, 1.0))
    names = {f"{'train' if i % 2 == 0 else 'test'}_{c.name}": c.name for i, c in enumerate(cams)}
    assert sorted(v.name for v in scene.views) == sorted(names)
    assert_same_cameras(scene.cameras, cams, render, names)
    report = write_source_model(scene, tmp_path / "colmap", ReconstructParams())
    assert report.points >= 100 and report.points_method in ("triangulated", "random")
    out = load_image(tmp_path / "colmap" / "images" / "train_000.png")
    original = load_image(tiny_scene / "images" / "000.png")
    opaque = load_labels(tiny_scene / "masks" / "000.png") >= 2
    np.testing.assert_allclose(out[opaque], original[opaque], atol=1 / 255)
    np.testing.assert_allclose(out[~opaque], np.broadcast_to([0.0, 0.0, 1.0], out[~opaque].shape), atol=1 / 255)


def test_blender_flipped_axes_fail_at_import(tmp_path: Path, tiny_scene: Path, truth) -> None:
    cams, _ = truth
    write_blender(tmp_path, tiny_scene, cams, opengl=False)
    with pytest.raises(InputError, match=r"transforms_train\.json\): the cameras' viewing axes meet behind"):
        read_source(tmp_path, "blender")


# ------------------------------------------------------------------------------------------ llff


def test_llff_poses_bounds_scaled_to_the_images_and_triangulated(tmp_path: Path, tiny_scene: Path, truth) -> None:
    """hwf of a 4× capture, 160×120 images: the cameras come back; the reconstruct layout gets points triangulated
    with those cameras fixed, which reproject onto the views."""
    cams, render = truth
    write_llff(tmp_path / "scene", tiny_scene, cams)
    scene = read_source(tmp_path / "scene", "llff")
    assert_same_cameras(scene.cameras, cams, render)
    assert scene.depth_range == (1.0, 12.0) and scene.points is None
    report = write_source_model(scene, tmp_path / "colmap", ReconstructParams())
    assert report.points_method == "triangulated" and report.points > 200
    assert report.mean_reprojection_error_px < 1.0 and report.median_epipolar_error_px < 0.3
    data = read_scene(tmp_path / "colmap")
    assert_same_cameras(data.cameras, cams, render)
    record = json.loads((tmp_path / "colmap" / "metrics.json").read_text())
    assert record["points_method"] == "triangulated" and "seconds" not in record


def test_llff_wrong_pairing_and_convention_fail(tmp_path: Path, tiny_scene: Path, truth) -> None:
    cams, _ = truth
    folder = tmp_path / "scene"
    write_llff(folder, tiny_scene, cams)
    arr = np.load(folder / "poses_bounds.npy")
    np.save(folder / "poses_bounds.npy", arr[::-1])  # the rows in reverse: every image gets another view's pose
    with pytest.raises(InputError, match=r"the views match each other \(\d+ verified feature matches\), but the matches "
                                         r"lie \d+\.\d+ px \(median\) off the epipolar lines .*poses do not fit the images"):
        write_source_model(read_source(folder, "llff"), tmp_path / "colmap", ReconstructParams())
    assert not (tmp_path / "colmap").exists()
    swapped = arr.copy().reshape(-1, 17)
    poses = swapped[:, :15].reshape(-1, 3, 5)
    poses[:, :, [0, 1]] = poses[:, :, [1, 0]]  # (right, down, back): OpenCV's order, not LLFF's
    np.save(folder / "poses_bounds.npy", swapped)
    with pytest.raises(InputError, match=r"poses_bounds\.npy row 0: the pose's columns 0-2 as LLFF's \(down, "
                                         r"right, back\) camera axes: the rotation is not a proper rotation"):
        read_source(folder, "llff")
    np.save(folder / "poses_bounds.npy", arr[:-1])
    with pytest.raises(InputError, match=r"holds 15 poses but .*images holds 16 images"):
        read_source(folder, "llff")


# ------------------------------------------------------------------------------------------ the stage and preflight


def test_reconstruct_stage_reads_a_dataset_scene(tmp_path: Path, tiny_scene: Path, truth) -> None:
    """stages/reconstruct.py on an LLFF scene named in params (format detected): the dataset's cameras, points
    triangulated, the record saying so; the preflight check reads the scene and names its key on a problem."""

    from abcgs.params import load_params
    from abcgs.pipeline import run_stage
    from abcgs.source_check import check_scene_sources

    cams, render = truth
    write_llff(tmp_path / "scene", tiny_scene, cams)
    (tmp_path / "params.yaml").write_text(json.dumps({"data": {"scenes": {"s": {"path": str(tmp_path / "scene")}}}}))
    from abcgs.dag import load_stage

    stage = load_stage(Path(__file__).parents[1] / "stages" / "reconstruct.py")
    ap = stage.stage_parser(stage.SPEC, "reconstruct")
    ap.add_argument("--colmap-log", default="warning")
    out = tmp_path / "out"
    (tmp_path / "stamp.json").write_text("{}")
    assert run_stage(stage.SPEC, ap, stage.main, [
        "--params", str(tmp_path / "params.yaml"), "--scene", "s", "--preflight", str(tmp_path / "stamp.json"),
        "--source", "{item.path}", "--out", str(out / "colmap"), "--metrics", str(out / "r.json")]) == 0
    record = json.loads((out / "r.json").read_text())
    assert record["format"] == "llff" and record["points_method"] == "triangulated" and record["seconds"] > 0
    assert_same_cameras(read_scene(out / "colmap").cameras, cams, render)
    params = load_params(tmp_path / "params.yaml")
    assert check_scene_sources(params, tmp_path) == []
    (tmp_path / "scene" / "images" / "003.png").unlink()
    with pytest.raises(InputError, match=r"^data\.scenes\.s: .*poses_bounds\.npy holds 16 poses but .*images holds 15"):
        check_scene_sources(params, tmp_path)


def test_textureless_views_start_from_random_points_in_the_frustums(tmp_path: Path, tiny_scene: Path, truth) -> None:
    """Nothing to match (flat views): random points between LLFF's near and far bounds, inside the views."""
    from abcgs.sources.model import RANDOM_POINTS

    cams, _ = truth
    write_llff(tmp_path / "scene", tiny_scene, cams)
    for i, p in enumerate(sorted((tmp_path / "scene" / "images").iterdir())):
        cv2.imwrite(str(p), np.full((120, 160, 3), 40 + 10 * i, np.uint8))
    report = write_source_model(read_source(tmp_path / "scene", "llff"), tmp_path / "colmap", ReconstructParams())
    assert report.points_method == "random" and report.points == RANDOM_POINTS and report.verified_matches == 0
    data = read_scene(tmp_path / "colmap")
    depth_in_some_view = np.zeros(len(data.points), bool)
    for cam in data.cameras:
        p = data.points @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
        uv = p @ cam.K.T
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= cam.width * uv[:, 2]) & (uv[:, 1] >= 0) & (uv[:, 1] <= cam.height * uv[:, 2])
        depth_in_some_view |= inside & (p[:, 2] >= 1.0 - 1e-6) & (p[:, 2] <= 12.0 + 1e-6)
    assert depth_in_some_view.all()
    grey = sorted(np.unique(np.round(data.colors[:, 0] * 255)))  # each point has its view's colour
    assert set(grey) <= {40.0 + 10 * i for i in range(16)} and len(grey) == 16
