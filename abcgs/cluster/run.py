"""The run folder of one submission, and what jobs and ``collect`` share: clones, the DVC cache, ``dvc repro``.

A run folder (on the cluster's shared filesystem) holds::

    run.json            the plan, the commit, the repository, the DVC cache, the interpreter, the Slurm job ids
    params.yaml         the merged params (only when an overlay, --set or a GPU backend changed them)
    scripts/*.sbatch    one script per job array (abcgs.cluster.slurm.SBATCH_TEMPLATE)
    logs/               the jobs' output, <array>_<arrayid>_<task>.out, appended to on a retry
    state/<job>.json    each job's progress: the stage it is in, what it ran and what it restored
    work/<job>/         a job's clone while it runs (removed when it succeeds)
    collect.json        what ``collect`` restored, ran and found missing
    collect-dvc.lock.before  the workspace's dvc.lock, moved aside by ``collect``
    collect/            ``collect``'s clone, when the run has its own params
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from abcgs.cluster.plan import Plan, Resources
from abcgs.errors import AbcgsError
from abcgs.io.atomic import write_json

DVC_RUN = Path(__file__).with_name("dvc_run.py")


class RunError(AbcgsError):
    """A run folder is missing or inconsistent."""


class DvcVersionError(AbcgsError):
    """The installed DVC is outside the versions :mod:`abcgs.cluster.dvc_run` was tested with."""


def check_dvc_version(version: str | None = None) -> None:
    """Raise :class:`DvcVersionError` when DVC ``version`` (default: the installed one) is untested
    (:data:`abcgs.cluster.dvc_run.DVC_TESTED`)."""
    from abcgs.cluster.dvc_run import dvc_version_problem

    problem = dvc_version_problem(version)
    if problem:
        raise DvcVersionError(problem)


@dataclass
class RunInfo:
    """``run.json``: everything a job needs to find its work."""

    repo: str
    commit: str
    cache: str
    python: str
    plan: Plan
    resources: dict[str, Resources]
    params_file: str | None = None
    changed_params: dict[str, Any] = field(default_factory=dict)
    slurm: dict[str, str] = field(default_factory=dict)
    created: str = ""
    keep_worktrees: bool = False
    use_remote: bool = False

    def to_dict(self) -> dict:
        d = asdict(self)
        d["plan"] = self.plan.to_dict()
        d["resources"] = {k: asdict(r) for k, r in self.resources.items()}
        return d

    @classmethod
    def from_dict(cls, d: dict) -> RunInfo:
        d = dict(d)
        d["plan"] = Plan.from_dict(d["plan"])
        d["resources"] = {k: Resources(**{**r, "extra": tuple(r.get("extra") or ())}) for k, r in d["resources"].items()}
        return cls(**d)


def save_run(run: Path, info: RunInfo) -> None:
    write_json(run / "run.json", info.to_dict())


def load_run(run: Path) -> RunInfo:
    path = run / "run.json"
    if not path.is_file():
        raise RunError(f"{run} is not a run folder of `python -m abcgs.cluster submit` (no run.json)")
    return RunInfo.from_dict(json.loads(path.read_text(encoding="utf-8")))


def state_path(run: Path, job: str) -> Path:
    return run / "state" / f"{job}.json"


def read_state(run: Path, job: str) -> dict | None:
    path = state_path(run, job)
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None


# ------------------------------------------------------------------------------------------------ clones
def git(args: list[str], cwd: Path) -> str:
    proc = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RunError(f"git {' '.join(args)} (in {cwd}) failed: {proc.stderr.strip()}")
    return proc.stdout.strip()


def make_clone(repo: str, commit: str, dst: Path) -> Path:
    """A fresh checkout of ``commit`` at ``dst`` (``git clone --shared``: objects are read from ``repo``)."""
    if dst.exists():
        shutil.rmtree(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    git(["clone", "-q", "--shared", "--no-checkout", repo, str(dst)], dst.parent)
    git(["-c", "advice.detachedHead=false", "checkout", "-q", "--detach", commit], dst)
    return dst


def configure_cache(repo: Path, cache: str) -> None:
    """Point ``repo``'s DVC at the shared cache (``.dvc/config.local``: ``cache.dir``, ``cache.shared = group``)."""
    local = repo / ".dvc" / "config.local"
    text = local.read_text(encoding="utf-8") if local.is_file() else ""
    text = re.sub(r"(?ms)^\[cache\]\n(?:(?!\[).*\n?)*", "", text).rstrip()
    local.write_text((text + "\n" if text else "") + f"[cache]\n    dir = {cache}\n    shared = group\n",
                     encoding="utf-8")


# ------------------------------------------------------------------------------------------------ dvc repro
_RUNNING = re.compile(r"Running stage '([^']+)'")
_CACHED = re.compile(r"Stage '([^']+)' is cached - skipping run")
_UNCHANGED = re.compile(r"Stage '([^']+)' didn't change, skipping")


@dataclass
class StageLog:
    """What one ``dvc repro`` did, from its output: the stages it ran, restored from the run cache, or skipped."""

    ran: list[str] = field(default_factory=list)
    restored: list[str] = field(default_factory=list)
    unchanged: list[str] = field(default_factory=list)
    current: str | None = None

    def feed(self, line: str) -> bool:
        """Take one output line; True when it starts, restores or skips a stage."""
        for pattern, bucket in ((_RUNNING, self.ran), (_CACHED, self.restored), (_UNCHANGED, self.unchanged)):
            m = pattern.search(line)
            if m:
                bucket.append(m.group(1))
                self.current = m.group(1) if bucket is self.ran else None
                return True
        return False

    def summary(self) -> str:
        ran = ", ".join(self.ran) if self.ran else "none"
        return f"ran {len(self.ran)} ({ran}); restored {len(self.restored)} from the run cache; {len(self.unchanged)} unchanged"


def dvc_env(repo: Path, extra: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of a ``dvc repro`` in ``repo``: the interpreter's ``bin/`` first on ``PATH`` and the clone's
    ``abcgs`` first on ``PYTHONPATH``, so the stages run the commit's code (the C++ kernels come from the installed
    abcgs while the clone's sources match them: ``abcgs.render.cpu``)."""
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = str(repo) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["PYTHONUNBUFFERED"] = "1"
    env.setdefault("DVC_NO_ANALYTICS", "1")
    env.update(extra or {})
    return env


def repro(repo: Path, args: Iterable[str], keep_run_cache: bool, on_line: Callable[[str, StageLog], None] | None = None,
          env: dict[str, str] | None = None) -> tuple[int, StageLog]:
    """Run ``dvc repro ARGS`` in ``repo``, streaming its output through ``on_line``; (exit status, what it did).

    Through :mod:`abcgs.cluster.dvc_run`, which writes ``dvc.lock`` once; ``keep_run_cache`` (the jobs): and keeps
    every finished stage in the run cache."""
    head = [sys.executable, str(DVC_RUN), *(["--keep-run-cache"] if keep_run_cache else [])]
    log = StageLog()
    proc = subprocess.Popen([*head, "repro", *args], cwd=repo, env=env or dvc_env(repo), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, bufsize=1)
    assert proc.stdout is not None
    for line in proc.stdout:
        log.feed(line)
        if on_line is not None:
            on_line(line, log)
    return proc.wait(), log


def dvc_call(repo: Path, args: list[str], env: dict[str, str] | None = None, script: bool = False) -> int:
    """Run ``dvc ARGS`` (``script``: :mod:`abcgs.cluster.dvc_run` ``ARGS``) in ``repo`` with its output on ours;
    the exit status."""
    head = [sys.executable, str(DVC_RUN)] if script else [sys.executable, "-m", "dvc"]
    proc = subprocess.Popen([*head, *args], cwd=repo, env=env or dvc_env(repo),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
    assert proc.stdout is not None
    for line in proc.stdout:
        sys.stdout.write(line)
    sys.stdout.flush()
    return proc.wait()


def now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")
