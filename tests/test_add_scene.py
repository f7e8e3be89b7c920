"""``python -m abcgs add-scene`` / ``add-style``: detect, check, say what was found, write a valid params entry.

The scenes are the tiny scene written in each dataset format (writers from test_sources.py); the params file is a
copy of the repository's, whose comments must survive the edit.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT
from test_sources import write_blender, write_colmap, write_llff, write_nerfstudio

from abcgs.__main__ import main
from abcgs.params import load_params
from abcgs.preflight import preflight
from abcgs.scene.synthetic import cameras_from_json
from abcgs.source_check import check_scene_sources


@pytest.fixture
def params_file(tmp_path: Path) -> Path:
    for name in ("params.yaml", "dvc.yaml"):  # dvc.yaml: the tiny scene's files are a stage's output
        shutil.copy(REPO_ROOT / name, tmp_path / name)
    return tmp_path / "params.yaml"


@pytest.fixture(scope="module")
def cams(tiny_scene: Path):
    import json

    return cameras_from_json(json.loads((tiny_scene / "cameras.json").read_text()))


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    rc = main(list(argv))
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_add_scene_for_each_format(tmp_path: Path, tiny_scene: Path, cams, params_file: Path, capsys) -> None:
    folders = {"nerfstudio": tmp_path / "ns", "blender": tmp_path / "bl", "llff": tmp_path / "ll", "colmap": tmp_path / "cm"}
    for folder in folders.values():
        folder.mkdir()
    write_nerfstudio(folders["nerfstudio"], tiny_scene, cams)
    write_blender(folders["blender"], tiny_scene, cams)
    write_llff(folders["llff"], tiny_scene, cams)
    write_colmap(folders["colmap"], cams)
    shutil.copytree(tiny_scene / "images", folders["colmap"] / "images")
    expect = {
        "photos": (tiny_scene, "16 photos, 160x120 pixels, in images/; cameras: structure from motion"),
        "colmap": (folders["colmap"], "16 views with cameras from sparse/0, 160x120 pixels, in images/; lens: "
                                      "SIMPLE_RADIAL (16)"),
        "nerfstudio": (folders["nerfstudio"], "16 views with cameras from transforms.json"),
        "blender": (folders["blender"], "16 views with cameras from transforms_train.json, 160x120 pixels, in test/, "
                                        "train/"),
        "llff": (folders["llff"], "no points in the dataset: the reconstruct stage triangulates them"),
    }
    for fmt, (folder, found) in expect.items():
        rc, out, err = _run(capsys, "add-scene", f"s_{fmt}", str(folder), "--params", str(params_file))
        assert rc == 0, err
        assert out.startswith(f"s_{fmt}: {fmt}\n") and found in out, out
        assert f"wrote data.scenes in {params_file}:" in out and f"path: {folder.resolve()}" in out
    assert "400 points in the dataset" in _run(capsys, "add-scene", "again", str(folders["colmap"]), "--params",
                                                str(params_file), "--dry-run")[1]
    text = params_file.read_text()
    assert text.startswith("# abcgs pipeline parameters.") and "# mirror | translate | fill" in text  # comments kept
    params = load_params(params_file)
    for fmt, (folder, _) in expect.items():
        assert params.data.scenes[f"s_{fmt}"].path == str(folder.resolve())
        assert params.data.scenes[f"s_{fmt}"].format == fmt
    assert "again" not in params.data.scenes and params.vgg.path is None  # dry run; nulls stay nulls
    raw = yaml.safe_load(text)
    preflight(params, raw, params_file)  # the written file passes the checks every stage runs
    assert check_scene_sources(params, params_file.parent, produced=["data/tiny"]) == [
        "data.scenes.s_nerfstudio: applied_transform/applied_scale undone: the scene is in the original data's frame"]


def test_add_scene_messages_name_the_file_and_the_fix(tmp_path: Path, tiny_scene: Path, cams, params_file: Path,
                                                      capsys) -> None:
    before = params_file.read_text()
    (tmp_path / "empty").mkdir()
    rc, _, err = _run(capsys, "add-scene", "e", str(tmp_path / "empty"), "--params", str(params_file))
    assert rc == 2 and err.count("\n") == 1
    assert f"{tmp_path / 'empty'}: no scene found (it is empty); put the photos in {tmp_path / 'empty' / 'images'}/" in err
    (tmp_path / "nomodel" / "sparse" / "0").mkdir(parents=True)
    rc, _, err = _run(capsys, "add-scene", "m", str(tmp_path / "nomodel"), "--params", str(params_file))
    assert rc == 2 and "nomodel/sparse has no cameras.bin/cameras.txt (nor sparse/0/): copy the COLMAP model there" in err
    write_colmap(tmp_path / "foreign", cams)
    (tmp_path / "foreign" / "images").mkdir()
    cv2.imwrite(str(tmp_path / "foreign" / "images" / "DSC_0001.jpg"), np.zeros((120, 160, 3), np.uint8))
    rc, _, err = _run(capsys, "add-scene", "f", str(tmp_path / "foreign"), "--params", str(params_file))
    assert rc == 2 and "none of the 16 images of the COLMAP model" in err and "the folder holds DSC_0001.jpg" in err
    assert "use the image folder the model was made from" in err
    rc, _, err = _run(capsys, "add-scene", "tiny", str(tiny_scene), "--params", str(params_file))
    assert rc == 2 and "data.scenes.tiny exists already" in err and "--force" in err
    rc, _, err = _run(capsys, "add-scene", "bad;name", str(tiny_scene), "--params", str(params_file))
    assert rc == 2 and "'bad;name': a name must match" in err
    assert params_file.read_text() == before  # nothing written on any failure


def test_add_scene_stores_paths_as_data(tmp_path: Path, tiny_scene: Path, params_file: Path, capsys) -> None:
    """A path with YAML and shell syntax in it is stored verbatim (the file is edited as data, not as text)."""
    odd = tmp_path / "a: b #c 'd' $(x)"
    shutil.copytree(tiny_scene / "images", odd / "images")
    rc, _, err = _run(capsys, "add-scene", "odd", str(odd), "--images", "images", "--params", str(params_file))
    assert rc == 0, err
    scene = load_params(params_file).data.scenes["odd"]
    assert (scene.path, scene.images, scene.format) == (str(odd), "images", "photos")


def test_add_scene_with_a_splat(tmp_path: Path, tiny_scene: Path, params_file: Path, capsys) -> None:
    (tmp_path / "fit.ply").write_bytes(b"ply\n")
    rc, out, err = _run(capsys, "add-scene", "withsplat", str(tiny_scene), "--splat", str(tmp_path / "fit.ply"),
                        "--params", str(params_file), "--dry-run")
    # a folder of photos has no cameras before structure from motion: the fit stage checks the splat against them
    assert rc == 0 and f"splat: {tmp_path / 'fit.ply'}" in out, err
    assert "checked against the photos in the fit stage" in out
    rc, _, err = _run(capsys, "add-scene", "nosplat", str(tiny_scene), "--splat", str(tmp_path / "gone.ply"),
                      "--params", str(params_file))
    assert rc == 2 and "gone.ply does not exist" in err


def test_add_style_with_and_without_region_map(tmp_path: Path, tiny_scene: Path, params_file: Path, capsys) -> None:
    styles = tiny_scene / "styles"
    rc, out, err = _run(capsys, "add-style", "p", str(styles / "paint.png"), "--labels", str(styles / "paint_labels.png"),
                        "--params", str(params_file))
    assert rc == 0, err
    assert "painting 341x256" in out and "region map 341x256, labels 1: " in out
    params = load_params(params_file)
    assert params.data.styles["p"] == str(styles / "paint.png")
    assert params.data.style_masks["p"] == str(styles / "paint_labels.png")
    cv2.imwrite(str(tmp_path / "blank.png"), np.zeros((256, 341), np.uint8))
    rc, _, err = _run(capsys, "add-style", "q", str(styles / "paint2.png"), "--labels", str(tmp_path / "blank.png"),
                      "--params", str(params_file))
    assert rc == 2 and "blank.png is all 0 (unassigned)" in err
    cv2.imwrite(str(tmp_path / "square.png"), np.ones((100, 100), np.uint8))
    rc, _, err = _run(capsys, "add-style", "q", str(styles / "paint2.png"), "--labels", str(tmp_path / "square.png"),
                      "--params", str(params_file))
    assert rc == 2 and "square.png is 100x100 but the painting" in err and "is 341x256" in err
    rc, _, err = _run(capsys, "add-style", "q", str(tmp_path / "nope.jpg"), "--params", str(params_file))
    assert rc == 2 and "nope.jpg does not exist" in err
    assert "q" not in load_params(params_file).data.styles


def test_preflight_reads_an_entrys_trained_splat_before_any_stage(tmp_path: Path, tiny_scene: Path) -> None:
    """A hand-written entry's splat is checked by preflight as add-scene checks it: NaN means or no Gaussian are
    refused in one line naming the entry (before the reconstruct stage runs); splat_nonfinite: drop passes them."""
    import torch

    from abcgs.errors import InputError
    from abcgs.gaussians.ply import write_ply
    from abcgs.params import validate_params
    from tests.test_splats import make_model

    good, nan, empty = tmp_path / "good.ply", tmp_path / "nan.ply", tmp_path / "empty.ply"
    model = make_model(200, 0)
    write_ply(good, model)
    with torch.no_grad():
        model.means[:3] = float("nan")
    write_ply(nan, model)
    write_ply(empty, make_model(0, 0))

    def check(splat: Path, **entry) -> list[str]:
        params = validate_params({"data": {"scenes": {"s": {"path": str(tiny_scene), "splat": str(splat), **entry}}}})
        return check_scene_sources(params, tmp_path)

    assert check(good) == []
    with pytest.raises(InputError, match=r"data\.scenes\.s: .*nan\.ply: 3 of 200 Gaussians") as exc:
        check(nan)
    assert "\n" not in str(exc.value)
    assert check(nan, splat_nonfinite="drop") == []
    with pytest.raises(InputError, match=r"data\.scenes\.s: .*0 Gaussians"):
        check(empty)
    # an INRIA output folder on a scene whose cameras structure from motion will find: its cameras.json's values are
    # checked now, without the cameras to align it to
    inria = tmp_path / "inria"
    write_ply(inria / "point_cloud" / "iteration_7000" / "point_cloud.ply", make_model(50, 0))
    views = [{"img_name": f"{i:03d}", "position": [float(i), 0.0, 1.0]} for i in range(4)]
    (inria / "cameras.json").write_text(json.dumps(views))
    assert check(inria) == []
    views[2]["position"] = [float("nan"), 0.0, 1.0]
    (inria / "cameras.json").write_text(json.dumps(views))
    with pytest.raises(InputError, match=r"data\.scenes\.s: .*cameras\.json: view 2 \(002\) has the position"):
        check(inria)
