"""One scene on disk: :func:`abcgs.sfm.model.write_scene` and :func:`abcgs.sfm.model.read_scene` give back everything
a scene is (cameras, images, alpha and label maps, background, frame, format, splat, metadata), and ``scene.json``
is refused in one line when it is missing, of another version, or holds a value of the wrong type or not finite."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from abcgs.cameras import Camera, Cameras, Distortion
from abcgs.errors import InputError
from abcgs.io.colmap import read_model
from abcgs.io.images import save_image, save_labels
from abcgs.layout import ColmapDir
from abcgs.sfm.model import SCENE_VERSION, read_scene, write_scene
from abcgs.sfm.params import ReconstructParams
from abcgs.sources.bare_splat import read_splat_source
from abcgs.sources.model import write_source_model
from abcgs.splats.formats.splat import write_splat_file
from abcgs.splats.params import SplatViewsParams
from abcgs.types import Background, CalibratedScene

sys.path.insert(0, str(Path(__file__).parent))
from test_splats import make_model  # noqa: E402


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q * np.linalg.det(q)


def make_scene(root: Path, seed: int = 0) -> CalibratedScene:
    """Four 12 × 8 views with images, alpha maps and two label maps in ``root``, every other field set."""
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(4):
        viewmat = np.eye(4)
        viewmat[:3, :3], viewmat[:3, 3] = _rotation(rng), rng.normal(size=3)
        K = np.array([[10.0 + rng.random(), 0.0, 6.0 + rng.random()], [0.0, 11.0 + rng.random(), 4.0], [0, 0, 1]])
        cams.append(Camera(f"v{i}.png", K, viewmat, 12, 8))
    for cam in cams:
        save_image(root / "images" / cam.name, rng.random((8, 12, 3)).astype(np.float32))
        save_image(root / "alpha" / cam.name, rng.random((8, 12)).astype(np.float32))
    for cam in cams[:2]:
        save_labels(root / "masks" / cam.name, rng.integers(0, 3, (8, 12)))
    frame = np.eye(4)
    frame[:3, :3], frame[:3, 3] = 0.3 * _rotation(rng), rng.normal(size=3)  # bits a decimal rounding would lose
    return CalibratedScene(Cameras.from_list(cams), tuple(root / "images" / c.name for c in cams),
                 rng.normal(size=(50, 3)).astype(np.float32), (rng.integers(0, 256, (50, 3)) / 255.0).astype(np.float32),
                 label_paths=(root / "masks/v0.png", root / "masks/v1.png", None, None),
                 alpha_paths=tuple(root / "alpha" / c.name for c in cams), format="nerfstudio", frame=frame,
                 background=Background((0.1, 0.25, 1 / 3), transparent=True, object=True), depth_range=(0.5, 7.25),
                 notes=("scaled by 0.3",), metadata={"views_kind": "orbit", "n": 3, "nested": {"a": [1.5, None]}},
                 splat=Path("data/scene/trained.ply"))


def test_a_scene_round_trips_exactly(tmp_path: Path) -> None:
    scene = make_scene(tmp_path)
    assert write_scene(scene, tmp_path) == ColmapDir(tmp_path).scene
    back = read_scene(tmp_path)
    assert back.frame.dtype == np.float64 and np.array_equal(back.frame, scene.frame)
    assert back.format == "nerfstudio" and back.background == scene.background and back.metadata == scene.metadata
    assert back.splat == scene.splat and back.depth_range == scene.depth_range and back.notes == scene.notes
    assert back.image_paths == scene.image_paths and back.alpha_paths == scene.alpha_paths
    assert back.label_paths == scene.label_paths
    assert back.cameras.names == scene.cameras.names
    for key in ("intrinsics", "sizes", "camera_models", "distortion_params"):
        assert np.array_equal(getattr(back.cameras, key), getattr(scene.cameras, key)), key
    # COLMAP stores a pose as a quaternion: the first trip rounds in the last bits, and from there the model holds
    assert np.abs(back.cameras.viewmats - scene.cameras.viewmats).max() < 1e-12
    assert np.array_equal(back.points, scene.points) and np.array_equal(back.colors, scene.colors)
    model = {p.name: p.read_bytes() for p in (tmp_path / "sparse").iterdir()}
    write_scene(back, tmp_path)
    assert {p.name: p.read_bytes() for p in (tmp_path / "sparse").iterdir()} == model  # kept, not rewritten
    again = read_scene(tmp_path)
    assert np.array_equal(again.cameras.viewmats, back.cameras.viewmats)
    # the cameras a stage reads are the model's own, as the COLMAP parser reads them
    assert np.array_equal(again.cameras.viewmats, read_model(tmp_path / "sparse").cameras().viewmats)


def test_a_scene_without_alpha_masks_or_background_reads_back_frame_filling(tmp_path: Path) -> None:
    scene = make_scene(tmp_path)
    plain = CalibratedScene(scene.cameras, scene.image_paths, scene.points, scene.colors)
    write_scene(plain, tmp_path)
    back = read_scene(tmp_path)
    assert back.background == Background() and back.alpha_paths is None and back.label_paths is None
    assert back.format == "colmap" and np.array_equal(back.frame, np.eye(4)) and back.splat is None


def test_write_scene_refuses_files_outside_its_folder_and_distorted_cameras(tmp_path: Path) -> None:
    scene = make_scene(tmp_path / "a")
    with pytest.raises(ValueError, match="not inside"):
        write_scene(scene, tmp_path / "b")
    lens = [Distortion("SIMPLE_RADIAL", (10.0, 6.0, 4.0, 0.01))] + [None] * 3
    distorted = CalibratedScene(Cameras.from_list(list(scene.cameras), lens), scene.image_paths, scene.points, scene.colors)
    with pytest.raises(ValueError, match="undistorted"):
        write_scene(distorted, tmp_path / "a")


def test_a_missing_or_other_version_scene_json_is_refused_naming_the_file_and_the_fix(tmp_path: Path) -> None:
    write_scene(make_scene(tmp_path), tmp_path)
    record = ColmapDir(tmp_path).scene
    doc = json.loads(record.read_text())
    for version in (SCENE_VERSION + 1, 0, "1", True, None, 1.0):
        record.write_text(json.dumps({**doc, "version": version}))
        with pytest.raises(InputError, match="re-run the reconstruct stage") as exc:
            read_scene(tmp_path)
        assert str(record) in str(exc.value) and "\n" not in str(exc.value)
        if not isinstance(version, int) or isinstance(version, bool):  # the wrong type is named as such
            assert f"holds version {type(version).__name__}" in str(exc.value) and "not the integer" in str(exc.value)
    record.unlink()
    with pytest.raises(InputError, match="scene.json does not exist.*re-run the reconstruct stage"):
        read_scene(tmp_path)


def _set(doc: dict, path: str, value) -> dict:
    *keys, last = path.split(".")
    node = doc
    for k in keys:
        node = node[int(k)] if isinstance(node, list) else node[k]
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return doc


@pytest.mark.parametrize(("path", "value", "reason"), [
    ("frame", [[float("nan")] * 4] * 4, "not a finite number"),
    ("frame", [[1.0, 0.0, 0.0]] * 4, "frame must be 4 x 4 numbers"),
    ("frame", [[True, 0, 0, 0]] * 4, "frame must be 4 x 4 numbers"),
    ("metadata", {"scale": float("inf")}, "scene.metadata.scale holds inf"),
    ("metadata", [1, 2], "metadata is list"),
    ("format", 3, "format is int"),
    ("splat", ["a.ply"], "splat is list"),
    ("depth_range", [1.0, float("-inf")], "not a finite number"),
    ("notes", ["ok", 1], "notes must be strings"),
    ("background.transparent", "yes", "background.transparent is str"),
    ("background.color", [0.0, 2.0, 0.0], "outside"),
    ("background.color", [0.0, 0.0], "background.color must be 3 numbers"),
    ("views.0.name", "other.png", "not the model's view"),
    ("views.1.image", "../../etc/passwd", "not a path inside"),
    ("views.1.alpha", "/abs/v1.png", "not a path inside"),
    ("views.2.mask", "masks/absent.png", "missing"),
    ("views.3", "v3.png", "not the model's view"),
    ("views", [], "lists 0 views"),
    ("frame", np.zeros((4, 4)).tolist(), "last row"),
    ("frame", [[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]], "determinant 0"),
    ("frame", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]], "determinant -1"),
    ("frame", [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "not a rotation times a positive scale"),
    ("frame", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], "last row"),
    ("depth_range", [5.0, 1.0], "0 < near < far"),
    ("depth_range", [0.0, 1.0], "0 < near < far"),
    ("views.0.image", "images/v1.png", "views\\[1\\].image .* is also views\\[0\\].image"),
    ("views.0.mask", "images/v0.png", "views\\[0\\].mask .* is also views\\[0\\].image"),
    ("views.0.mask", "alpha/v2.png", "is also views\\[2\\].alpha"),
])
def test_a_scene_json_with_a_bad_value_is_refused_in_one_line(tmp_path: Path, path: str, value, reason: str) -> None:
    write_scene(make_scene(tmp_path), tmp_path)
    record = ColmapDir(tmp_path).scene
    record.write_text(json.dumps(_set(json.loads(record.read_text()), path, value)))  # NaN and inf as JSON's extension
    with pytest.raises(InputError, match=reason) as exc:
        read_scene(tmp_path)
    assert str(record) in str(exc.value) and "re-run the reconstruct stage" in str(exc.value)
    assert "\n" not in str(exc.value)


def test_a_hostile_scene_json_is_bounded_before_it_is_parsed(tmp_path: Path) -> None:
    write_scene(make_scene(tmp_path), tmp_path)
    record = ColmapDir(tmp_path).scene
    doc = json.loads(record.read_text())
    record.write_text(json.dumps(doc)[:-1] + ', "metadata_deep": ' + "[" * 500 + "]" * 500 + "}")
    with pytest.raises(InputError, match="nested too deeply"):
        read_scene(tmp_path)
    record.write_text("{not json")
    with pytest.raises(InputError, match="not readable JSON"):
        read_scene(tmp_path)


def test_the_reconstruct_writer_records_a_bare_splats_file_format_and_views_for_the_fit(tmp_path: Path) -> None:
    """What the fit stage reads instead of detecting the format again: the splat file, the format, the views' kind."""
    src = tmp_path / "scene.splat"
    write_splat_file(src, make_model(800, 0, seed=3))
    source = read_splat_source(src, tmp_path / "views", SplatViewsParams(count=4, width=32, height=24),
                               background=(0.0, 0.0, 0.0))
    object_on_black = Background(object=True)
    write_source_model(source, tmp_path / "colmap", ReconstructParams(), background=object_on_black)
    scene = read_scene(tmp_path / "colmap")
    assert scene.splat == src and scene.format == "splat" and scene.background == object_on_black
    assert scene.metadata == source.metadata and scene.metadata["views_kind"] in ("orbit", "forward")
    assert all(p.parent == tmp_path / "colmap" / "images" and p.is_file() for p in scene.image_paths)


def test_the_stages_read_the_reconstructed_model_as_it_is(tiny_colmap: Path) -> None:
    """Structure from motion's model is kept byte for byte: a stage reads the cameras and points that the COLMAP
    parser (:func:`abcgs.io.colmap.read_model`) reads from ``sparse/`` and the views in ``images/``, with the scene's
    format, background and label maps beside them."""
    scene, model = read_scene(tiny_colmap), read_model(tiny_colmap / "sparse")
    cameras = model.cameras()
    assert scene.cameras.names == cameras.names
    assert scene.image_paths == tuple(tiny_colmap / "images" / name for name in cameras.names)
    for key in ("viewmats", "intrinsics", "sizes", "camera_models", "distortion_params"):
        assert np.array_equal(getattr(scene.cameras, key), getattr(cameras, key)), key
    assert np.array_equal(scene.points, model.points.astype(np.float32))
    assert np.array_equal(scene.colors, (model.colors / 255.0).astype(np.float32))
    assert scene.format == "photos" and scene.background == Background() and scene.alpha_paths is None
    assert scene.label_paths is not None and scene.label_paths[0] == tiny_colmap / "masks" / "000.png"


def test_a_label_map_that_is_a_photo_and_a_scene_json_that_is_no_file_are_refused_in_one_line(tmp_path: Path) -> None:
    import os

    write_scene(make_scene(tmp_path), tmp_path)
    record = ColmapDir(tmp_path).scene
    doc = json.loads(record.read_text())
    save_image(tmp_path / "masks" / "photo.png", np.random.default_rng(1).random((8, 12, 3)).astype(np.float32))
    record.write_text(json.dumps(_set(json.loads(json.dumps(doc)), "views.0.mask", "masks/photo.png")))
    with pytest.raises(InputError, match="is a RGB image, not a single-channel label map"):
        read_scene(tmp_path)
    record.unlink()
    os.mkfifo(record)  # opening a FIFO would block: refused from its stat, in one line
    with pytest.raises(InputError, match="is a FIFO .*not a regular file") as exc:
        read_scene(tmp_path)
    assert "\n" not in str(exc.value)
    record.unlink()
    record.symlink_to(record)
    with pytest.raises(InputError, match="symlink loop"):
        read_scene(tmp_path)


def test_the_fit_imports_only_the_splat_of_the_entry_or_one_inside_the_scene_folder(tmp_path: Path) -> None:
    """A scene record that names a splat elsewhere (a hand-edited scene.json) is refused: DVC tracks the scene's
    folder, and a splat outside it that the entry does not name would be imported with nothing tracking it."""
    from abcgs.sources.params import SceneParams

    folder = tmp_path / "scene"
    (folder / "gs").mkdir(parents=True)
    inside, outside = folder / "gs" / "point_cloud.ply", tmp_path / "elsewhere.ply"
    for p in (inside, outside):
        p.write_bytes(b"ply\n")
    plain = SceneParams(path=str(folder))
    assert plain.recorded_splat(inside, folder) == inside
    with pytest.raises(InputError, match="neither the scene's splat .* nor inside its folder") as exc:
        plain.recorded_splat(outside, folder)
    assert "re-run the reconstruct stage" in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(InputError, match="nor inside its folder"):
        plain.recorded_splat(folder / ".." / "elsewhere.ply", folder)  # not inside once resolved
    named = SceneParams(path=str(folder), splat=str(outside))  # an absolute splat the entry names
    assert named.recorded_splat(outside, folder) == outside
    bare = SceneParams(path=str(outside))  # a bare splat: the scene's path is the file
    assert bare.recorded_splat(outside, outside) == outside
