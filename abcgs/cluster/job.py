"""What one Slurm array task does: ``python -m abcgs.cluster job RUN ARRAY TASK`` (the sbatch scripts call it).

1. Look the task's job up in the run's plan (``run.json``). If a job it waits for did not succeed, run nothing and
   fail: this is what the report job does when Slurm starts it after every other job has ended (``afterany``).
2. Make a fresh clone of the run's commit (``work/<job>``, or ``$ABCGS_CLUSTER_SCRATCH/<run>/<job>`` on node-local
   disk), without its ``dvc.lock``, point its DVC at the shared cache and, when the run has its own params, write
   them in.
3. ``dvc repro <the job's targets>`` through :mod:`abcgs.cluster.dvc_run`. Upstream stages, made by earlier jobs,
   are restored from the run cache; the job's own stages run and go into the run cache as each one finishes. A
   stage killed halfway leaves nothing in the cache (DVC commits a stage's outputs after its command succeeds),
   and a retry starts from a fresh clone, so it restores every finished stage and re-runs only the rest.
   With a DVC remote instead of a shared cache (``submit --remote``), the clone keeps its own cache:
   ``dvc repro --pull`` fetches the run cache and the upstream outputs, and :func:`abcgs.cluster.dvc_run.push_run_cache`
   sends the run-cache entries and their outputs back when the job succeeds.
4. Keep ``state/<job>.json`` current (the stage it is in, what it ran and restored) for ``status`` and
   ``collect``; the output goes to the Slurm log.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

from abcgs.cluster.run import (
    StageLog,
    configure_cache,
    dvc_call,
    dvc_env,
    load_run,
    make_clone,
    now,
    read_state,
    repro,
    state_path,
)
from abcgs.io.atomic import write_json


def clone_dir(run: Path, job: str) -> Path:
    """Where ``job`` checks the commit out: node-local scratch when ``ABCGS_CLUSTER_SCRATCH`` is set."""
    scratch = os.environ.get("ABCGS_CLUSTER_SCRATCH")
    return Path(scratch) / run.name / job if scratch else run / "work" / job


def run_job(run: Path, array: str, task: int) -> int:
    """Run task ``task`` of ``array``; the exit status of its ``dvc repro``."""
    run = run.resolve()
    info = load_run(run)
    name = info.plan.array(array).jobs[task]
    job = info.plan.jobs[name]
    slurm_id = f"{os.environ.get('SLURM_ARRAY_JOB_ID', '?')}_{os.environ.get('SLURM_ARRAY_TASK_ID', task)}"
    record = {"job": name, "array": array, "task": task, "slurm_id": slurm_id,
              "attempt": int(os.environ.get("SLURM_RESTART_COUNT", "0") or 0) + 1,
              "host": os.uname().nodename, "log": str(run / "logs" / f"{array}_{slurm_id}.out"),
              "state": "preparing", "stage": None, "ran": [], "restored": [], "unchanged": [], "started": now()}
    write_json(state_path(run, name), record)
    print(f"[abcgs.cluster] {name} (attempt {record['attempt']}, {slurm_id} on {record['host']}): "
          f"dvc repro {' '.join(job.targets) or '(whole pipeline)'}", flush=True)
    missing = [j for j in job.after if (read_state(run, j) or {}).get("state") != "ok"]
    if missing:  # the report job starts when the others have ended (afterany); it needs them to have succeeded
        record.update(state="failed", error=f"jobs not done: {', '.join(missing)}", ended=now(), exit_code=3)
        write_json(state_path(run, name), record)
        print(f"[abcgs.cluster] {name}: not run, these jobs did not succeed: {', '.join(missing)} "
              "(python -m abcgs.cluster status shows why)", flush=True)
        return 3

    try:
        wt = make_clone(info.repo, info.commit, clone_dir(run, name))
        (wt / "dvc.lock").unlink(missing_ok=True)  # every stage comes from the run cache or runs; none from git
        if not info.use_remote:
            configure_cache(wt, info.cache)
        if info.params_file:
            shutil.copyfile(run / info.params_file, wt / "params.yaml")
    except Exception as exc:
        record.update(state="failed", error=f"preparing the clone: {exc}", ended=now(), exit_code=1)
        write_json(state_path(run, name), record)
        raise

    def on_line(line: str, log: StageLog) -> None:
        sys.stdout.write(line)
        sys.stdout.flush()
        if log.current != record["stage"] or len(log.ran) + len(log.restored) + len(log.unchanged) != \
                len(record["ran"]) + len(record["restored"]) + len(record["unchanged"]):
            record.update(state="running", stage=log.current, ran=list(log.ran), restored=list(log.restored),
                          unchanged=list(log.unchanged))
            write_json(state_path(run, name), record)

    args = ["--pull", *job.targets] if info.use_remote else list(job.targets)
    rc, log = repro(wt, args, keep_run_cache=True, on_line=on_line, env=dvc_env(wt))
    if rc == 0 and info.use_remote:  # the run-cache entries and their outputs go to the remote for the next jobs
        rc = dvc_call(wt, ["push-run-cache"], script=True)
    record.update(state="ok" if rc == 0 else "failed", stage=None if rc == 0 else log.current, ran=log.ran,
                  restored=log.restored, unchanged=log.unchanged, ended=now(), exit_code=rc)
    write_json(state_path(run, name), record)
    print(f"[abcgs.cluster] {name}: {'done' if rc == 0 else f'FAILED ({rc})'}: {log.summary()}", flush=True)
    if rc == 0 and not info.keep_worktrees:
        shutil.rmtree(wt, ignore_errors=True)
    return rc
