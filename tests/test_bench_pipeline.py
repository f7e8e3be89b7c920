"""eval/bench/pipeline.py: per-stage wall, core use and peak RSS from a clean copy."""

from __future__ import annotations

import json
import platform

import pytest

from eval.bench import pipeline as bench_pipeline

pytestmark = pytest.mark.slow


def test_bench_runs_the_stages_a_target_needs_in_order(tmp_path) -> None:
    out = bench_pipeline.main(["--set", "fit.iterations=30", "--set", "fit.min_psnr=0", "--targets", "masks@tiny", "--json", str(tmp_path / "b.json")])
    names = [r["stage"] for r in out["stages"]]
    assert names == ["preflight", "make_tiny", "reconstruct@tiny", "fit@tiny", "masks@tiny"]
    for r in out["stages"]:
        assert r["rc"] == 0 and r["wall_s"] > 0 and r["cpu_s"] > 0 and 0 < r["core_use"] <= 2.5
        # measured as the stage's own processes: python + torch (the preflight stage imports no torch)
        assert r["peak_rss_mib"] > (20 if r["stage"] == "preflight" else 100), r
    assert out["total_wall_s"] >= sum(r["wall_s"] for r in out["stages"]) * 0.99
    assert out["peak_rss_mib"] == max(r["peak_rss_mib"] for r in out["stages"])
    machine = json.loads((tmp_path / "b.json").read_text())["machine"]
    assert machine["cpus"] >= 1
    if platform.system() == "Linux":  # the CPU's flags go beside the figures (they change them)
        assert machine["cpu"]["model"] and isinstance(machine["cpu"]["simd"], list)


def test_unknown_target_is_an_error_that_lists_the_stages(tmp_path) -> None:
    with pytest.raises(SystemExit, match="unknown stage"):
        bench_pipeline.main(["--targets", "fitt@tiny", "--work", str(tmp_path)])


def _run(stages: dict[str, float]) -> dict:
    rows = [{"stage": k, "wall_s": v, "cpu_s": v, "peak_rss_mib": 100.0 + v} for k, v in stages.items()]
    return {"stages": rows, "total_wall_s": sum(stages.values()), "peak_rss_mib": max(r["peak_rss_mib"] for r in rows)}


def test_compare_sums_stage_kinds_and_gives_the_ratio(tmp_path, capsys) -> None:
    before = _run({"fit@fern": 1000.0, "colormatch@a": 150.0, "colormatch@b": 150.0, "evaluate@a": 300.0})
    after = _run({"fit@fern": 500.0, "colormatch@a": 75.0, "reference@fern": 10.0, "evaluate@a": 165.0})
    (tmp_path / "b.json").write_text(json.dumps(before))
    (tmp_path / "a.json").write_text(json.dumps(after))
    out = bench_pipeline.main(["--compare", str(tmp_path / "b.json"), str(tmp_path / "a.json")])
    kinds = {r["kind"]: r for r in out["kinds"]}
    assert kinds["colormatch"]["before_s"] == 300.0 and kinds["colormatch"]["before_n"] == 2
    assert kinds["colormatch"]["ratio"] == pytest.approx(4.0)
    assert kinds["reference"]["before_s"] is None and kinds["reference"]["ratio"] is None
    assert out["total_ratio"] == pytest.approx(1600.0 / 750.0)
    assert "2.13" in capsys.readouterr().out
    (tmp_path / "x.json").write_text("{}")
    with pytest.raises(SystemExit, match="not a bench_pipeline JSON"):
        bench_pipeline.main(["--compare", str(tmp_path / "x.json"), str(tmp_path / "a.json")])


def test_compare_projects_a_baseline_run_to_more_paintings(tmp_path, capsys) -> None:
    """One --baseline run's JSON compares its two runs; --paintings K keeps the per-scene stages once and scales
    the per-painting ones (colour match, stylize, evaluate, export; not export_scene) by K."""
    before = _run({"fit@fern": 1000.0, "colormatch@a_fast": 150.0, "colormatch@a_nnfm": 150.0,
                   "stylize@a_fast": 800.0, "evaluate@a_fast": 300.0, "export_scene@fern": 20.0, "export@a_fast": 5.0})
    after = _run({"fit@fern": 700.0, "reference@fern": 10.0, "colormatch@a": 75.0, "stylize@a_fast": 600.0,
                  "evaluate@a_fast": 150.0, "export_scene@fern": 20.0, "export@a_fast": 5.0})
    (tmp_path / "ab.json").write_text(json.dumps({"baseline": before, "current": after, "machine": {}}))
    out = bench_pipeline.main(["--compare", str(tmp_path / "ab.json"), "--paintings", "3"])
    assert out["total_ratio"] == pytest.approx(2425.0 / 1560.0)
    proj = out["projection"]
    assert proj["before"]["per_scene_s"] == pytest.approx(1020.0)
    assert proj["before"]["projected_s"] == pytest.approx(1020.0 + 3 * 1405.0)
    assert proj["after"]["projected_s"] == pytest.approx(730.0 + 3 * 830.0)
    assert proj["ratio"] == pytest.approx((1020.0 + 3 * 1405.0) / (730.0 + 3 * 830.0))
    assert "an extrapolation" in capsys.readouterr().out
    two = bench_pipeline.main(["--compare", str(tmp_path / "ab.json"), "--paintings", "6", "--measured-paintings", "2"])
    assert two["projection"]["ratio"] == pytest.approx(proj["ratio"])
    with pytest.raises(SystemExit, match="not a --baseline run's JSON"):
        (tmp_path / "one.json").write_text(json.dumps(after))
        bench_pipeline.main(["--compare", str(tmp_path / "one.json")])
    with pytest.raises(SystemExit, match="use it with --compare"):
        bench_pipeline.main(["--paintings", "3"])
    with pytest.raises(SystemExit, match=">= 1"):
        bench_pipeline.main(["--compare", str(tmp_path / "ab.json"), "--paintings", "0"])


def test_an_interleaved_run_saves_each_stage_as_it_ends(tmp_path, monkeypatch, capsys) -> None:
    """A run of hours may be cut off: after every stage the JSON holds the stages measured so far, marked
    unfinished, and --compare reads such a file (saying so)."""
    saved: list[tuple[int, int]] = []

    def fake_stage(repo, name, label=""):
        return {"stage": name, "wall_s": 10.0 if "baseline" in label else 5.0, "cpu_s": 1.0, "peak_rss_mib": 50.0,
                "core_use": 0.1, "rc": 0}

    monkeypatch.setattr(bench_pipeline, "run_stage", fake_stage)

    def on_stage(rows_b, rows_c):
        saved.append((len(rows_b), len(rows_c)))
        partial = {"baseline": {**bench_pipeline.summary(rows_b), "stage_count": 3},
                   "current": {**bench_pipeline.summary(rows_c), "stage_count": 2}, "complete": False}
        (tmp_path / "ab.json").write_text(json.dumps(partial))

    rows_b, rows_c = bench_pipeline.bench_interleaved(tmp_path, ["a", "b", "c"], tmp_path, ["a", "b"], on_stage=on_stage)
    assert saved == [(1, 0), (1, 1), (1, 2), (2, 2), (3, 2)]  # baseline first on even steps, current on odd ones
    assert [r["stage"] for r in rows_b] == ["a", "b", "c"] and [r["stage"] for r in rows_c] == ["a", "b"]
    out = bench_pipeline.main(["--compare", str(tmp_path / "ab.json")])
    assert out["total_ratio"] == pytest.approx(30.0 / 10.0)
    assert "an unfinished run, 3 of 3 stages" in capsys.readouterr().out
    assert bench_pipeline.summary([])["peak_rss_mib"] == 0.0  # a file saved before any stage ended


def test_baseline_runs_interleave_with_the_working_tree(tmp_path, capsys) -> None:
    """--baseline: a clean copy of a git revision runs beside the working tree's copy, one stage of each in turn,
    which goes first alternating; both totals and the comparison are written."""
    out = bench_pipeline.main(["--baseline", "HEAD", "--targets", "reconstruct@tiny", "--json", str(tmp_path / "ab.json")])
    assert [r["stage"] for r in out["baseline"]["stages"]] == ["preflight", "make_tiny", "reconstruct@tiny"]
    assert [r["stage"] for r in out["current"]["stages"]] == ["preflight", "make_tiny", "reconstruct@tiny"]
    assert out["baseline"]["revision"] == "HEAD"
    assert out["baseline"]["total_wall_s"] == pytest.approx(sum(r["wall_s"] for r in out["baseline"]["stages"]))
    printed = [line.split()[:2] for line in capsys.readouterr().out.splitlines() if line.startswith("  ")]
    assert printed[:6] == [["baseline", "preflight"], ["current", "preflight"], ["current", "make_tiny"],
                           ["baseline", "make_tiny"], ["baseline", "reconstruct@tiny"], ["current", "reconstruct@tiny"]]
    assert out["comparison"]["total_ratio"] > 0
    assert {k["kind"] for k in json.loads((tmp_path / "ab.json").read_text())["comparison"]["kinds"]} >= {"make_tiny"}
    with pytest.raises(ValueError, match="git archive"):
        bench_pipeline.main(["--baseline", "no-such-revision", "--targets", "make_tiny", "--work", str(tmp_path / "w")])
