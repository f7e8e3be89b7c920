"""The README's first command on a machine that has nothing: a fresh clone, an empty HOME, no git identity.

    python -m eval run first_run [--json docs/measurements/first_run.json] [--rev HEAD] [--work /tmp/first-run]

Clones ``--rev`` of this repository into ``--work`` and runs ``make install`` then ``make run`` there with ``HOME``
an empty folder, no global git config and no git identity (as ``.ci/run`` does; pip's configuration, which holds
the machine's package indexes, is kept). Records the wall time of each, the load average before them (the
record's provenance has the machine and the load after) and the end of each log. ``make run`` is ``make install``
(a no-op by then) + the preflight + ``dvc repro``; the per-stage times come from DVC's log of the run.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from eval.record import bench_parser, write_record

ROOT = Path(__file__).resolve().parents[2]
STAGE_DONE = re.compile(r"\[(\w+)\] done in ([0-9.]+) s")


def newcomer_env(home: Path) -> dict[str, str]:
    """The environment of a newcomer: this one with ``HOME`` empty, no git identity or global git config."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("GIT_", "XDG_", "VIRTUAL_ENV")) and k not in ("EMAIL", "PYTHONPATH")}
    pip_conf = [Path(os.environ.get("PIP_CONFIG_FILE", "")), Path.home() / ".config/pip/pip.conf",
                Path.home() / ".pip/pip.conf"]
    for conf in pip_conf:
        if str(conf) not in ("", ".") and conf.is_file():
            env["PIP_CONFIG_FILE"] = str(conf)
            break
    env.update(HOME=str(home), GIT_CONFIG_GLOBAL="/dev/null")
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep) if "/.venv/" not in p)
    return env


def timed(cmd: list[str], cwd: Path, env: dict[str, str], log: Path) -> tuple[float, int, str]:
    """Run ``cmd``; its wall time in seconds, exit status and output (also written to ``log``)."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seconds = time.perf_counter() - t0
    log.write_text(proc.stdout)
    print(f"{' '.join(cmd)}: {seconds:.0f} s (exit {proc.returncode})", flush=True)
    return seconds, proc.returncode, proc.stdout


def main(argv: list[str] | None = None) -> int:
    ap = bench_parser(__doc__)
    ap.add_argument("--rev", default="HEAD", help="the revision to clone")
    ap.add_argument("--work", type=Path, help="where to clone (default: a temporary folder, removed afterwards)")
    args = ap.parse_args(argv)
    work = args.work or Path(tempfile.mkdtemp(prefix="abcgs-first-run-"))
    clone, home = work / "abcgs", work / "home"
    if clone.exists():
        sys.exit(f"{clone} exists; give an empty --work")
    home.mkdir(parents=True)
    subprocess.run(["git", "clone", "-q", "--no-hardlinks", str(ROOT), str(clone)], check=True)
    subprocess.run(["git", "checkout", "-q", args.rev], cwd=clone, check=True)
    rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=clone, capture_output=True, text=True, check=True).stdout
    env = newcomer_env(home)
    load_before = os.getloadavg()
    install_s, install_rc, _ = timed(["make", "install"], clone, env, work / "install.log")
    run_s, run_rc, run_log = (timed(["make", "run"], clone, env, work / "run.log") if install_rc == 0
                              else (0.0, -1, ""))
    record = {
        "revision": rev.strip(),
        "load_average_before": [round(x, 2) for x in load_before],
        "make_install_s": round(install_s, 1), "make_install_exit": install_rc,
        "make_run_s": round(run_s, 1), "make_run_exit": run_rc,
        "total_s": round(install_s + run_s, 1), "total_min": round((install_s + run_s) / 60, 2),
        "stage_seconds": [{"stage": m.group(1), "seconds": float(m.group(2))} for m in STAGE_DONE.finditer(run_log)],
        "run_log_tail": run_log[-3000:],
    }
    if args.json:
        write_record(args.json, record, argv)
    print(f"first run: install {install_s / 60:.1f} min + run {run_s / 60:.1f} min = {record['total_min']:.1f} min")
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if install_rc == run_rc == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
