"""``plan``, ``submit``, ``status`` and ``collect``: what the researcher runs on the login node."""

from __future__ import annotations

import argparse
import copy
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from abcgs.cluster.plan import (
    KINDS,
    Plan,
    Resources,
    apply_sets,
    gpu_overrides,
    load_resources,
    make_plan,
)
from abcgs.cluster.run import (
    RunError,
    RunInfo,
    StageLog,
    configure_cache,
    dvc_env,
    git,
    load_run,
    make_clone,
    now,
    read_state,
    repro,
    save_run,
)
from abcgs.cluster.slurm import (
    SlurmError,
    check_reachable,
    dependency,
    python_executable,
    render_script,
    sbatch,
    script_path,
    task_states,
)
from abcgs.io.atomic import write_json
from abcgs.overlay import apply_overlay, read_overlay

CLUSTER_DIR_ENV = "ABCGS_CLUSTER_DIR"
"""Environment variable naming the cluster folder (``cache/`` and ``runs/``) when ``--cluster-dir`` is not given."""


# ------------------------------------------------------------------------------------------------ inputs
def _repo_root(path: Path) -> Path:
    return Path(git(["rev-parse", "--show-toplevel"], path))


def _committed_yaml(repo: Path, commit: str, name: str) -> Any:
    return yaml.safe_load(git(["show", f"{commit}:{name}"], repo))


def build_params(base: Mapping[str, Any], overlay: Path | None, data: Path | None, sets: list[str],
                 resources: Mapping[str, Resources]) -> tuple[dict, dict[str, Any]]:
    """The run's params (base, overlay, ``--set``, GPU backends) and the GPU backend keys that were changed."""
    from abcgs.params import validate_params

    params = apply_overlay(base, read_overlay(overlay, data, "--data", "--params")) if overlay else dict(base)
    params = apply_sets(copy.deepcopy(params), sets)
    gpu = gpu_overrides(resources, params)
    apply_sets(params, [f"{k}={v}" for k, v in gpu.items()])
    validate_params(params, "the run's params")
    return params, gpu


def _prepare(a: argparse.Namespace) -> tuple[Path, str, dict, dict, dict[str, Any], Plan, dict[str, Resources]]:
    repo = _repo_root(Path.cwd())
    try:
        commit = git(["rev-parse", "--verify", "--end-of-options", f"{a.rev}^{{commit}}"], repo)
    except RunError:
        raise RunError(f"--rev {a.rev!r} is not a commit of {repo}") from None
    dirty = git(["status", "--porcelain", "--untracked-files=no"], repo)
    if dirty:
        print(f"note: the jobs run commit {commit[:10]}; uncommitted changes to tracked files are not in it:\n"
              + "\n".join(f"  {line}" for line in dirty.splitlines()[:10]), file=sys.stderr)
    base = _committed_yaml(repo, commit, "params.yaml")
    resources = load_resources(a.resources)
    params, gpu = build_params(base, a.params, a.data, a.set, resources)
    plan = make_plan(_committed_yaml(repo, commit, "dvc.yaml"), params)
    return repo, commit, base, params, gpu, plan, resources


def describe_plan(plan: Plan, resources: Mapping[str, Resources]) -> str:
    """The arrays, their dependencies and resources, and each job's targets, as text."""
    lines = []
    for arr in plan.arrays:
        after = f"{arr.wait} " + ", ".join(a if t is None else f"{a}[{t}]" for a, t in arr.after) if arr.after else "first"
        lines.append(f"{arr.name}: {len(arr.jobs)} task(s), {after}; {resources[arr.kind].describe()}")
        for i, name in enumerate(arr.jobs):
            targets = " ".join(plan.jobs[name].targets) or "(the whole pipeline)"
            lines.append(f"  {i}  {name}: dvc repro {targets}")
    return "\n".join(lines)


def cmd_plan(a: argparse.Namespace) -> int:
    _, commit, _, _, gpu, plan, resources = _prepare(a)
    counts = {k: sum(j.kind == k for j in plan.jobs.values()) for k in KINDS}
    print(f"commit {commit[:10]}: {counts['scene']} scene job(s), {counts['experiment']} experiment job(s), "
          f"{len(plan.arrays)} arrays")
    if gpu:
        print(f"GPU backends set to auto: {', '.join(gpu)}")
    print(describe_plan(plan, resources))
    return 0


# ------------------------------------------------------------------------------------------------ submit
def _cluster_dir(a: argparse.Namespace) -> Path:
    d = a.cluster_dir or os.environ.get(CLUSTER_DIR_ENV)
    if not d:
        raise RunError(f"where do the cache and the run folders go? Pass --cluster-dir DIR (a folder on the "
                       f"cluster's shared filesystem) or set {CLUSTER_DIR_ENV}")
    return Path(d).resolve()


def _default_remote(repo: Path, commit: str) -> str | None:
    """The default DVC remote (``core.remote``) of ``.dvc/config`` at ``commit``."""
    import configparser

    cfg = configparser.ConfigParser()
    try:
        cfg.read_string(git(["show", f"{commit}:.dvc/config"], repo))
    except (RunError, configparser.Error):
        return None
    return cfg.get("core", "remote", fallback=None)


def latest_run(a: argparse.Namespace) -> Path:
    """The run folder given, else the newest one under the cluster folder's ``runs/``."""
    if a.run is not None:
        return Path(a.run).resolve()
    runs = sorted((_cluster_dir(a) / "runs").glob("*/run.json"))
    if not runs:
        raise RunError(f"no run under {_cluster_dir(a) / 'runs'}: submit one first")
    return runs[-1].parent


def cmd_submit(a: argparse.Namespace) -> int:
    cluster = _cluster_dir(a) if not (a.cache and a.run_dir) else None
    where = "--cluster-dir" if a.cluster_dir else f"${CLUSTER_DIR_ENV}"
    script_path(a.run_dir or cluster, "--run-dir" if a.run_dir else where, directive=True)  # before any work
    script_path(a.cache or cluster, "--cache" if a.cache else where)
    repo, commit, base, params, gpu, plan, resources = _prepare(a)
    cache = (a.cache or cluster / "cache").resolve()
    run = (a.run_dir or cluster / "runs" / f"{time.strftime('%Y%m%d-%H%M%S')}-{commit[:8]}").resolve()
    script_path(run, "--run-dir" if a.run_dir else where, directive=True)  # the resolved paths (symbolic links)
    script_path(cache, "--cache" if a.cache else where)
    if (run / "run.json").exists():
        raise RunError(f"{run} already holds a run; choose another --run-dir")
    if a.remote and not _default_remote(repo, commit):
        raise RunError("--remote: the commit's .dvc/config names no default remote (`dvc remote add -d NAME URL`, "
                       "then commit .dvc/config)")
    if not a.dry_run:
        check_reachable()  # before the run folder exists
    for d in (run / "logs", run / "state", run / "scripts", *(() if a.remote else (cache,))):
        d.mkdir(parents=True, exist_ok=True)
    params_file = None
    if params != base:
        params_file = "params.yaml"
        (run / params_file).write_text(yaml.safe_dump(params, sort_keys=False), encoding="utf-8")
    info = RunInfo(str(repo), commit, str(cache), python_executable(), plan, resources, params_file, gpu,
                   created=now(), keep_worktrees=a.keep_worktrees, use_remote=a.remote)
    save_run(run, info)
    scripts = {}
    for arr in plan.arrays:
        scripts[arr.name] = run / "scripts" / f"{arr.name}.sbatch"
        scripts[arr.name].write_text(render_script(plan, arr, resources[arr.kind], run, commit, str(cache),
                                                   info.python), encoding="utf-8")
    where = f"DVC remote {_default_remote(repo, commit)!r}" if a.remote else f"DVC cache {cache}"
    print(f"run {run}\ncommit {commit[:10]}, {where}" + (", params: overlay/--set" if params_file else ""))
    if gpu:
        print(f"GPU backends set to auto: {', '.join(gpu)}")
    print(describe_plan(plan, resources))
    if a.dry_run:
        print(f"dry run: the scripts are in {run / 'scripts'}; nothing submitted")
        return 0
    try:
        for arr in plan.arrays:
            info.slurm[arr.name] = sbatch(scripts[arr.name], dependency(arr, info.slurm))
    except SlurmError:
        if info.slurm:
            subprocess.run(["scancel", *info.slurm.values()], capture_output=True)
        raise
    finally:
        save_run(run, info)
    print("submitted: " + ", ".join(f"{n} {i}" for n, i in info.slurm.items()))
    print(f"then: python -m abcgs.cluster status {run}\n      python -m abcgs.cluster collect {run}")
    return 0


# ------------------------------------------------------------------------------------------------ status
def job_rows(run: Path, info: RunInfo) -> list[dict]:
    """One row per job: its array task, Slurm's state and the job's own record (stage, what it ran)."""
    states = task_states(info.slurm.values()) if info.slurm else {}
    rows = []
    for arr in info.plan.arrays:
        for i, name in enumerate(arr.jobs):
            sid = f"{info.slurm[arr.name]}_{i}" if arr.name in info.slurm else "-"
            st = states.get(sid)
            rec = read_state(run, name) or {}
            rows.append({"job": name, "slurm_id": sid, "slurm": st.state if st else ("-" if sid == "-" else "?"),
                         "reason": st.reason if st else "", "restarts": st.restarts if st else 0, "record": rec})
    return rows


def _tail(path: str | None, n: int) -> list[str]:
    if not path or not Path(path).is_file():
        return []
    return Path(path).read_text(encoding="utf-8", errors="replace").splitlines()[-n:]


def _progress(rec: Mapping[str, Any]) -> str:
    if not rec:
        return "not started"
    ran, restored = rec.get("ran") or [], rec.get("restored") or []
    text = f"ran {len(ran)}, restored {len(restored)}"
    if rec.get("state") == "failed":
        return f"FAILED in {rec.get('stage') or rec.get('error') or '?'}; {text}"
    if rec.get("state") in ("running", "preparing"):
        return f"in {rec.get('stage') or '(restoring upstream)'}; {text}"
    return text


def cmd_status(a: argparse.Namespace) -> int:
    run = latest_run(a)
    info = load_run(run)
    rows = job_rows(run, info)
    print(f"run {run} (commit {info.commit[:10]}, submitted {info.created})")
    width = max(len(r["job"]) for r in rows)
    bad = []
    for r in rows:
        rec = r["record"]
        attempt = f"attempt {rec.get('attempt', r['restarts'] + 1)}"
        why = f" ({r['reason']})" if r["reason"] and r["reason"] != "None" else ""
        print(f"{r['job']:<{width}}  {r['slurm_id']:<10} {r['slurm'] + why:<28} {attempt:<10} {_progress(rec)}")
        failed_slurm = r["slurm"] in ("FAILED", "CANCELLED", "TIMEOUT", "OUT_OF_MEMORY", "NODE_FAIL")
        if rec.get("state") == "failed" or (failed_slurm and rec.get("state") != "ok"):
            bad.append(r)
    for r in bad:
        rec = r["record"]
        print(f"\n{r['job']} ({r['slurm_id']}, {r['slurm']}): last lines of {rec.get('log', 'its log')}")
        for line in _tail(rec.get("log"), a.lines):
            print(f"  | {line}")
    if bad:
        ids = ",".join(r["slurm_id"] for r in bad)
        print(f"\nretry: `scontrol requeue {ids}` while the jobs after them still wait, or submit the same commit "
              "again: every finished stage is restored from the run cache, only the rest runs")
    return 0


# ------------------------------------------------------------------------------------------------ collect
def _collect_target(run: Path, info: RunInfo, into: Path | None) -> Path:
    """Where ``collect`` reproduces: ``into``, else the workspace, or a clone in the run folder when the run has
    its own params (the workspace's ``params.yaml`` stays as it is)."""
    if into is None and not info.params_file:
        target = Path(info.repo)
        head = git(["rev-parse", "HEAD"], target)
        if head != info.commit:
            print(f"note: the workspace is at {head[:10]}, the run at {info.commit[:10]}: stages whose code or "
                  "params differ run here", file=sys.stderr)
        return target
    target = (into or run / "collect").resolve()
    if not (target / ".dvc").is_dir():
        make_clone(info.repo, info.commit, target)
    if info.params_file:
        shutil.copyfile(run / info.params_file, target / "params.yaml")
    return target


def cmd_collect(a: argparse.Namespace) -> int:
    """``dvc repro`` in the workspace (or a clone) from the run cache: every finished job's stages restored, the
    report when nothing is missing. The workspace's ``dvc.lock`` is moved into the run folder first: DVC restores a
    stage from its lock entry when the entry matches, which names outputs of an earlier run, not of this one."""
    run = latest_run(a)
    info = load_run(run)
    records = {name: read_state(run, name) or {} for name in info.plan.jobs}
    missing = [n for n, rec in records.items() if rec.get("state") != "ok" and info.plan.jobs[n].kind != "report"]
    target = _collect_target(run, info, a.into)
    if not info.use_remote:
        configure_cache(target, info.cache)
    lock = target / "dvc.lock"
    if lock.is_file():  # its entries would win over the run cache, and their outputs are not in this run's cache
        shutil.move(lock, run / "collect-dvc.lock.before")
        print(f"collect: moved {lock} to {run / 'collect-dvc.lock.before'}; dvc repro writes the run's", flush=True)
    if missing:
        targets = [t for n, j in info.plan.jobs.items() if n not in missing and j.kind != "report" for t in j.targets]
        args = ["--keep-going", *targets]
    else:
        args = []
    if info.use_remote:
        args = ["--pull", *args]
    source = "the DVC remote" if info.use_remote else f"cache {info.cache}"
    print(f"collect: dvc repro {' '.join(args) or '(the whole pipeline)'} in {target}, {source}", flush=True)

    def echo(line: str, _: StageLog) -> None:
        sys.stdout.write(line)
        sys.stdout.flush()

    rc, log = repro(target, args, keep_run_cache=False, on_line=echo if a.verbose else None, env=dvc_env(target))
    summary = {"run": str(run), "target": str(target), "exit_code": rc, "ran": log.ran, "restored": log.restored,
               "unchanged": log.unchanged, "missing": missing, "collected": now()}
    write_json(run / "collect.json", summary)
    print(f"collect: {log.summary()}")
    for name in missing:
        rec = records[name]
        where = f"failed in {rec.get('stage')}" if rec.get("state") == "failed" else (
            f"stopped in {rec.get('stage')}" if rec.get("stage") else rec.get("state", "never started"))
        print(f"MISSING {name}: {where}; log {rec.get('log', '-')}")
        for line in _tail(rec.get("log"), a.lines):
            print(f"  | {line}")
    report = target / "reports" / "report.html"
    if missing:
        print(f"not written: the report, which needs every experiment ({len(missing)} job(s) missing); "
              "submit the same commit again to run what is missing")
    elif rc == 0 and report.is_file():
        print(f"report: {report}")
    return 0 if rc == 0 and not missing else 1


# ------------------------------------------------------------------------------------------------ cli
def add_plan_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", type=Path, help="a benchmark overlay (eval/params/*.yaml) over the commit's params.yaml")
    p.add_argument("--data", type=Path, help="the folder ${shared} in the overlay stands for")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="change a params key (YAML value)")
    p.add_argument("--resources", type=Path, help="per-kind Slurm resources (default abcgs/cluster/resources.yaml)")
    p.add_argument("--rev", default="HEAD", help="the commit the jobs run (default HEAD)")
