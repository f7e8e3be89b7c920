"""make test's two processes: the files that run pipelines form one lane, handed out first (tests/conftest.py)."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest
from conftest import PIPELINE_MARKERS, REPO_ROOT, pipeline_lane_files


def test_every_test_with_a_pipeline_marker_is_in_a_lane_file(request: pytest.FixtureRequest) -> None:
    lane = pipeline_lane_files()
    assert {"tests/test_pipeline_e2e.py", "tests/test_cluster.py", "tests/test_viewer_browser.py"} <= lane
    assert "tests/test_params.py" not in lane
    for item in request.session.items:
        if any(item.get_closest_marker(m) for m in PIPELINE_MARKERS):
            assert item.nodeid.split("::", 1)[0] in lane, item.nodeid


def test_the_lane_runs_first_on_one_process_and_the_other_files_beside_it() -> None:
    """Fast tests of two lane files and two other files, on two processes: the lane's tests all ran on one process
    and before any other file's test there."""
    files = ["tests/test_params.py", "tests/test_bench_pipeline.py", "tests/test_dag.py", "tests/test_readme_workflow.py"]
    proc = subprocess.run([sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadfile", "-v", "-p", "no:cacheprovider",
                           *files, "-k", "compare_sums or shipped_params or out_of_range or makefile_repro or what_the_stage_specs_make"],
                          cwd=REPO_ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    ran = re.findall(r"^\[(gw\d)\] \[ *\d+%\] PASSED (tests/\S+?\.py)::", proc.stdout, re.M)
    lane = pipeline_lane_files()
    in_lane = [(worker, path) for worker, path in ran if path in lane]
    assert {p for _, p in in_lane} == {"tests/test_bench_pipeline.py", "tests/test_readme_workflow.py"}, ran
    worker = in_lane[0][0]
    assert {w for w, _ in in_lane} == {worker}, ran
    on_worker = [path for w, path in ran if w == worker]
    assert on_worker[:len(in_lane)] == [p for _, p in in_lane], ran
    assert {p for _, p in ran} - lane == {"tests/test_params.py", "tests/test_dag.py"}, ran
