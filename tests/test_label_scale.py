"""Label maps at another scale than their views: the same picture at another scale is scaled (nearest label) where
the scene is read; another aspect is refused by preflight and ``add-scene`` before any work, naming the file, both
sizes and the fix.

The scene is the tiny scene as a nerfstudio dataset read through ``images_4`` (¼ size, 40×30 views), with a label
map painted at full size (160×120), as a user who painted on ``images/`` gives one.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import REPO_ROOT
from test_sources import _copy_images, write_nerfstudio

from abcgs.__main__ import main
from abcgs.errors import InputError
from abcgs.io.images import (
    labels_for_view,
    load_labels,
    load_stroke_map,
    resized_labels,
    same_picture_scaled,
    save_labels,
    save_stroke_map,
    stroke_map_path,
    strokes_for_view,
)
from abcgs.params import load_params
from abcgs.preflight import check_input_files
from abcgs.scene.synthetic import cameras_from_json
from abcgs.sfm.params import ReconstructParams
from abcgs.source_check import check_scene_sources
from abcgs.sources.model import write_source_model
from abcgs.sources.read import read_source


def test_the_same_picture_at_another_scale_is_scaled_with_the_nearest_label() -> None:
    labels = np.zeros((1080, 1920), np.int64)
    labels[:540, :960], labels[540:, 960:] = 1, 255
    small = labels_for_view(labels, (270, 480), "masks/a.png")
    assert small.shape == (270, 480) and small.dtype == np.int64 and set(np.unique(small)) == {0, 1, 255}
    assert small[:135, :240].min() == 1 and small[135:, 240:].min() == 255
    assert same_picture_scaled((1080, 1920), (270, 480)) and same_picture_scaled((121, 160), (30, 40))  # rounding
    assert labels_for_view(labels, (1080, 1920)) is labels
    with pytest.raises(InputError, match=r"label map masks/a\.png is 1920×1080 but its view a\.jpg is 480×480, another "
                                         r"aspect, .*save it at 480×480"):
        labels_for_view(labels, (480, 480), "masks/a.png", "a.jpg")


def test_a_label_map_with_undecided_pixels_keeps_them_when_resized() -> None:
    """``resized_labels`` (a cut at the lift's working size, a view's labels at a stylization's scale): nearest
    label, the undecided -1 kept, up and down."""
    labels = np.full((40, 60), -1, np.int64)
    labels[:20, :30], labels[20:, 30:] = 2, 300
    up = resized_labels(labels, (80, 120))
    assert up.shape == (80, 120) and up.dtype == np.int64 and set(np.unique(up)) == {-1, 2, 300}
    assert (up[:40, :60] == 2).all() and (up[40:, 60:] == 300).all() and (up[:40, 60:] == -1).all()
    np.testing.assert_array_equal(resized_labels(up, (40, 60)), labels)
    assert resized_labels(labels, (40, 60)) is labels


def nerfstudio_quarter(folder: Path, tiny_scene: Path) -> Path:
    """The tiny scene as a nerfstudio dataset in ``folder`` with a ¼-size copy of its views in ``images_4/`` and an
    empty ``masks/`` for the user's label maps (the dataset's own keep-masks removed)."""
    cams = cameras_from_json(json.loads((tiny_scene / "cameras.json").read_text()))
    folder.mkdir(parents=True)
    write_nerfstudio(folder, tiny_scene, cams)
    shutil.rmtree(folder / "masks")  # the dataset's own keep-masks: this scene's masks/ are the user's label maps
    (folder / "masks").mkdir()
    meta = json.loads((folder / "transforms.json").read_text())
    for f in meta["frames"]:
        f.pop("mask_path", None)
    (folder / "transforms.json").write_text(json.dumps(meta))
    _copy_images(tiny_scene / "images", folder / "images_4", scale=0.25)
    return folder


@pytest.fixture()
def quarter_scene(tmp_path: Path, tiny_scene: Path) -> Path:
    """:func:`nerfstudio_quarter`; masks/ holds a user's full-size label map of view 000."""
    folder = nerfstudio_quarter(tmp_path / "ns", tiny_scene)
    shutil.copy(tiny_scene / "masks" / "000.png", folder / "masks" / "000.png")
    return folder


def _params(root: Path, folder: Path) -> Path:
    path = root / "params.yaml"
    path.write_text(json.dumps({"data": {"scenes": {"ns": {"path": str(folder), "source": {"images": "images_4"}}}}}))
    return path


def test_a_full_size_label_map_of_an_images_4_scene_is_scaled_where_the_scene_is_read(quarter_scene: Path,
                                                                                       tiny_scene: Path,
                                                                                       tmp_path: Path) -> None:
    params = load_params(_params(tmp_path, quarter_scene))
    assert not any("label map" in w for w in check_scene_sources(params, tmp_path))
    source = read_source(quarter_scene, "nerfstudio", images="images_4")
    write_source_model(source, tmp_path / "colmap", ReconstructParams(), masks_dir=quarter_scene / "masks")
    got = load_labels(tmp_path / "colmap" / "masks" / "000.png")
    truth = load_labels(tiny_scene / "masks" / "000.png")
    assert got.shape == (30, 40)
    assert np.array_equal(got, cv2.resize(truth.astype(np.uint8), (40, 30), interpolation=cv2.INTER_NEAREST))


def test_a_label_map_of_another_aspect_is_refused_before_any_work(quarter_scene: Path, tmp_path: Path,
                                                                   capsys) -> None:
    save_labels(quarter_scene / "masks" / "000.png", np.ones((120, 120), np.int64))
    params = load_params(_params(tmp_path, quarter_scene))
    t0 = time.perf_counter()
    with pytest.raises(InputError) as err:
        check_scene_sources(params, tmp_path)
    assert time.perf_counter() - t0 < 10.0
    msg = str(err.value)
    assert msg.startswith("data.scenes.ns: label map ") and "masks/000.png is 120×120 but its view 000.png is 40×30" in msg
    assert "save it at 40×30" in msg and f"python -m abcgs.masks.page {quarter_scene} --images images_4" in msg

    repo_params = _repo_params(tmp_path)
    before = repo_params.read_text()
    t0 = time.perf_counter()
    rc = main(["add-scene", "ns", str(quarter_scene), "--images", "images_4", "--params", str(repo_params)])
    err_text = capsys.readouterr().err
    assert rc == 2 and time.perf_counter() - t0 < 10.0
    assert "masks/000.png is 120×120 but its view 000.png is 40×30" in err_text and "save it at 40×30" in err_text
    assert repo_params.read_text() == before


def test_photos_label_maps_are_checked_against_the_images_folder_the_scene_names(tiny_scene: Path,
                                                                                  tmp_path: Path, capsys) -> None:
    folder = tmp_path / "photos"
    _copy_images(tiny_scene / "images", folder / "images_4", scale=0.25)
    (folder / "masks").mkdir()
    shutil.copy(tiny_scene / "masks" / "000.png", folder / "masks" / "000.png")  # full size: scaled
    params = load_params(_params(tmp_path, folder))
    check_input_files(params, tmp_path)
    rc = main(["add-scene", "ph", str(folder), "--images", "images_4", "--params", str(_repo_params(tmp_path))])
    assert rc == 0 and "1 of another size than their views: scaled to them" in capsys.readouterr().out
    save_labels(folder / "masks" / "001.png", np.ones((30, 30), np.int64))
    t0 = time.perf_counter()
    with pytest.raises(InputError, match=r"^data\.scenes\.ns: label map .*001\.png is 30×30 but its view 001\.png is "
                                         r"40×30"):
        check_input_files(params, tmp_path)
    assert time.perf_counter() - t0 < 10.0


def _repo_params(tmp_path: Path) -> Path:
    repo = tmp_path / "repo"
    repo.mkdir(exist_ok=True)
    for name in ("params.yaml", "dvc.yaml"):
        shutil.copy(REPO_ROOT / name, repo / name)
    return repo / "params.yaml"


def test_a_thin_stroke_painted_at_full_size_survives_a_view_four_times_smaller() -> None:
    raw = np.zeros((1080, 1920), np.int64)
    raw[500:502, 100:1800] = 3  # a 2-px line of label 2 (saved as seed + 1)
    raw[800:840, 900:940] = 1  # a blob of the background brush
    small = strokes_for_view(raw, (270, 480), "masks/strokes/a.png")
    assert small.shape == (270, 480) and small.dtype == np.int64
    row = small[125]  # rows 500..501 of 1080 fall in row 125 of 270
    assert (row[25:450] == 3).all()  # nearest neighbour keeps one row in four: this line would be gone
    assert set(np.unique(small)) == {0, 1, 3} and (small[200:210, 225:235] == 1).all()
    with pytest.raises(InputError, match=r"is 1920×1080 but its view a\.jpg is 480×480, another aspect"):
        strokes_for_view(raw, (480, 480), "masks/strokes/a.png", "a.jpg")


def test_strokes_painted_on_full_size_frames_reach_the_images_4_views(quarter_scene: Path, tiny_scene: Path,
                                                                       tmp_path: Path) -> None:
    """The page saved view 000's strokes at the photo's size (160×120) beside its label map; the scene reads
    ``images_4`` (40×30): preflight's check passes, the layout holds the strokes at the views' size, and the masks
    stage's reader takes them."""
    seeds = np.full((120, 160), -1, np.int64)
    seeds[40:42, 20:140] = 1  # a thin stroke of label 1
    seeds[100:110, 10:30] = 0  # the background brush
    save_stroke_map(stroke_map_path(quarter_scene / "masks", "000"), seeds)
    params = load_params(_params(tmp_path, quarter_scene))
    check_scene_sources(params, tmp_path)
    source = read_source(quarter_scene, "nerfstudio", images="images_4")
    write_source_model(source, tmp_path / "colmap", ReconstructParams(), masks_dir=quarter_scene / "masks")
    got = load_stroke_map(stroke_map_path(tmp_path / "colmap" / "masks", "000"), (30, 40))
    assert (got[10, 5:35] == 1).all() and (got[25:27, 3:7] == 0).all() and (got >= 0).sum() < 0.2 * got.size


def test_strokes_of_another_aspect_are_refused_before_any_work(quarter_scene: Path, tmp_path: Path) -> None:
    save_stroke_map(stroke_map_path(quarter_scene / "masks", "000"), np.full((120, 120), -1, np.int64))
    params = load_params(_params(tmp_path, quarter_scene))
    t0 = time.perf_counter()
    with pytest.raises(InputError, match=r"strokes/000\.png is 120×120 but its view 000\.png is 40×30"):
        check_scene_sources(params, tmp_path)
    assert time.perf_counter() - t0 < 10.0
