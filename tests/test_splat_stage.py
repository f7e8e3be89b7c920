"""The fit stage imports a scene's trained splat through DVC, and the export script gives it back: `dvc repro` of a
scene whose `splat` names an INRIA output folder of another scene's fit (the same photos)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import copy_repo, run_in

from abcgs.gaussians.ply import read_ply
from abcgs.sfm.model import read_scene

pytestmark = pytest.mark.slow


def _small(params: dict) -> None:
    params["tiny"].update(n_views=8)
    params["fit"]["iterations"] = 200


def test_fit_stage_imports_an_inria_folder_and_export_gives_it_back(tmp_path: Path) -> None:
    repo = copy_repo(tmp_path / "repo", _small)
    proc = run_in(["dvc", "repro", "fit@tiny"], repo, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads((repo / "out/tiny/gs/splat_source.json").read_text())["format"] is None
    folder = repo / "data/tiny2"
    shutil.copytree(repo / "data/tiny/images", folder / "images")
    trained = folder / "trained"
    (trained / "point_cloud/iteration_200").mkdir(parents=True)
    shutil.copy(repo / "out/tiny/gs/point_cloud.ply", trained / "point_cloud/iteration_200/point_cloud.ply")
    scene = read_scene(repo / "out/tiny/colmap")
    (trained / "cameras.json").write_text(json.dumps([
        {"id": i, "img_name": Path(c.name).stem, "width": c.width, "height": c.height, "position": c.center.tolist(),
         "rotation": np.linalg.inv(c.viewmat)[:3, :3].tolist(), "fx": float(c.K[0, 0]), "fy": float(c.K[1, 1])}
        for i, c in enumerate(scene.cameras)]))
    (trained / "cfg_args").write_text("Namespace(sh_degree=0, source_path='data/tiny')")
    params = yaml.safe_load((repo / "params.yaml").read_text())
    params["data"]["scenes"]["tiny2"] = {"path": "data/tiny2", "splat": "trained"}
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    proc = run_in(["dvc", "repro", "fit@tiny2"], repo, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    record = json.loads((repo / "out/tiny2/gs/metrics.json").read_text())
    assert record["iterations"] == 0 and record["imported"]["format"] == "inria"
    assert record["psnr"] > 16.0 and json.loads((repo / "out/tiny2/fit_metrics.json").read_text())["heldout_psnr"] > 16.0
    assert read_ply(repo / "out/tiny2/gs/point_cloud.ply").num_gaussians == read_ply(repo / "out/tiny/gs/point_cloud.ply").num_gaussians
    # the export stage is the experiments' (it reads no params: the key names no file here, the paths are explicit)
    proc = run_in(["python", "stages/export.py", "--experiment", "tiny_single", "--preflight", "out/preflight.json",
                   "--ply", "out/tiny2/gs/point_cloud.ply",
                   "--out", "out/tiny2/x.spz",
                   "--source", "out/tiny2/gs/splat_source.json", "--returned", "out/tiny2/returned"], repo, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    back = repo / "out/tiny2/returned/trained"
    assert (back / "cameras.json").read_text() == (trained / "cameras.json").read_text()
    assert (back / "point_cloud/iteration_200/point_cloud.ply").is_file()
    assert json.loads((repo / "out/tiny2/returned/returned.json").read_text())["format"] == "inria"
