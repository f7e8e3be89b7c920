"""The test suite's time: how long ``pytest`` takes, per file, and its slowest tests, so that CI keeps its margin as
tests are added.

    python -m eval run test_suite --json docs/measurements/test_suite.json        # the whole suite (what CI runs)
    python -m eval run test_suite -- tests/test_label_field.py -x                  # any pytest arguments after --

Runs ``python -m pytest -q`` in the repository as ``make test`` does (``--workers 2``: two processes of pytest-xdist,
``--dist loadfile``, where ``tests/conftest.py`` makes the files that run pipelines one lane; ``--workers 0``: one
process), with a JUnit XML report (pytest's own ``--junitxml``) in a
temporary folder, reads each test case's seconds from it and prints: the wall time, the counts (passed, failed,
skipped, errors), the files by their summed seconds and the ``--slowest`` (30) tests. The record keeps them all,
with pytest's exit code; the command's own exit code is pytest's.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from abcgs.runtime import setup

setup()  # before anything that may load torch: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
from eval.record import bench_parser, write_record

REPO = Path(__file__).resolve().parents[2]
WORKERS = 2
"""pytest-xdist processes of ``make test``: two, the pipelines lane on one and the other files on the other
(docs/SCALING.md "The test suite")."""


def worker_args(workers: int) -> list[str]:
    """pytest's arguments for ``workers`` processes, each test file on one (its module fixtures computed once; in this
    repository's tests the pipelines lane's files count as one); none for 0 (one process)."""
    return ["-n", str(workers), "--dist", "loadfile"] if workers else []


def read_junit(path: Path) -> list[dict]:
    """Each test case of a JUnit XML report: ``{"test": file::name, "seconds", "outcome"}`` (``passed``, ``failed``,
    ``error`` or ``skipped``), in the report's order."""
    cases = []
    for case in ET.parse(path).getroot().iter("testcase"):
        outcome = "passed"
        for child in case:
            if child.tag in ("failure", "error", "skipped"):
                outcome = {"failure": "failed"}.get(child.tag, child.tag)
        module = case.get("classname", "").replace(".", "/")
        cases.append({"test": f"{module}.py::{case.get('name', '')}", "seconds": float(case.get("time", 0.0)),
                      "outcome": outcome})
    return cases


def summarise(cases: list[dict], wall: float, slowest: int) -> dict:
    """Counts by outcome, seconds per file (most first) and the ``slowest`` tests."""
    counts: dict[str, int] = {}
    files: dict[str, float] = {}
    for c in cases:
        counts[c["outcome"]] = counts.get(c["outcome"], 0) + 1
        name = c["test"].split("::")[0]
        files[name] = files.get(name, 0.0) + c["seconds"]
    by_file = dict(sorted(files.items(), key=lambda kv: -kv[1]))
    top = sorted(cases, key=lambda c: -c["seconds"])[:slowest]
    return {"wall_seconds": wall, "test_seconds": sum(c["seconds"] for c in cases), "counts": counts,
            "files": by_file, "slowest": top}


def main(argv: list[str] | None = None) -> int:
    ap = bench_parser(__doc__)
    ap.add_argument("--slowest", type=int, default=30, help="how many of the slowest tests to print and keep")
    ap.add_argument("--workers", type=int, default=WORKERS, help="pytest-xdist processes (0: one process)")
    ap.add_argument("pytest_args", nargs="*", help="arguments for pytest (after --); default: the whole suite")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="abcgs-test-suite-") as tmp:
        report = Path(tmp) / "junit.xml"
        t0 = time.perf_counter()
        rc = subprocess.call([sys.executable, "-m", "pytest", "-q", *worker_args(args.workers),
                               f"--junitxml={report}", *args.pytest_args],
                             cwd=REPO)
        wall = time.perf_counter() - t0
        cases = read_junit(report) if report.is_file() else []
    summary = summarise(cases, wall, args.slowest)
    print(f"\npytest exit {rc}: {summary['counts']} in {wall / 60:.1f} min (tests {summary['test_seconds'] / 60:.1f} "
          "min)")
    print("seconds per file (first 15):")
    for name, sec in list(summary["files"].items())[:15]:
        print(f"  {sec:8.1f}  {name}")
    print(f"the {len(summary['slowest'])} slowest tests:")
    for c in summary["slowest"]:
        print(f"  {c['seconds']:8.1f}  {c['test']} ({c['outcome']})")
    if args.json:
        write_record(args.json, {"pytest_args": args.pytest_args, "workers": args.workers, "exit_code": rc,
                                  **summary}, argv)
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
