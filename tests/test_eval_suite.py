"""The benchmark suite's runner (``python -m eval``): it lists every benchmark and study from source and runs one by
name with its own arguments; every benchmark's ``--json`` record is written through :mod:`eval.record`, with the
run's provenance."""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from datetime import datetime, timedelta
from pathlib import Path

import pytest

from eval.record import bench_parser, write_record
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


# --- the record a benchmark writes (eval/record.py) ------------------------------------------------------------


def _record_helpers_called(tree: ast.AST) -> set[str]:
    """Which of ``bench_parser`` / ``write_record`` / ``provenance``, imported from :mod:`eval.record` (at any
    depth), the module calls."""
    imported = {a.asname or a.name: a.name for node in ast.walk(tree)
                if isinstance(node, ast.ImportFrom) and node.module == "eval.record" for a in node.names}
    return {imported[n.func.id] for n in ast.walk(tree)
            if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id in imported}


def _adds_json_option(tree: ast.AST) -> bool:
    """Whether the module declares ``--json`` itself (an ``add_argument("--json", ...)`` call)."""
    return any(isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr == "add_argument"
               and any(isinstance(a, ast.Constant) and a.value == "--json" for a in n.args) for n in ast.walk(tree))


def test_every_benchmark_with_a_json_record_uses_the_shared_parser_or_writer():
    """A suite module that offers ``--json`` builds its parser with :func:`eval.record.bench_parser` or writes its
    record with :func:`eval.record.write_record` (which adds the run's provenance)."""
    offenders, with_record = [], []
    for b in discover():
        tree = ast.parse((REPO / "eval" / b.room / f"{b.name}.py").read_text(encoding="utf-8"))
        used = _record_helpers_called(tree)
        if used:
            with_record.append(b.module)
        if _adds_json_option(tree) and not used & {"bench_parser", "write_record"}:
            offenders.append(b.module)
    assert not offenders, ("these declare --json themselves and write their record by hand; build the parser with "
                           f"eval.record.bench_parser or write with eval.record.write_record: {offenders}")
    assert {"eval.bench.structure", "eval.bench.fit_schedule", "eval.bench.gpu"} <= set(with_record)


def test_the_json_option_check_sees_a_hand_built_one():
    hand = ast.parse("import argparse\nap = argparse.ArgumentParser()\nap.add_argument('--json')\n")
    shared = ast.parse("def main():\n    from eval.record import bench_parser as bp\n    ap = bp(__doc__)\n")
    assert _adds_json_option(hand) and not _record_helpers_called(hand)
    assert not _adds_json_option(shared) and _record_helpers_called(shared) == {"bench_parser"}


def test_bench_parser_takes_the_docstring_and_an_optional_json_path():
    ap = bench_parser("What it measures.\n\n    python -m eval.bench.x --json out.json\n")
    assert ap.parse_args([]).json is None
    assert ap.parse_args(["--json", "a/b.json"]).json == Path("a/b.json")
    assert "    python -m eval.bench.x --json out.json" in ap.format_help()  # kept as written


def test_write_record_adds_the_provenance_and_keeps_the_records_own_keys(tmp_path):
    import torch  # provenance names torch once it is loaded (as in every benchmark that uses it)

    path = tmp_path / "deep" / "r.json"
    write_record(path, {"rows": [{"ms": 1.5}], "machine": "the benchmark's own"}, ["--steps", "3", "--note", "a b"])
    rec = json.loads(path.read_text())
    assert rec["rows"] == [{"ms": 1.5}] and rec["machine"] == "the benchmark's own"
    prov = rec["provenance"]
    assert prov["command"].startswith("python ") and prov["command"].endswith(" --steps 3 --note 'a b'")
    assert prov["cores"] >= 1 and prov["machine"] and prov["python"].count(".") == 2
    assert prov["torch"] == torch.__version__ and prov["torch_threads"] == torch.get_num_threads()
    assert prov["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert datetime.fromisoformat(prov["date"]).utcoffset() == timedelta(0)
    assert prov["loadavg"] is None or len(prov["loadavg"]) == 3
    write_record(path, {"provenance": {"command": "kept"}, "x": 1})
    assert json.loads(path.read_text()) == {"provenance": {"command": "kept"}, "x": 1}
    assert not list(path.parent.glob(".*.tmp*")), "the atomic writer left its temporary file"


def test_provenance_names_the_simd_level_and_the_kernel_variant_a_run_used():
    """A run with ``ATEN_CPU_CAPABILITY=default`` takes ATen's portable kernels and abcgs's portable build; the
    record says so (a timing made with lower SIMD code than the machine has is labelled as such)."""
    code = ("import json; import torch; from abcgs.render.cpu import load_extension; load_extension(); "
            "from eval.record import provenance; p = provenance([]); "
            "print(json.dumps([p['cpu_capability'], p['kernels'], p['isa_limits']]))")
    env = {k: v for k, v in os.environ.items() if k not in ("ONEDNN_MAX_CPU_ISA", "MKL_ENABLE_INSTRUCTIONS")}
    env["ATEN_CPU_CAPABILITY"] = "default"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO, env=env)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == ["DEFAULT", "portable", {"ATEN_CPU_CAPABILITY": "default"}]


def test_provenance_does_not_load_torch():
    code = ("import sys; from eval.record import provenance; p = provenance([]); "
            "print('torch' in sys.modules, 'torch' in p)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["False", "False"]


def test_a_benchmark_run_through_the_suite_writes_its_record_with_the_command_that_reproduces_it(tmp_path):
    out = tmp_path / "structure.json"
    proc = subprocess.run([sys.executable, "-m", "eval", "run", "structure", "--json", str(out), "--label", "t"],
                          capture_output=True, text=True, timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    rec = json.loads(out.read_text())
    assert rec["t"]["modules"] > 0 and rec["t"]["upward_imports"] == 0
    assert rec["provenance"]["command"] == f"python -m eval.bench.structure --json {out} --label t"
    assert "torch" not in rec["provenance"]  # the structure count never loads torch


def test_the_test_suite_benchmark_times_a_pytest_run_and_keeps_its_outcomes(tmp_path):
    """``python -m eval run test_suite`` on a small test file of its own: one pass, one failure, one skip. The
    record counts each, names the failing test and passes pytest's exit code through."""
    tests = tmp_path / "test_tiny.py"
    tests.write_text("import pytest, time\n\n"
                     "def test_ok():\n    time.sleep(0.2)\n\n"
                     "def test_bad():\n    assert 1 == 2\n\n"
                     "@pytest.mark.skip(reason='shown as skipped')\ndef test_skipped():\n    pass\n")
    out = tmp_path / "suite.json"
    proc = subprocess.run([sys.executable, "-m", "eval", "run", "test_suite", "--json", str(out), "--slowest", "2",
                           "--", str(tests), "-p", "no:cacheprovider"],
                          capture_output=True, text=True, timeout=300, cwd=REPO)
    assert proc.returncode == 1, proc.stdout + proc.stderr  # pytest's own code for failed tests
    rec = json.loads(out.read_text())
    assert rec["exit_code"] == 1 and rec["counts"] == {"passed": 1, "failed": 1, "skipped": 1}
    assert len(rec["slowest"]) == 2 and rec["slowest"][0]["test"].endswith("::test_ok")
    assert rec["slowest"][0]["seconds"] >= 0.2 and rec["wall_seconds"] >= rec["test_seconds"]
    assert "pytest exit 1" in proc.stdout and "test_ok" in proc.stdout


def test_the_test_suite_benchmark_runs_pytest_as_make_test_does(tmp_path):
    """The benchmark's default is make test's two pytest-xdist processes (the Makefile's ``TEST_ARGS``), each file on
    one, and it still counts every test."""
    from eval.bench.test_suite import WORKERS, worker_args

    makefile = (REPO / "Makefile").read_text()
    assert "pytest -q $(TEST_ARGS)" in makefile and "TEST_ARGS ?= -n 2 --dist loadfile --durations=20\n" in makefile
    assert WORKERS == 2 and worker_args(0) == [] and worker_args(2) == ["-n", "2", "--dist", "loadfile"]
    for name in ("a", "b"):
        (tmp_path / f"test_{name}.py").write_text("def test_one():\n    pass\n\ndef test_two():\n    pass\n")
    out = tmp_path / "suite.json"
    proc = subprocess.run([sys.executable, "-m", "eval", "run", "test_suite", "--json", str(out), "--workers", "2",
                           "--", str(tmp_path), "-p", "no:cacheprovider"],
                          capture_output=True, text=True, timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rec = json.loads(out.read_text())
    assert rec["workers"] == 2 and rec["counts"] == {"passed": 4}
    assert sorted(c["test"].rsplit("/", 1)[-1] for c in rec["slowest"][:4]) == [
        "test_a.py::test_one", "test_a.py::test_two", "test_b.py::test_one", "test_b.py::test_two"]
