"""``python -m abcgs.cluster plan|submit|status|collect`` (and ``job``, which the sbatch scripts run)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from abcgs.errors import AbcgsError


def parser() -> argparse.ArgumentParser:
    from abcgs.cluster.commands import add_plan_options

    ap = argparse.ArgumentParser(prog="python -m abcgs.cluster",
                                 description="Run the DVC pipeline as Slurm job arrays with a shared DVC cache.")
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("plan", help="print the jobs and arrays the pipeline splits into; submit nothing")
    add_plan_options(p)
    s = sub.add_parser("submit", help="submit the pipeline as job arrays; prints the run folder")
    add_plan_options(s)
    s.add_argument("--cluster-dir", type=Path, help="shared folder for cache/ and runs/ (or $ABCGS_CLUSTER_DIR)")
    s.add_argument("--cache", type=Path, help="the shared DVC cache (default CLUSTER_DIR/cache)")
    s.add_argument("--run-dir", type=Path, help="the run folder (default CLUSTER_DIR/runs/<time>-<commit>)")
    s.add_argument("--remote", action="store_true",
                   help="no shared cache: jobs pull from and push to the commit's default DVC remote (S3, ...)")
    s.add_argument("--keep-worktrees", action="store_true", help="keep each job's clone after it succeeds")
    s.add_argument("--dry-run", action="store_true", help="write the run folder and scripts; submit nothing")
    for name, text in (("status", "per-job state; the failing stage's last log lines"),
                       ("collect", "dvc repro in the workspace from the run cache: dvc.lock, the report")):
        c = sub.add_parser(name, help=text)
        c.add_argument("run", nargs="?", type=Path, help="the run folder (default: the newest under the cluster dir)")
        c.add_argument("--cluster-dir", type=Path, help="shared folder for cache/ and runs/ (or $ABCGS_CLUSTER_DIR)")
        c.add_argument("--lines", type=int, default=15, help="log lines shown per failed job")
        if name == "collect":
            c.add_argument("--into", type=Path, help="reproduce in this folder (a clone of the run's commit is made)")
            c.add_argument("-v", "--verbose", action="store_true", help="show dvc repro's output")
    j = sub.add_parser("job", help="run one array task (the sbatch scripts call this)")
    j.add_argument("run", type=Path)
    j.add_argument("array")
    j.add_argument("task", type=int)
    return ap


def main(argv: list[str] | None = None) -> int:
    a = parser().parse_args(argv)
    try:
        if a.cmd == "job":
            from abcgs.cluster.job import run_job

            return run_job(a.run, a.array, a.task)
        from abcgs.cluster import commands
        from abcgs.cluster.run import check_dvc_version

        if a.cmd in ("submit", "collect"):  # both run DVC through abcgs/cluster/dvc_run.py (the jobs check there)
            check_dvc_version()
        return {"plan": commands.cmd_plan, "submit": commands.cmd_submit, "status": commands.cmd_status,
                "collect": commands.cmd_collect}[a.cmd](a)
    except AbcgsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
