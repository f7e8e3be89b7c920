"""Wall time, core use and peak memory of every pipeline stage, from a clean copy of this repository.

    python eval/bench_pipeline.py                           # the default params (tiny scene)
    python eval/bench_pipeline.py --set fit.iterations=300 --json out/bench/pipeline_tiny.json
    python eval/bench_pipeline.py --params my_params.yaml   # e.g. a real scene × paintings (absolute paths)
    python eval/bench_pipeline.py --targets fit@tiny        # one stage and what it needs

How it measures: the working tree is copied into a fresh git + DVC repository (``eval/repo_copy.py``: no
outputs, empty cache, as a clean clone), ``--params`` replaces its ``params.yaml`` and ``--set`` changes keys
in it. ``dvc dag`` gives the stages in an order that respects their edges; then each stage runs alone
(``dvc repro --single-item <stage>``) inside a fresh Python wrapper process that reports, from
``getrusage(RUSAGE_CHILDREN)``, the CPU seconds (user + system) of the stage's processes and their peak
resident set size. Per stage it prints wall seconds, CPU seconds / wall (core use: 1.0 = one core busy) and
peak RSS, then the totals (peak = the largest stage's), and writes everything to ``--json`` with the machine
(``os.cpu_count()``, load average before the run) so that figures from different days can be compared. Run on
an idle machine for figures you quote: other work shows up as lower core use and longer walls.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import yaml  # noqa: E402

from abcgs.io.atomic import write_json  # noqa: E402
from abcgs.params import set_dotted  # noqa: E402
from eval.repo_copy import copy_repo, run_in  # noqa: E402

WRAPPER = r"""
import json, resource, subprocess, sys, time
t = time.perf_counter()
proc = subprocess.run(sys.argv[1:], capture_output=True, text=True)
wall = time.perf_counter() - t
ru = resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"rc": proc.returncode, "wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime,
                  "peak_rss_mib": ru.ru_maxrss / 1024.0, "tail": (proc.stdout + proc.stderr)[-3000:]}))
"""
"""Runs one command and reports its children's resource use (a fresh process per stage: ru_maxrss is a max)."""


def stage_order(repo: Path, targets: list[str] | None = None) -> list[str]:
    """Every stage (or the ``targets`` and what they need), in an order that respects the pipeline's edges
    (``dvc dag --dot``; ties keep the ``dvc.yaml`` order): the order ``dvc repro`` runs them on a fresh clone."""
    proc = run_in(["dvc", "dag", "--dot"], repo, timeout=600)
    if proc.returncode != 0:
        raise RuntimeError(f"dvc dag failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")
    nodes = re.findall(r'^"([^"]+)";$', proc.stdout, re.M)
    edges = re.findall(r'^"([^"]+)" -> "([^"]+)";$', proc.stdout, re.M)
    before = {n: {a for a, b in edges if b == n} for n in nodes}
    if targets:
        unknown = [t for t in targets if t not in before]
        if unknown:
            raise SystemExit(f"unknown stage(s) {unknown}; stages: {', '.join(nodes)}")
        keep, todo = set(), list(targets)
        while todo:
            n = todo.pop()
            if n not in keep:
                keep.add(n)
                todo.extend(before[n])
        nodes = [n for n in nodes if n in keep]
    order: list[str] = []
    while len(order) < len(nodes):
        ready = [n for n in nodes if n not in order and before[n] <= set(order)]
        if not ready:
            raise RuntimeError("the DVC graph has a cycle")
        order.append(ready[0])
    return order


def bench(repo: Path, stages: list[str]) -> list[dict]:
    rows = []
    for name in stages:
        proc = run_in([sys.executable, "-c", WRAPPER, "dvc", "repro", "--single-item", name], repo, timeout=None)
        rec = json.loads(proc.stdout.strip().splitlines()[-1])
        if rec["rc"] != 0:
            raise RuntimeError(f"stage {name} failed:\n{rec['tail']}")
        rec.pop("tail")
        rec["stage"] = name
        rec["core_use"] = rec["cpu_s"] / max(rec["wall_s"], 1e-9)
        rows.append(rec)
        print(f"  {name:34s} {rec['wall_s']:8.1f} s  cpu/wall {rec['core_use']:4.2f}  peak RSS {rec['peak_rss_mib']:7.0f} MiB",
              flush=True)
    return rows


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--params", type=Path, default=None, help="params file to run (default: this repository's)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="change a key (YAML value)")
    ap.add_argument("--targets", nargs="*", default=None, help="only these stages and the ones they need")
    ap.add_argument("--work", type=Path, default=None, help="where the copy goes (default: a temporary folder)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)

    def edit(params: dict) -> None:
        if args.params is not None:
            params.clear()
            params.update(yaml.safe_load(args.params.read_text()))
        for item in args.set:
            key, _, value = item.partition("=")
            set_dotted(params, key, yaml.safe_load(value))

    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        repo = copy_repo(work / "repo", edit)
        stages = stage_order(repo, args.targets)
        load = os.getloadavg()
        print(f"[bench_pipeline] {len(stages)} stages in {repo}; {os.cpu_count()} CPUs, load average {load[0]:.2f}",
              flush=True)
        t0 = time.perf_counter()
        rows = bench(repo, stages)
        total_wall = time.perf_counter() - t0
    total_cpu = sum(r["cpu_s"] for r in rows)
    result = {
        "stages": rows, "total_wall_s": total_wall, "total_cpu_s": total_cpu,
        "core_use": total_cpu / max(total_wall, 1e-9), "peak_rss_mib": max(r["peak_rss_mib"] for r in rows),
        "params": str(args.params or "params.yaml"), "set": args.set,
        "machine": {"cpus": os.cpu_count(), "loadavg_before": load, "platform": platform.platform(),
                    "python": platform.python_version()},
        "how": "each stage alone (dvc repro --single-item) in a fresh wrapper process; CPU and peak RSS from "
               "getrusage(RUSAGE_CHILDREN); a clean copy of the working tree with an empty DVC cache",
    }
    print(f"[bench_pipeline] total {total_wall / 60:.1f} min wall, cpu/wall {result['core_use']:.2f}, "
          f"peak RSS {result['peak_rss_mib']:.0f} MiB")
    if args.json:
        write_json(args.json, result)
    return result


if __name__ == "__main__":
    main()
