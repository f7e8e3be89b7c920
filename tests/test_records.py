"""eval.records: the benchmark records' own DVC project (``docs/dvc.yaml``), apart from the repository's pipeline."""

from __future__ import annotations

import json
import shlex
from pathlib import Path

from conftest import REPO_ROOT

from eval.records import PROJECT, RECORDS, command, deps, records_yaml, stale
from eval.suite import discover, find


def test_the_committed_records_pipeline_is_current() -> None:
    assert (REPO_ROOT / PROJECT / "dvc.yaml").read_text(encoding="utf-8") == records_yaml(), \
        "docs/dvc.yaml is not current: run `python -m eval records --write`"


def test_each_record_runs_its_benchmark_and_depends_on_the_code_it_runs() -> None:
    for r in RECORDS:
        words = shlex.split(command(r))
        assert words[:3] == ["cd", "..", "&&"] and words[3:8] == ["python", "-m", "eval", "run", r.bench]
        assert words[-2:] == ["--json", f"{PROJECT}/{r.out}"] and (REPO_ROOT / PROJECT / r.out).is_file()
        found = deps(r)
        module = find(r.bench, discover()).module.replace(".", "/")
        assert f"../{module}.py" in found and "../eval/record.py" in found and "../abcgs/runtime.py" in found, r.name
        assert not any("__pycache__" in d or d.endswith((".so", ".pyc")) for d in found), r.name
        assert all((REPO_ROOT / PROJECT / d).is_file() for d in found), r.name  # files, never folders
    fit = next(r for r in RECORDS if r.bench == "fit_schedule")
    assert {"../abcgs/fit/training.py", "../abcgs/fit/strategy/default.py", "../params.yaml"} <= set(deps(fit))
    suite = next(r for r in RECORDS if r.bench == "test_suite")
    assert {"../tests/conftest.py", "../stages/stylize.py", "../README.md"} <= set(deps(suite))


def test_the_repository_pipeline_and_the_records_project_are_apart() -> None:
    """The repository's `dvc repro` / `dvc status` never see a record's stage, and the records' project holds them
    all."""
    from dvc.repo import Repo

    with Repo(str(REPO_ROOT)) as repo:
        outer = {s.addressing for s in repo.index.stages}
    with Repo(str(REPO_ROOT / PROJECT)) as repo:
        inner = {s.name for s in repo.index.stages}
    assert inner == {r.name for r in RECORDS}
    assert "preflight" in outer and not any(Path(a.split(":")[0]).parts[:1] == (PROJECT,) for a in outer), outer


def test_stale_says_what_changed_per_stage() -> None:
    status = json.loads('{"fuzz": [{"changed deps": {"/r/abcgs/x.py": "modified", "/r/eval/y.py": "modified"}}, '
                        '{"changed outs": {"measurements/fuzz.json": "deleted"}}], "structure": ["changed command"]}')
    assert stale(status) == {"fuzz": "2 deps, 1 outs", "structure": "changed command"}
    assert stale({}) == {}


def test_status_names_each_record_once(tmp_path: Path) -> None:
    """`python -m eval records --status` as the README writes it, on a copy of docs/'s DVC project over the same
    files: the tree's own docs/ holds the test suite's record busy while `dvc repro test_suite` runs this suite."""
    import shutil
    import subprocess
    import sys

    root = tmp_path / "repo"
    shutil.copytree(REPO_ROOT / PROJECT, root / PROJECT, ignore=shutil.ignore_patterns("tmp", "img", "*.md"))
    for top in sorted({Path(d).parts[1] for r in RECORDS for d in deps(r)}):  # ../abcgs/x.py -> abcgs
        (root / top).symlink_to(REPO_ROOT / top)
    subprocess.run(["git", "init", "-q", str(root)], check=True)
    proc = subprocess.run([sys.executable, "-m", "eval", "records", "--status", "--root", str(root)], cwd=REPO_ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode in (0, 1), proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    assert [line.split()[0] for line in lines] == [r.name for r in RECORDS], proc.stdout
    assert all(line.split()[2] in ("current", "stale") for line in lines), proc.stdout
    assert (proc.returncode == 1) == any(" stale " in f"{line} " for line in lines)
    own = subprocess.run([sys.executable, "-m", "eval", "records", "--status"], cwd=REPO_ROOT, capture_output=True,
                         text=True, timeout=300)
    if own.returncode in (0, 1):  # the tree's own project, where no run holds it: the same verdicts
        assert own.stdout == proc.stdout
