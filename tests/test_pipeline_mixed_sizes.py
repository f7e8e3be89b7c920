"""End to end with views of different sizes: `dvc repro` of the tiny pipeline on a scene shot with
two cameras whose images differ by a pixel in width. COLMAP undistorts each camera to its own size, so the
views reach every stage at several sizes; evaluation pairs them on one grid and says how many it resampled."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest
from conftest import copy_repo, run_in

pytestmark = pytest.mark.slow


def _mixed(params: dict) -> None:
    params["tiny"].update(n_views=8, odd_view_width_delta=1)
    params["fit"].update(iterations=200, strategy={"refine_every": 20})  # as REDUCED: densifying every 10 steps of 200
    params["colormatch"]["refit_iterations"] = 10
    params["stylize"]["optim"].update(iterations=10, color_pass_iterations=5)
    params["colormatches"] = {"tiny_single": params["colormatches"]["tiny_single"]}
    params["experiments"] = {"tiny_single": params["experiments"]["tiny_single"]}


@pytest.fixture(scope="module")
def repo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    repo = copy_repo(tmp_path_factory.mktemp("mixed") / "repo", _mixed)
    proc = run_in(["dvc", "repro"], repo, timeout=1500)
    assert proc.returncode == 0, f"dvc repro failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}"
    return repo


def test_views_of_different_sizes_run_end_to_end(repo: Path) -> None:
    out = repo / "out"
    sizes = {p.name: cv2.imread(str(p)).shape[:2] for p in sorted((repo / "data/tiny/images").glob("*.png"))}
    assert {hw[1] for hw in sizes.values()} == {159, 160}  # two cameras
    views = sorted((out / "tiny/colmap/images").glob("*.png"))
    undistorted = {p.name: cv2.imread(str(p)).shape[:2] for p in views}
    assert len(undistorted) == 8 and len(set(undistorted.values())) > 1
    for name, hw in undistorted.items():  # every stage's per-view output keeps its view's size
        assert cv2.imread(str(out / "tiny/masks/views" / name), cv2.IMREAD_UNCHANGED).shape[:2] == hw, name
        assert cv2.imread(str(out / "tiny_single/stylize/renders" / name)).shape[:2] == hw, name
    ev = json.loads((out / "tiny_single/eval.json").read_text())
    assert ev["n_view_sizes"] == len(set(undistorted.values()))
    assert ev["short_pairs_resampled"] > 0 and ev["short_rmse"] < 0.2 and ev["long_rmse"] < 0.3
    assert (out / "tiny_single/stylize/turntable.mp4").stat().st_size > 0
    assert "tiny_single" in (repo / "reports/report.html").read_text()
