"""Show a DVC experiment's results without touching the workspace.

    python eval/show_exp.py fern-bench --out out/bench/fern-bench [--only '^fern_'] [--markdown]

`dvc exp run --temp` (``make bench-fern``) runs in a copy of the repository and keeps its results in an
experiment ref: git-tracked metrics in the ref's commit, cached outputs (renders, grids, report.html) in this
repository's DVC cache. This script checks the ref's commit out into a temporary git worktree, points it at
this repository's cache, restores the cached outputs (``dvc checkout``), prints the results table
(this checkout's ``python -m eval.report`` on the experiment's params and outputs) and copies ``reports/`` plus each run's ``stylize/grid.png`` and consistency heat
map to ``--out``. The worktree is removed afterwards; the workspace, its params and dvc.lock stay as they are.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def run(cmd: list[str], cwd: Path, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=cwd, check=check, capture_output=True, text=True)


def find_exp_commit(name: str) -> str:
    """The newest experiment ref named ``name`` (refs/exps/<..>/<baseline>/<name>)."""
    refs = run(["git", "for-each-ref", "--sort=-committerdate", "--format=%(objectname) %(refname)", "refs/exps"], REPO)
    for line in refs.stdout.splitlines():
        sha, ref = line.split(" ", 1)
        if ref.rsplit("/", 1)[-1] == name:
            return sha
    raise SystemExit(f"no DVC experiment named {name!r}; `dvc exp list --all-commits` shows the ones that exist")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("name", help="experiment name (dvc exp run -n NAME)")
    ap.add_argument("--out", type=Path, help="copy reports/ and per-run grids here")
    ap.add_argument("--only", help="regular expression on experiment names (passed to eval.report)")
    ap.add_argument("--markdown", action="store_true")
    a = ap.parse_args()
    sha = find_exp_commit(a.name)
    with tempfile.TemporaryDirectory(prefix="abcgs-exp-") as tmp:
        wt = Path(tmp) / "wt"
        run(["git", "worktree", "add", "--detach", str(wt), sha], REPO)
        try:
            dvc = [sys.executable, "-m", "dvc"]
            run(dvc + ["cache", "dir", "--local", str(REPO / ".dvc" / "cache")], wt)
            co = run(dvc + ["checkout", "--quiet"], wt, check=False)
            if co.returncode != 0:
                print(f"warning: dvc checkout restored only part of the outputs:\n{co.stderr.strip()[-2000:]}",
                      file=sys.stderr)
            # this checkout's report code on the experiment's params and outputs
            cmd = [sys.executable, "-m", "eval.report", "--params", str(wt / "params.yaml"), "--root", str(wt / "out")]
            cmd += (["--markdown"] if a.markdown else []) + (["--only", a.only] if a.only else [])
            table = run(cmd, REPO, check=False)
            if table.returncode != 0:
                print(table.stderr, file=sys.stderr)
                return table.returncode
            print(f"experiment {a.name} ({sha[:10]}):\n{table.stdout}")
            if a.out:
                a.out.mkdir(parents=True, exist_ok=True)
                if (wt / "reports").is_dir():
                    shutil.copytree(wt / "reports", a.out / "reports", dirs_exist_ok=True)
                for run_dir in sorted((wt / "out").iterdir()):
                    for src, dst in ((run_dir / "stylize" / "grid.png", f"{run_dir.name}_grid.png"),
                                     (run_dir / "eval_consistency.png", f"{run_dir.name}_consistency.png")):
                        if src.is_file():
                            shutil.copy2(src, a.out / dst)
                print(f"report and grids copied to {a.out}")
        finally:
            run(["git", "worktree", "remove", "--force", str(wt)], REPO, check=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
