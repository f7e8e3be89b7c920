"""The Slurm side: sbatch scripts from a template, submission with dependencies, and job states.

One script per job array (:func:`render_script`). Every task runs ``python -m abcgs.cluster job RUN ARRAY
$SLURM_ARRAY_TASK_ID``, which looks the task's job up in the run folder's plan. Dependencies are given at
submission, when the upstream arrays' ids are known (:func:`dependency`). ``afterok`` ones come with
``--kill-on-invalid-dep=yes``: when a scene fails, its experiments are cancelled instead of pending forever.

States come from ``squeue`` for jobs still queued or running and from ``sacct`` for finished ones, or from
``scontrol show job`` on a cluster without accounting storage, which keeps a finished job for ``MinJobAge``
seconds (:func:`task_states`).
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from string import Template

from abcgs.cluster.plan import Array, Plan, Resources
from abcgs.errors import AbcgsError

SBATCH_TEMPLATE = Template("""\
#!/bin/bash
# abcgs job array "$array" ($kind): task i runs job i below in its own clone of commit $commit, with the DVC
# cache $cache_q. Written by `python -m abcgs.cluster submit`; run folder $run_q.
$job_list
#SBATCH --job-name=abcgs-$array
#SBATCH --array=0-$last$throttle
#SBATCH --output=$logs/${array}_%A_%a.out
#SBATCH --open-mode=append
#SBATCH --chdir=$run
#SBATCH --requeue
$resource_lines
set -euo pipefail
export PATH=$bindir:$$PATH
export OMP_NUM_THREADS=$${SLURM_CPUS_PER_TASK:-1}
export DVC_NO_ANALYTICS=1
exec $python -m abcgs.cluster job $run_q $array_q "$$SLURM_ARRAY_TASK_ID"
""")
"""The sbatch script of one job array (``string.Template``; ``$$`` is a literal ``$`` for bash). Every path in it is
checked by :func:`script_path` and, outside ``#SBATCH`` lines, quoted for the shell."""


class SlurmError(AbcgsError):
    """A Slurm command failed (the message has its output), or a value cannot go into an sbatch script."""


_CONTROL = re.compile(r"[\x00-\x1f\x7f]")
_DIRECTIVE_UNSAFE = re.compile(r"[\s\"'\\#%]")


def script_path(path: str | Path, what: str, directive: bool = False) -> str:
    """``path`` as text for an sbatch script, refused (naming ``what``, e.g. ``--run-dir``) when it holds a newline,
    NUL or another control character, which would end its line and start a command of its own; ``directive``: it
    also goes into ``#SBATCH`` lines, which sbatch splits at spaces and cuts at ``#`` (and reads ``%`` in
    ``--output`` as a pattern), so those are refused too."""
    text = str(path)
    bad = _CONTROL.search(text)
    if bad:
        raise SlurmError(f"{what} {text!r} holds the control character {bad.group()!r} (e.g. a newline), which would "
                         "end its line in the sbatch script; choose a path without it")
    bad = _DIRECTIVE_UNSAFE.search(text) if directive else None
    if bad:
        raise SlurmError(f"{what} {text!r} holds {bad.group()!r}; the run folder goes into #SBATCH lines, which "
                         "take no spaces, quotes, '#', '%' or backslashes: choose a folder without them")
    return text


def render_script(plan: Plan, array: Array, resources: Resources, run: Path, commit: str, cache: str,
                  python: str) -> str:
    """The sbatch script of ``array`` (see :data:`SBATCH_TEMPLATE`)."""
    jobs = "\n".join(f"#   {i}: {name}: dvc repro {' '.join(plan.jobs[name].targets) or '(the whole pipeline)'}"
                     for i, name in enumerate(array.jobs))
    throttle = f"%{resources.max_parallel}" if resources.max_parallel else ""
    run_text = script_path(run, "the run folder", directive=True)
    cache, python = script_path(cache, "the DVC cache"), script_path(python, "the Python interpreter")
    targets = [t for name in array.jobs for t in (name, *plan.jobs[name].targets)]
    for text in (commit, array.name, array.kind, *targets, *resources.sbatch_options()):
        script_path(text, "a value of the plan or of --resources")
    return SBATCH_TEMPLATE.substitute(
        array=array.name, kind=array.kind, commit=commit, cache_q=shlex.quote(cache), run=run_text, job_list=jobs,
        last=len(array.jobs) - 1, throttle=throttle, logs=run / "logs",
        resource_lines="\n".join(f"#SBATCH {o}" for o in resources.sbatch_options()),
        bindir=shlex.quote(str(Path(python).parent)), python=shlex.quote(python),
        run_q=shlex.quote(run_text), array_q=shlex.quote(array.name))


def dependency(array: Array, ids: Mapping[str, str]) -> list[str]:
    """sbatch options for ``array.after``: ``<wait>:<id>`` (all tasks) or ``<wait>:<id>_<task>`` (one task), and
    ``--kill-on-invalid-dep=yes`` for ``afterok``."""
    if not array.after:
        return []
    deps = [ids[a] if task is None else f"{ids[a]}_{task}" for a, task in array.after]
    kill = ["--kill-on-invalid-dep=yes"] if array.wait == "afterok" else []
    return [f"--dependency={array.wait}:{':'.join(deps)}", *kill]


LOCAL_SLURM_HINT = (
    "run on a Slurm login node, or set SLURM_CONF to the cluster's slurm.conf; to try it on this machine, start a "
    "one-node Slurm from the abcgs checkout: `sudo python -m eval.slurm_local install`, then "
    "`sudo python -m eval.slurm_local start DIR` and `export SLURM_CONF=DIR/slurm.conf`"
)
"""What to do when no Slurm is reachable: abcgs submits to a Slurm that is there and sets none up
(``eval/slurm_local.py`` does, for a try on one machine and for the tests)."""


def _run(cmd: list[str], check: bool = True) -> subprocess.CompletedProcess:
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    except FileNotFoundError:
        raise SlurmError(f"{cmd[0]} not found, so no Slurm is reachable from here: {LOCAL_SLURM_HINT}") from None
    if check and proc.returncode != 0:
        raise SlurmError(f"`{shlex.join(cmd)}` failed ({proc.returncode}): {proc.stderr.strip() or proc.stdout.strip()}")
    return proc


def check_reachable() -> None:
    """Raise :class:`SlurmError` (with :data:`LOCAL_SLURM_HINT`) unless ``sinfo`` reaches a Slurm controller."""
    proc = _run(["sinfo", "-h", "-o", "%P"], check=False)
    if proc.returncode != 0:
        raise SlurmError(f"no Slurm controller answers `sinfo` ({(proc.stderr or proc.stdout).strip()[-300:]}): "
                         f"{LOCAL_SLURM_HINT}")


def sbatch(script: Path, options: Iterable[str] = ()) -> str:
    """Submit ``script``; the job id (an array's master id)."""
    out = _run(["sbatch", "--parsable", *options, str(script)]).stdout.strip()
    return out.split(";")[0]


@dataclass(frozen=True)
class TaskState:
    """One array task as Slurm sees it."""

    slurm_id: str
    state: str
    reason: str = ""
    exit_code: str = ""
    restarts: int = 0
    elapsed: str = ""


FINISHED = ("COMPLETED", "FAILED", "CANCELLED", "TIMEOUT", "OUT_OF_MEMORY", "NODE_FAIL", "PREEMPTED", "BOOT_FAIL",
            "DEADLINE")


def _expand_tasks(spec: str) -> list[int]:
    """``0-2,5%2`` → ``[0, 1, 2, 5]`` (an array's pending tasks as ``scontrol`` lists them)."""
    out: list[int] = []
    for part in spec.split("%")[0].split(","):
        if "-" in part:
            a, b = part.split("-", 1)
            out += range(int(a), int(b) + 1)
        elif part.strip().isdigit():
            out.append(int(part))
    return out


def _from_squeue(ids: list[str]) -> dict[str, TaskState]:
    proc = _run(["squeue", "-h", "-r", "-j", ",".join(ids), "-o", "%i|%T|%r|%M"], check=False)
    out: dict[str, TaskState] = {}
    for line in proc.stdout.splitlines():
        parts = line.strip().split("|")
        if len(parts) == 4 and "_" in parts[0]:
            out[parts[0]] = TaskState(parts[0], parts[1], parts[2], elapsed=parts[3])
    return out


def _from_sacct(ids: list[str]) -> dict[str, TaskState] | None:
    proc = _run(["sacct", "-n", "-P", "-X", "-j", ",".join(ids), "--format=JobID,State,ExitCode,Elapsed"], check=False)
    if proc.returncode != 0:
        return None  # no accounting storage on this cluster
    out: dict[str, TaskState] = {}
    for line in proc.stdout.splitlines():
        parts = line.strip().split("|")
        if len(parts) == 4 and "_" in parts[0] and "[" not in parts[0]:
            out[parts[0]] = TaskState(parts[0], parts[1].split()[0], exit_code=parts[2], elapsed=parts[3])
    return out


def _from_scontrol(ids: list[str]) -> dict[str, TaskState]:
    out: dict[str, TaskState] = {}
    for jid in ids:
        proc = _run(["scontrol", "-o", "show", "job", jid], check=False)
        for line in proc.stdout.splitlines():
            f = dict(re.findall(r"(\w+)=(\S*)", line))
            if "ArrayJobId" not in f:
                continue
            for task in _expand_tasks(f.get("ArrayTaskId", "")):
                sid = f"{f['ArrayJobId']}_{task}"
                out[sid] = TaskState(sid, f.get("JobState", "?"), f.get("Reason", ""), f.get("ExitCode", ""),
                                     int(f.get("Restarts", "0") or 0), f.get("RunTime", ""))
    return out


def task_states(ids: Iterable[str]) -> dict[str, TaskState]:
    """``<arrayid>_<task>`` → :class:`TaskState` for every task of the arrays ``ids``: the state from ``squeue``
    while queued or running, else from ``sacct``, else from ``scontrol`` (which also gives the restart count)."""
    ids = [i for i in ids if i]
    if not ids:
        return {}
    details, acct, queue = _from_scontrol(ids), _from_sacct(ids) or {}, _from_squeue(ids)
    out: dict[str, TaskState] = {}
    for sid in sorted(set(details) | set(acct) | set(queue)):
        d, a, q = details.get(sid), acct.get(sid), queue.get(sid)
        first = q or a or d
        assert first is not None
        out[sid] = TaskState(sid, first.state, (q.reason if q else "") or (d.reason if d else ""),
                             (a.exit_code if a else "") or (d.exit_code if d else ""), d.restarts if d else 0,
                             first.elapsed or (d.elapsed if d else ""))
    return out


def requeue_command(slurm_ids: Iterable[str]) -> str:
    return f"scontrol requeue {','.join(slurm_ids)}"


def python_executable() -> str:
    """The interpreter the jobs run (this one: the project's virtual environment, on the shared filesystem)."""
    return sys.executable
