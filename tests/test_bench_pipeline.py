"""eval/bench_pipeline.py: per-stage wall, core use and peak RSS from a clean copy (issue 13's baseline tool)."""

from __future__ import annotations

import json

import pytest

from eval import bench_pipeline

pytestmark = pytest.mark.slow


def test_bench_runs_the_stages_a_target_needs_in_order(tmp_path) -> None:
    out = bench_pipeline.main(["--set", "fit.iterations=30", "--targets", "masks@tiny", "--json", str(tmp_path / "b.json")])
    names = [r["stage"] for r in out["stages"]]
    assert names == ["make_tiny", "reconstruct@tiny", "fit@tiny", "masks@tiny"]
    for r in out["stages"]:
        assert r["rc"] == 0 and r["wall_s"] > 0 and r["cpu_s"] > 0 and 0 < r["core_use"] <= 2.5
        assert r["peak_rss_mib"] > 100  # python + torch, measured as the stage's own processes
    assert out["total_wall_s"] >= sum(r["wall_s"] for r in out["stages"]) * 0.99
    assert out["peak_rss_mib"] == max(r["peak_rss_mib"] for r in out["stages"])
    assert json.loads((tmp_path / "b.json").read_text())["machine"]["cpus"] >= 1


def test_unknown_target_is_an_error_that_lists_the_stages(tmp_path) -> None:
    with pytest.raises(SystemExit, match="unknown stage"):
        bench_pipeline.main(["--targets", "fitt@tiny", "--work", str(tmp_path)])
