"""The benchmark suite's runner (``python -m eval``): it lists every benchmark and study from source and runs one by
name with its own arguments."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from eval.suite import Benchmark, discover, find, main

REPO = Path(__file__).resolve().parents[1]


def test_every_runnable_module_is_listed_with_its_summary_and_helpers_are_not():
    found = {b.module: b for b in discover()}
    assert "eval.bench.fit_schedule" in found and "eval.studies.seed_spread" in found
    for helper in ("eval.bench.timing", "eval.bench.browser", "eval.bench.regression", "eval.bench.real_features"):
        assert helper not in found  # shared by benchmarks, not run on their own
    for b in found.values():
        path = REPO / "eval" / b.room / f"{b.name}.py"
        assert '__name__ == "__main__"' in path.read_text()
        assert b.summary, f"{b.module} has no docstring saying what it measures"


def test_a_name_resolves_to_one_benchmark_or_a_clear_error():
    suite = discover()
    assert find("fit_schedule", suite).module == "eval.bench.fit_schedule"
    assert find("studies.seed_spread", suite).module == "eval.studies.seed_spread"
    with pytest.raises(SystemExit, match="no benchmark 'nope'; `python -m eval list` shows them"):
        find("nope", suite)
    twins = [Benchmark("bench", "x", ""), Benchmark("studies", "x", "")]
    with pytest.raises(SystemExit, match="names 2 benchmarks"):
        find("x", twins)
    assert find("studies.x", twins).room == "studies"


def test_list_prints_one_line_per_benchmark(capsys):
    assert main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(discover())
    assert any(line.split()[:2] == ["bench", "fit_schedule"] for line in lines)


def test_run_passes_the_arguments_after_the_name_to_the_benchmark():
    proc = subprocess.run([sys.executable, "-m", "eval", "run", "structure", "--help"], capture_output=True,
                          text=True, timeout=120, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    assert "usage:" in proc.stdout and "Structure numbers" in proc.stdout
