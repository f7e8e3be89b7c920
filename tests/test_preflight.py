"""Checks before any work: keys dvc.yaml tracks, style files and scene folders (abcgs/preflight.py)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT

from abcgs.dag import load_stage
from abcgs.errors import InputError, ParamsError
from abcgs.io.images import save_image
from abcgs.params import validate_params
from abcgs.pipeline import run_stage, stage_parser
from abcgs.preflight import check_dvc_tracked_keys, check_input_files, dvc_outputs, dvc_tracked_keys, preflight

DVC = {"stages": {
    "make": {"cmd": "x", "outs": ["data/made"]},
    "colormatch": {"foreach": "${colormatches}", "do": {"cmd": "x", "params": ["colormatches.${key}", "data.styles",
                                                                                "data.style_masks", "colormatch"],
                                                          "outs": ["out/${key}/colormatch", {"out/rec.json": {"cache": False}}]}},
}}


def _raw(tmp_path, **data) -> dict:
    return {"data": {"scenes": {"s": "scene"}, **data}, "colormatch": {}}


def _scene(tmp_path, name="scene", n=2):
    img = (np.random.default_rng(0).random((24, 32, 3))).astype(np.float32)
    for k in range(n):
        save_image(tmp_path / name / "images" / f"{k:03d}.png", img)


def test_tracked_keys_come_from_dvc_yaml_without_templates(tmp_path) -> None:
    (tmp_path / "dvc.yaml").write_text(yaml.safe_dump(DVC))
    assert dvc_tracked_keys(tmp_path / "dvc.yaml") == {"data.styles": ["colormatch"], "data.style_masks": ["colormatch"],
                                                       "colormatch": ["colormatch"]}
    assert sorted(dvc_outputs(tmp_path / "dvc.yaml")) == ["data/made", "out/rec.json"]


def test_a_key_dvc_tracks_but_the_file_lacks_is_named_with_the_fix(tmp_path) -> None:
    (tmp_path / "dvc.yaml").write_text(yaml.safe_dump(DVC))
    raw = _raw(tmp_path, styles={})
    with pytest.raises(ParamsError, match=r"data\.style_masks: tracked by stage\(s\) colormatch; add `style_masks: \{\}` "
                                          r"under `data:`"):
        check_dvc_tracked_keys(raw, tmp_path / "dvc.yaml")
    check_dvc_tracked_keys(_raw(tmp_path, styles={}, style_masks={}), tmp_path / "dvc.yaml")  # empty is fine


def test_the_repositorys_params_cover_what_its_dvc_yaml_tracks() -> None:
    raw = yaml.safe_load((REPO_ROOT / "params.yaml").read_text())
    check_dvc_tracked_keys(raw, REPO_ROOT / "dvc.yaml")
    assert "data.style_masks" in dvc_tracked_keys(REPO_ROOT / "dvc.yaml")


def test_style_files_must_exist_and_decode(tmp_path) -> None:
    _scene(tmp_path)
    with pytest.raises(InputError, match=r"data\.styles\.p: .*nope\.jpg does not exist"):
        check_input_files(validate_params(_raw(tmp_path, styles={"p": "nope.jpg"})), tmp_path)
    (tmp_path / "bad.jpg").write_bytes(b"\xff\xd8 not really a jpeg")
    with pytest.raises(InputError, match=r"data\.styles\.p: .*bad\.jpg is not a readable image"):
        check_input_files(validate_params(_raw(tmp_path, styles={"p": "bad.jpg"})), tmp_path)
    save_image(tmp_path / "small.png", np.zeros((16, 16, 3), np.float32))
    with pytest.raises(InputError, match=r"data\.styles\.p: .*small\.png is 16×16 pixels"):
        check_input_files(validate_params(_raw(tmp_path, styles={"p": "small.png"})), tmp_path)
    save_image(tmp_path / "ok.png", np.zeros((64, 64, 3), np.float32))
    with pytest.raises(InputError, match=r"data\.style_masks\.p: .*gone\.png does not exist"):
        check_input_files(validate_params(_raw(tmp_path, styles={"p": "ok.png"}, style_masks={"p": "gone.png"})), tmp_path)
    check_input_files(validate_params(_raw(tmp_path, styles={"p": "ok.png"})), tmp_path)


def test_scene_folders_must_hold_readable_images_unless_a_stage_makes_them(tmp_path) -> None:
    params = validate_params({"data": {"scenes": {"s": "scene"}}})
    with pytest.raises(InputError, match=r"data\.scenes\.s: .*images does not exist"):
        check_input_files(params, tmp_path)
    check_input_files(validate_params({"data": {"scenes": {"s": "data/made/tiny"}, "styles": {"p": "data/made/p.png"}}}),
                      tmp_path, produced=["data/made"])  # made by a stage: nothing to check yet
    (tmp_path / "scene" / "images").mkdir(parents=True)
    with pytest.raises(InputError, match="holds no images"):
        check_input_files(params, tmp_path)
    _scene(tmp_path)
    (tmp_path / "scene" / "images" / "002.jpg").write_bytes(b"garbage")
    with pytest.raises(InputError, match=r"1 image\(s\) .* do not decode: 002\.jpg"):
        check_input_files(params, tmp_path)


def test_the_preflight_stage_stops_before_work_and_says_why(tmp_path, capsys) -> None:
    """A key dvc.yaml tracks that the params file lacks: the preflight stage, which every other stage runs after,
    fails naming the key and writes no stamp; with the key given it writes the stamp."""
    stage = load_stage(REPO_ROOT / "stages" / "preflight.py")
    (tmp_path / "dvc.yaml").write_text(yaml.safe_dump(DVC))
    _scene(tmp_path)
    params, stamp = tmp_path / "params.yaml", tmp_path / "out" / "preflight.json"
    argv = ["--params", str(params), "--out", str(stamp), "--record", str(tmp_path / "out" / "report.json"),
            "--label-use", str(tmp_path / "out" / "label_use")]
    params.write_text(yaml.safe_dump({"data": {"scenes": {"s": "scene"}, "styles": {}}}))
    assert run_stage(stage.SPEC, stage_parser(stage.SPEC, "t"), stage.main, argv) == 2 and not stamp.exists()
    err = capsys.readouterr().err
    assert "data.style_masks" in err and "colormatch" in err
    params.write_text(yaml.safe_dump({"data": {"scenes": {"s": "scene"}, "styles": {}, "style_masks": {}},
                                      "colormatch": {}}))
    assert run_stage(stage.SPEC, stage_parser(stage.SPEC, "t"), stage.main, argv) == 0 and stamp.is_file()
    complete = yaml.safe_load(params.read_text())
    preflight(validate_params(complete), complete, params)
    raw = {"data": {"scenes": {"s": "scene"}}}
    with pytest.raises(ParamsError, match="data.style_masks"):  # the raw mapping, not the filled-in defaults
        preflight(validate_params(raw), raw, params)


def test_schema_errors_do_not_print_the_whole_params(tmp_path) -> None:
    with pytest.raises(ParamsError, match=r"stylize\.optim\.iterations: .*\(got 'many'\)"):  # a scalar culprit is shown
        validate_params({"data": {"scenes": {"s": "scene"}}, "stylize": {"optim": {"iterations": "many"}}})
    raw = {"data": {"scenes": {"s": "scene"}, "styles": {}},
           "colormatches": {"e": {"scene": "s", "transfer": "single", "style": "missing"}}}
    with pytest.raises(ParamsError) as exc:
        validate_params(raw)
    msg = str(exc.value)
    assert "colormatches.e uses style 'missing'" in msg
    assert "'scenes'" not in msg and "{'data'" not in msg  # the mapping behind a cross-check is not printed


def test_a_bare_scene_path_is_caught_before_dvc_reads_item_path(tmp_path, capsys) -> None:
    """dvc.yaml reads ${item.path}; DVC itself would stop with "Could not find 'item.path'" before any stage."""
    from abcgs.preflight import main

    shutil.copy(REPO_ROOT / "dvc.yaml", tmp_path / "dvc.yaml")
    raw = yaml.safe_load((REPO_ROOT / "params.yaml").read_text())
    raw["data"]["scenes"]["fern"] = "scenes/fern"
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(raw))
    assert main([str(tmp_path / "params.yaml")]) == 2
    err = capsys.readouterr().err
    assert "data.scenes.fern: a plain path" in err and "`fern: {path: scenes/fern}`" in err
    raw["data"]["scenes"]["fern"] = {"path": "scenes/fern"}
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(raw))
    assert main([str(tmp_path / "params.yaml")]) == 2  # now the next check: the folder does not exist
    assert "data.scenes.fern:" in capsys.readouterr().err
    del raw["data"]["scenes"]["fern"]
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(raw))
    assert main([str(tmp_path / "params.yaml")]) == 0
