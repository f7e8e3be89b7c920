"""abcgs.cluster: the pipeline as Slurm job arrays against one shared DVC cache.

Three layers:

- the plan (``dvc.yaml`` + params → jobs and arrays), the sbatch template and the parsers: pure functions, no Slurm;
- a toy DVC pipeline of shell commands, its jobs run one after the other without Slurm (``run_job``): the run
  cache carries every stage between clones, a failed experiment is reported missing by ``collect``;
- the tiny pipeline (REDUCED iteration counts) on a real one-node Slurm started on localhost (``slurm`` marker):
  every job completes, a job killed with ``scancel --signal=KILL`` during ``stylize`` and requeued (as Slurm's
  ``--requeue`` does after a node failure) restores what was finished and gives the uninterrupted result,
  ``collect``'s ``dvc repro`` runs no stage, and a second submit runs nothing. Debian's ``slurm-wlm`` and
  ``munge`` are installed when missing (root); without root these tests skip, or fail under CI.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml
from conftest import REPO_ROOT, copy_repo

from abcgs.cluster.job import run_job
from abcgs.cluster.plan import (
    PlanError,
    Resources,
    apply_sets,
    gpu_overrides,
    load_resources,
    make_plan,
)
from abcgs.cluster.run import RunInfo, StageLog, configure_cache, load_run, read_state, save_run
from abcgs.cluster.slurm import _expand_tasks, dependency, render_script
from abcgs.overlay import apply_overlay
from eval.bench.regression import reduce

SLURM = (pytest.mark.slow, pytest.mark.slurm)


def _slurm(f: Callable) -> Callable:
    for mark in SLURM:
        f = mark(f)
    return f


def _yaml(name: str) -> dict:
    return yaml.safe_load((REPO_ROOT / name).read_text())


# ------------------------------------------------------------------------------------------------ the plan
def test_the_tiny_pipeline_splits_into_prep_scene_experiments_and_report() -> None:
    plan = make_plan(_yaml("dvc.yaml"), _yaml("params.yaml"))
    params = _yaml("params.yaml")
    assert set(plan.jobs) == {"prep", "scene@tiny", "report"} | {f"experiment@{e}" for e in params["experiments"]}
    assert plan.jobs["prep"].targets[:2] == ("preflight", "make_tiny")
    scene = plan.jobs["scene@tiny"]
    assert set(scene.targets) == {f"{s}@tiny" for s in ("reconstruct", "fit", "masks", "reference", "export_scene")} \
        | {f"colormatch@{m}" for m in params["colormatches"]}
    assert scene.after == ("prep",)
    for e in params["experiments"]:
        job = plan.jobs[f"experiment@{e}"]
        assert job.targets == (f"stylize@{e}", f"evaluate@{e}", f"export@{e}") and job.after == ("scene@tiny",)
    assert plan.jobs["report"].targets == () and plan.jobs["report"].stages == ("report",)
    assert [a.name for a in plan.arrays] == ["prep", "scenes", "experiments@tiny", "report"]
    assert plan.array("scenes").after == (("prep", 0),)
    assert plan.array("experiments@tiny").after == (("scenes", 0),)
    assert plan.array("report").after == (("prep", None), ("scenes", None), ("experiments@tiny", None))
    assert plan.array("report").wait == "afterany" and plan.array("scenes").wait == "afterok"


def test_each_scene_gets_its_own_experiments_array_after_its_own_task() -> None:
    params = _yaml("params.yaml")
    params["data"]["scenes"]["fern"] = {"path": "/data/fern"}
    params["colormatches"]["fern_starry"] = {"scene": "fern", "transfer": "single", "style": "tiny_paint"}
    params["experiments"]["fern_fast"] = {"scene": "fern", "colormatch": "fern_starry", "method": "fast"}
    params["experiments"]["fern_nnfm"] = {"scene": "fern", "colormatch": "fern_starry", "method": "nnfm"}
    plan = make_plan(_yaml("dvc.yaml"), params)
    assert plan.array("scenes").jobs == ("scene@tiny", "scene@fern")
    assert "colormatch@fern_starry" in plan.jobs["scene@fern"].targets
    assert "colormatch@fern_starry" not in plan.jobs["scene@tiny"].targets
    fern = plan.array("experiments@fern")
    assert fern.jobs == ("experiment@fern_fast", "experiment@fern_nnfm") and fern.after == (("scenes", 1),)
    assert plan.jobs["experiment@fern_nnfm"].after == ("scene@fern",)
    assert Path(plan.to_dict()["jobs"]["report"]["name"]) == Path("report")
    assert type(plan).from_dict(json.loads(json.dumps(plan.to_dict()))) == plan


def test_a_stage_that_needs_a_job_it_does_not_wait_for_is_an_error() -> None:
    dvc = _yaml("dvc.yaml")
    dvc["stages"]["fit"]["do"]["deps"].append("out/tiny_single/stylize")  # a scene stage reading an experiment
    with pytest.raises(PlanError, match=r"fit@tiny.*stylize@tiny_single"):
        make_plan(dvc, _yaml("params.yaml"))
    dvc = _yaml("dvc.yaml")
    dvc["stages"]["odd"] = {"foreach": "${viewer}", "do": {"cmd": "true"}}
    with pytest.raises(PlanError, match="foreach over 'viewer'"):
        make_plan(dvc, _yaml("params.yaml"))


def test_an_overlay_replaces_the_collections_and_merges_the_other_sections() -> None:
    base = _yaml("params.yaml")
    overlay = yaml.safe_load((REPO_ROOT / "eval/params/fern_starry.yaml").read_text())
    merged = apply_sets(apply_overlay(base, overlay), ["stylize.optim.iterations=7", "data.scenes.fern.path=/x/fern"])
    assert set(merged["data"]["scenes"]) == {"fern"} and merged["data"]["scenes"]["fern"]["path"] == "/x/fern"
    assert set(merged["experiments"]) == set(overlay["experiments"])
    assert merged["stylize"]["optim"]["iterations"] == 7
    assert merged["stylize"]["weights"]["tv"] == overlay["stylize"].get("weights", {}).get("tv", base["stylize"]["weights"]["tv"])
    assert base["stylize"]["optim"]["iterations"] != 7  # the base is not changed
    with pytest.raises(PlanError, match="KEY=VALUE"):
        apply_sets({}, ["stylize.optim.iterations"])


def test_a_kind_with_a_gpu_gets_its_backends_set_to_auto() -> None:
    res = load_resources()
    params = _yaml("params.yaml")
    params["fit"]["backend"] = "cpu"
    params["stylize"]["compute"] = {"backend": "reference"}
    assert gpu_overrides(res, params) == {}  # the default resources have no GPU
    res = {**res, "experiment": Resources(cpus=8, mem="16G", gres="gpu:1")}
    assert gpu_overrides(res, params) == {"stylize.compute.backend": "auto"}
    assert "--gres=gpu:1" in res["experiment"].sbatch_options()


def test_the_sbatch_script_and_the_dependencies(tmp_path: Path) -> None:
    plan = make_plan(_yaml("dvc.yaml"), _yaml("params.yaml"))
    arr = plan.array("experiments@tiny")
    res = Resources(cpus=3, mem="5G", time="00:42:00", max_parallel=2, partition="gpu", extra=("--constraint=avx2",))
    text = render_script(plan, arr, res, tmp_path / "run", "abc123", "/shared/cache", "/venv/bin/python")
    for line in ("#SBATCH --array=0-2%2", "#SBATCH --requeue", "#SBATCH --cpus-per-task=3", "#SBATCH --mem=5G",
                 "#SBATCH --time=00:42:00", "#SBATCH --partition=gpu", "#SBATCH --constraint=avx2",
                 "#SBATCH --open-mode=append", f"#SBATCH --output={tmp_path}/run/logs/experiments@tiny_%A_%a.out"):
        assert line in text.splitlines(), line
    assert 'exec /venv/bin/python -m abcgs.cluster job' in text and '"$SLURM_ARRAY_TASK_ID"' in text
    assert "export PATH=/venv/bin:$PATH" in text
    first_exec = min(i for i, line in enumerate(text.splitlines()) if line and not line.startswith("#"))
    assert all(i < first_exec for i, line in enumerate(text.splitlines()) if line.startswith("#SBATCH"))
    ids = {"prep": "7", "scenes": "8", "experiments@tiny": "9"}
    assert dependency(arr, ids) == ["--dependency=afterok:8_0", "--kill-on-invalid-dep=yes"]
    assert dependency(plan.array("scenes"), ids) == ["--dependency=afterok:7_0", "--kill-on-invalid-dep=yes"]
    assert dependency(plan.array("report"), ids) == ["--dependency=afterany:7:8:9"]  # it checks them itself
    assert dependency(plan.array("prep"), ids) == []
    assert _expand_tasks("0-2,5%2") == [0, 1, 2, 5]


def test_the_stage_log_reads_dvc_repro_output() -> None:
    log = StageLog()
    for line in ("Stage 'preflight' didn't change, skipping", "Stage 'fit@tiny' is cached - skipping run, checking out outputs",
                 "Running stage 'stylize@a':", "> python stages/stylize.py", "Running stage 'evaluate@a':"):
        log.feed(line)
    assert (log.unchanged, log.restored, log.ran, log.current) == (["preflight"], ["fit@tiny"],
                                                                 ["stylize@a", "evaluate@a"], "evaluate@a")


def test_configure_cache_keeps_the_other_local_settings(tmp_path: Path) -> None:
    (tmp_path / ".dvc").mkdir()
    (tmp_path / ".dvc" / "config.local").write_text("[core]\n    autostage = true\n[cache]\n    dir = /old\n")
    configure_cache(tmp_path, "/shared/cache")
    text = (tmp_path / ".dvc" / "config.local").read_text()
    assert "autostage = true" in text and "dir = /shared/cache" in text and "/old" not in text
    assert "shared = group" in text


# ------------------------------------------------------------------------------------------------ a toy pipeline
TOY_DVC = """\
stages:
  preflight:
    cmd: mkdir -p out && echo ok > out/preflight.json
    deps:
      - params.yaml
    outs:
      - out/preflight.json:
          cache: false
  fit:
    foreach: ${data.scenes}
    do:
      cmd: mkdir -p out/${key} && echo ${key} ${item.path} > out/${key}/fit.txt && date +%s%N > out/${key}/fit.json && echo x >> ../fit_calls
      deps:
        - out/preflight.json
      params:
        - data.scenes.${key}
      outs:
        - out/${key}/fit.txt
        - out/${key}/fit.json:
            cache: false
  stylize:
    foreach: ${experiments}
    do:
      cmd: test ${item.fail} = no && mkdir -p out/${key} && cat out/${item.scene}/fit.txt > out/${key}/sty.txt && echo "{}" > out/${key}/sty.json
      deps:
        - out/${item.scene}/fit.txt
      outs:
        - out/${key}/sty.txt
        - out/${key}/sty.json:
            cache: false
  report:
    cmd: cat out/*/sty.txt > report.txt
    deps:
      - out
    outs:
      - report.txt
"""
TOY_PARAMS = {"data": {"scenes": {"a": {"path": "pa"}}},
              "experiments": {"x": {"scene": "a", "fail": "no"}, "y": {"scene": "a", "fail": "yes"}}}


def _git(args: list[str], cwd: Path) -> None:
    subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@example.invalid", *args], cwd=cwd, check=True,
                   capture_output=True)


def _toy_run(tmp_path: Path, remote: bool) -> tuple[Path, Path]:
    """The toy pipeline committed in a git + DVC repository, and a run folder for it (with a shared cache, or with
    a DVC remote: a local folder, the code path of S3)."""
    repo = tmp_path / "toy" / "repo"
    repo.mkdir(parents=True)
    (repo / "dvc.yaml").write_text(TOY_DVC)
    (repo / "params.yaml").write_text(yaml.safe_dump(TOY_PARAMS))
    _git(["init", "-q"], repo)
    dvc = [sys.executable, "-m", "dvc"]
    subprocess.run(dvc + ["init", "-q"], cwd=repo, check=True)
    subprocess.run(dvc + ["config", "core.analytics", "false"], cwd=repo, check=True)
    if remote:
        subprocess.run(dvc + ["remote", "add", "-d", "store", str(tmp_path / "toy" / "store")], cwd=repo, check=True)
    _git(["add", "-A"], repo)
    _git(["commit", "-qm", "toy"], repo)
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo, capture_output=True, text=True).stdout.strip()
    plan = make_plan(yaml.safe_load(TOY_DVC), TOY_PARAMS)
    run = tmp_path / "toy" / "run"
    save_run(run, RunInfo(str(repo), commit, str(tmp_path / "toy" / "cache"), sys.executable, plan, load_resources(),
                          use_remote=remote))
    return repo, run


@pytest.mark.slow
@pytest.mark.parametrize("remote", [False, True], ids=["shared-cache", "remote"])
def test_jobs_share_stages_through_the_run_cache_and_collect_reports_the_missing(tmp_path: Path, capsys,
                                                                                 remote: bool) -> None:
    """Each job runs in its own clone; what one job finished, the next restores (stages with an uncached output
    too, through dvc_run); a failed experiment stops nothing else; collect restores every finished stage without
    running one and names the missing experiment. The same through a DVC remote instead of a shared cache."""
    repo, run = _toy_run(tmp_path, remote)
    plan = load_run(run).plan
    assert [a.name for a in plan.arrays] == ["prep", "scenes", "experiments@a", "report"]
    assert run_job(run, "prep", 0) == 0
    assert run_job(run, "scenes", 0) == 0
    assert read_state(run, "scene@a")["ran"] == ["fit@a"] and read_state(run, "scene@a")["restored"] == ["preflight"]
    assert run_job(run, "scenes", 0) == 0  # a retry: restores, runs nothing
    again = read_state(run, "scene@a")
    assert again["ran"] == [] and again["restored"] == ["preflight", "fit@a"]
    assert (tmp_path / "toy" / "run" / "work" / "fit_calls").read_text() == "x\n"  # the fit ran once
    assert run_job(run, "experiments@a", 1) != 0  # y fails ...
    assert run_job(run, "experiments@a", 0) == 0  # ... x does not care
    failed = read_state(run, "experiment@y")
    assert failed["state"] == "failed" and failed["stage"] == "stylize@y"
    assert read_state(run, "experiment@x")["restored"] == ["preflight", "fit@a"]
    assert not (run / "work" / "experiment@x").exists() and (run / "work" / "experiment@y").is_dir()
    assert run_job(run, "report", 0) == 3  # started after the others ended: it needs them all, runs nothing
    assert read_state(run, "report")["error"] == "jobs not done: experiment@y"
    # a dvc.lock from an earlier run (a fresh clone's committed one: outputs absent) names a fit.json, a timing say,
    # that the cluster's fit did not write; DVC would follow it and re-run fit@a: collect moves it aside
    subprocess.run([sys.executable, "-m", "dvc", "repro", "fit@a"], cwd=repo, check=True, capture_output=True)
    shutil.rmtree(repo / "out")
    capsys.readouterr()
    from abcgs.cluster.commands import cmd_collect

    rc = cmd_collect(argparse.Namespace(run=run, cluster_dir=None, lines=5, into=None, verbose=False))
    out = capsys.readouterr().out
    assert rc == 1
    summary = json.loads((run / "collect.json").read_text())
    assert summary["ran"] == [] and set(summary["restored"]) == {"preflight", "fit@a", "stylize@x"}, summary
    assert summary["missing"] == ["experiment@y"] and (run / "collect-dvc.lock.before").is_file()
    assert "MISSING experiment@y: failed in stylize@y" in out and "not written: the report" in out
    assert (repo / "out" / "x" / "sty.json").is_file() and (repo / "out" / "a" / "fit.json").is_file()
    assert (tmp_path / "toy" / "cache").is_dir() != remote and (tmp_path / "toy" / "store").is_dir() == remote


# ------------------------------------------------------------------------------------------------ a real Slurm
KILLED = "tiny_single"
RESOURCES = {"prep": {"cpus": 2, "mem": "1G", "time": "00:30:00"},
             "scene": {"cpus": 2, "mem": "2G", "time": "00:30:00"},
             "experiment": {"cpus": 1, "mem": "2G", "time": "00:30:00"},
             "report": {"cpus": 2, "mem": "2G", "time": "00:30:00"}}
"""The test node has 2 cores: a scene job takes both, two experiments run side by side."""


def _wait(what: str, check: Callable[[], Any], timeout: float, every: float = 1.0) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(every)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


@pytest.fixture(scope="module")
def slurm(tmp_path_factory: pytest.TempPathFactory):
    """A one-node Slurm on localhost (munged, slurmctld, slurmd), torn down at the end of the module."""
    from eval.slurm_local import LocalSlurm, SlurmUnavailable, install

    try:
        if os.geteuid() != 0:
            raise SlurmUnavailable("a local Slurm needs root (slurmd starts the jobs; apt-get installs it)")
        install()
    except SlurmUnavailable as exc:
        if os.environ.get("CI"):
            pytest.fail(f"Slurm unavailable under CI: {exc}")
        pytest.skip(str(exc))
    cluster = LocalSlurm(tmp_path_factory.mktemp("slurm"), cpus=2).start()
    yield cluster
    cluster.stop()


KILLED_STAGES = ("stylize", "evaluate", "export")
"""The stages of experiment KILLED that the cluster computes itself; every other stage is in the seeded cache."""


def seed_cache(src: Path, dst: Path) -> None:
    """Copy the DVC cache ``src`` (objects and run cache) to ``dst``, leaving out the run-cache entries of
    KILLED's :data:`KILLED_STAGES`: a submit then restores the scene and the other experiments from the run cache
    and computes only KILLED's branch, the one the tests kill, retry and compare."""
    skip = {p.parent for s in KILLED_STAGES for p in _run_cache_entries(src, s, KILLED)}  # runs/<xx>/<stage key>/
    shutil.copytree(src, dst, ignore=lambda d, names: [n for n in names if Path(d, n) in skip])
    assert not any(_run_cache_entries(dst, s, KILLED) for s in KILLED_STAGES)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory, tiny_pipeline: dict) -> dict[str, Path]:
    """A git + DVC copy of the working tree with REDUCED iteration counts, and a shared folder for the cluster whose
    cache holds the same pipeline's stages from :func:`conftest.tiny_pipeline` (:func:`seed_cache`)."""
    root = tmp_path_factory.mktemp("cluster")
    (root / "resources.yaml").write_text(yaml.safe_dump(RESOURCES))
    seed_cache(tiny_pipeline["repo"] / ".dvc" / "cache", root / "shared" / "cache")
    return {"repo": copy_repo(root / "repo", reduce), "shared": root / "shared", "resources": root / "resources.yaml"}


def _cli(args: list[str], workspace: dict[str, Path], slurm, timeout: float = 900) -> subprocess.CompletedProcess:
    env = {**slurm.env, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    return subprocess.run([sys.executable, "-m", "abcgs.cluster", *args], cwd=workspace["repo"], env=env,
                          capture_output=True, text=True, timeout=timeout)


def _submit(workspace: dict[str, Path], slurm) -> Path:
    proc = _cli(["submit", "--cluster-dir", str(workspace["shared"]), "--resources", str(workspace["resources"])],
                workspace, slurm)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return Path(re.search(r"^run (\S+)", proc.stdout, re.M).group(1))


def _queue_empty(slurm) -> bool:
    return not subprocess.run(["squeue", "-h"], env=slurm.env, capture_output=True, text=True).stdout.strip()


def _scontrol_state(slurm, sid: str) -> str:
    out = subprocess.run(["scontrol", "-o", "show", "job", sid], env=slurm.env, capture_output=True, text=True).stdout
    m = re.search(r"JobState=(\S+)", out)
    return m.group(1) if m else "?"


def _run_cache_entries(cache: Path, script: str, key: str) -> list[Path]:
    """Run-cache entries of the stage ``stages/<script>.py`` for key ``key`` (named by its outputs, ``out/<key>/…``:
    the command itself holds no key)."""
    return [p for p in (cache / "runs").rglob("*") if p.is_file()
            and f"stages/{script}.py" in (text := p.read_text(errors="replace")) and f"out/{key}/" in text]


@pytest.fixture(scope="module")
def first_run(workspace: dict[str, Path], slurm) -> dict[str, Any]:
    """Submit the tiny pipeline; kill experiment KILLED's task with SIGKILL during stylize, then requeue it (what
    ``--requeue`` has Slurm do after a node failure); wait for every job."""
    started = time.monotonic()
    run = _submit(workspace, slurm)
    name = f"experiment@{KILLED}"
    rec = _wait(f"{name} to start stylize", lambda: (r := read_state(run, name)) and r.get("stage") == f"stylize@{KILLED}" and r,
                timeout=1500)
    time.sleep(3)  # well inside the stage
    sid = rec["slurm_id"]
    subprocess.run(["scancel", "--signal=KILL", sid], env=slurm.env, check=True)
    _wait(f"{sid} to end", lambda: _scontrol_state(slurm, sid) not in ("RUNNING", "COMPLETING"), timeout=60, every=0.5)
    killed_state = _scontrol_state(slurm, sid)
    entries_after_kill = _run_cache_entries(Path(load_run(run).cache), "stylize", KILLED)
    status = _cli(["status", str(run), "--lines", "30"], workspace, slurm)
    subprocess.run(["scontrol", "requeue", sid], env=slurm.env, check=True)
    _wait("every job to finish", lambda: _queue_empty(slurm), timeout=1800, every=2)
    return {"run": run, "sid": sid, "killed_state": killed_state, "entries_after_kill": entries_after_kill,
            "status_after_kill": status, "wall_s": time.monotonic() - started}


@_slurm
def test_every_job_completes_and_the_killed_one_was_retried(first_run: dict, workspace, slurm) -> None:
    run = first_run["run"]
    assert first_run["killed_state"] in ("CANCELLED", "FAILED"), first_run["killed_state"]
    proc = _cli(["status", str(run)], workspace, slurm)
    assert proc.returncode == 0, proc.stderr
    info = load_run(run)
    for name in info.plan.jobs:
        assert read_state(run, name)["state"] == "ok", (name, read_state(run, name), proc.stdout)
        assert re.search(rf"^{re.escape(name)}\s+\S+\s+COMPLETED", proc.stdout, re.M), proc.stdout
    rec = read_state(run, f"experiment@{KILLED}")
    assert rec["attempt"] == 2 and rec["slurm_id"] == first_run["sid"]
    assert rec["ran"] == [f"stylize@{KILLED}", f"evaluate@{KILLED}", f"export@{KILLED}"]
    assert f"colormatch@{KILLED}" in rec["restored"] and "fit@tiny" in rec["restored"]
    log = Path(rec["log"]).read_text()
    assert log.count(f"[abcgs.cluster] experiment@{KILLED} (attempt") == 2  # both attempts, appended
    assert log.count(f"Running stage 'stylize@{KILLED}'") == 2


@_slurm
def test_status_showed_the_killed_stage_and_its_log(first_run: dict) -> None:
    out = first_run["status_after_kill"].stdout
    assert re.search(rf"experiment@{KILLED}\s+{re.escape(first_run['sid'])}\s+(CANCELLED|FAILED)", out), out
    assert f"in stylize@{KILLED}" in out and f"Running stage 'stylize@{KILLED}'" in out and "scontrol requeue" in out


@_slurm
def test_a_killed_stage_leaves_nothing_in_the_cache(first_run: dict) -> None:
    """No run-cache entry for the killed stage until the retry finished it, and every cached file is whole."""
    cache = Path(load_run(first_run["run"]).cache)
    assert first_run["entries_after_kill"] == []
    assert len(_run_cache_entries(cache, "stylize", KILLED)) == 1
    for f in (cache / "files" / "md5").rglob("*"):
        if f.is_file():
            assert hashlib.md5(f.read_bytes()).hexdigest() == f.parent.name + f.name.removesuffix(".dir"), f


@pytest.fixture(scope="module")
def collected(first_run: dict, workspace, slurm) -> dict[str, Any]:
    t0 = time.monotonic()
    proc = _cli(["collect", str(first_run["run"])], workspace, slurm)
    return {"proc": proc, "summary": json.loads((first_run["run"] / "collect.json").read_text()),
            "wall_s": time.monotonic() - t0}


@_slurm
def test_collect_restores_every_stage_and_runs_none(collected: dict, workspace) -> None:
    proc, summary = collected["proc"], collected["summary"]
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert summary["ran"] == [] and summary["missing"] == [], summary
    assert "report" in summary["restored"] and len(summary["restored"]) >= 10
    repo = workspace["repo"]
    lock = yaml.safe_load((repo / "dvc.lock").read_text())["stages"]
    assert {"report", f"stylize@{KILLED}", "fit@tiny"} <= set(lock)
    page = (repo / "reports" / "report.html").read_text()
    for exp in _yaml("params.yaml")["experiments"]:
        assert exp in page and (repo / "out" / exp / "metrics.json").is_file()
    status = subprocess.run([sys.executable, "-m", "dvc", "status"], cwd=repo, capture_output=True, text=True)
    assert "up to date" in status.stdout, status.stdout


@_slurm
def test_a_second_submit_of_the_same_commit_runs_nothing(collected: dict, workspace, slurm) -> None:
    run = _submit(workspace, slurm)
    _wait("the second run", lambda: _queue_empty(slurm), timeout=1200, every=2)
    for name in load_run(run).plan.jobs:
        rec = read_state(run, name)
        assert rec["state"] == "ok" and rec["ran"] == [], (name, rec)


@_slurm
def test_the_retried_stylization_equals_an_uninterrupted_one(collected: dict, workspace, first_run) -> None:
    """stylize of the killed experiment, run again uninterrupted in the workspace (forced: not from the run cache),
    writes the same PLY and renders as the retried job did."""
    repo = workspace["repo"]
    stylized = repo / "out" / KILLED / "stylize"

    def digests() -> dict[str, str]:
        return {p.relative_to(stylized).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(stylized.rglob("*")) if p.is_file() and p.suffix in (".ply", ".png")}

    retried = digests()
    assert "point_cloud.ply" in retried
    env = {**os.environ, "OMP_NUM_THREADS": str(RESOURCES["experiment"]["cpus"]), "PYTHONPATH": str(repo),
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    proc = subprocess.run([sys.executable, "-m", "dvc", "repro", "--force", "--single-item", f"stylize@{KILLED}"],
                          cwd=repo, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0 and f"Running stage 'stylize@{KILLED}'" in proc.stdout, proc.stdout + proc.stderr
    assert digests() == retried
