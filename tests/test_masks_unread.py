"""A scene whose colour matches are all single-image transfer: nothing reads its content labels, so its ``masks``
stage lifts and re-cuts nothing. The preflight stage writes, per scene, whether a colour match reads them; the
masks stage depends on that file (not on the colour matches) and writes all-0 labels that the later stages load."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT
from test_splats import make_model

from abcgs import layout
from abcgs.dag import load_stage
from abcgs.features.params import TransferSpec, content_label_readers
from abcgs.gaussians.ply import write_ply
from abcgs.masks.outputs import UNREAD_SOURCE, load_scene_masks
from abcgs.pipeline import run_stage, stage_parser
from abcgs.sfm.model import read_scene


def test_the_colour_matches_that_read_a_scenes_labels() -> None:
    matches = {"a": TransferSpec(scene="s", style="p"), "b": TransferSpec(scene="t", transfer="semantic", style="p"),
               "c": TransferSpec(scene="t", transfer="compositional", styles={1: "p"}),
               "d": TransferSpec(scene="t", style="p")}
    assert content_label_readers(matches, "s") == [] and content_label_readers(matches, "t") == ["b", "c"]
    assert content_label_readers(matches, "other") == []


def test_the_preflight_stage_says_which_scenes_labels_are_read(tmp_path: Path) -> None:
    """The repository's params (the tiny scene: a compositional and a semantic match) and a single-only copy."""
    stage = load_stage(REPO_ROOT / "stages" / "preflight.py")
    raw = yaml.safe_load((REPO_ROOT / "params.yaml").read_text())
    (tmp_path / "dvc.yaml").write_text((REPO_ROOT / "dvc.yaml").read_text())
    for single_only in (False, True):
        if single_only:
            raw["colormatches"] = {"tiny_single": raw["colormatches"]["tiny_single"]}
            raw["experiments"] = {"tiny_single": raw["experiments"]["tiny_single"]}
        (tmp_path / "params.yaml").write_text(yaml.safe_dump(raw))
        use = tmp_path / "out" / "label_use"
        assert run_stage(stage.SPEC, stage_parser(stage.SPEC, "t"), stage.main, [
            "--params", str(tmp_path / "params.yaml"), "--out", str(tmp_path / "out" / "preflight.json"),
            "--record", str(tmp_path / "out" / "report.json"), "--label-use", str(use)]) == 0
        assert sorted(p.name for p in use.iterdir()) == ["tiny.json"]
        assert json.loads((use / "tiny.json").read_text()) == {"content_labels_read": not single_only}


def test_the_masks_stage_of_a_single_only_scene_writes_labels_at_0_at_once(tmp_path: Path, tiny_colmap: Path) -> None:
    stage = load_stage(REPO_ROOT / "stages" / "masks.py")
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"data": {"scenes": {"s": {"path": "scene"}}}}))
    model = tmp_path / "point_cloud.ply"
    write_ply(model, make_model(5000, 0))
    use = layout.label_use("s", tmp_path / "out")
    use.parent.mkdir(parents=True)
    use.write_text(json.dumps({"content_labels_read": False}))
    (tmp_path / "stamp.json").write_text("{}")
    out = tmp_path / "out" / "s" / "masks"
    t0 = time.perf_counter()
    assert run_stage(stage.SPEC, stage_parser(stage.SPEC, "masks"), stage.main, [
        "--params", str(params), "--scene", "s", "--preflight", str(tmp_path / "stamp.json"), "--colmap",
        str(tiny_colmap), "--model", str(model), "--label-use", str(use), "--out", str(out)]) == 0
    assert time.perf_counter() - t0 < 10.0
    record = json.loads(layout.MasksDir(out).record.read_text())
    assert record["source"] == UNREAD_SOURCE and record["warnings"] == [] and record["n_labels"] == 0
    scene = read_scene(tiny_colmap)
    masks = load_scene_masks(out, scene, 5000)  # as the colormatch and stylize stages load them
    assert int(masks.gaussian_labels.abs().sum()) == 0 and len(masks.view_labels) == len(scene.cameras)
    assert all(v.shape == (c.height, c.width) and not v.any() for v, c in zip(masks.view_labels, scene.cameras))
    assert not layout.MasksDir(out).overlay.exists()


@pytest.mark.parametrize("stage", ["reference", "evaluate"])
def test_reference_and_evaluate_do_not_depend_on_the_masks_stage(stage: str) -> None:
    body = yaml.safe_load((REPO_ROOT / "dvc.yaml").read_text())["stages"][stage]["do"]
    assert not any("/masks" in d for d in body["deps"]), body["deps"]
    masks = yaml.safe_load((REPO_ROOT / "dvc.yaml").read_text())["stages"]["masks"]["do"]
    assert "out/label_use/${key}.json" in masks["deps"] and "colormatches" not in masks.get("params", [])
