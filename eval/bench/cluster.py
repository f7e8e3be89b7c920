"""The tiny pipeline through a one-node Slurm cluster against plain ``dvc repro``: wall time and equal results.

    python -m eval run cluster --repeat 2 --json docs/measurements/cluster_tiny.json

Both runs start from a clean copy of the working tree (``eval/bench/repo_copy.py``) with the REDUCED iteration
counts of the regression test (``eval/bench/regression.py``) and an empty DVC cache:

- **plain**: ``dvc repro`` in the copy;
- **cluster**: a one-node Slurm on localhost (``eval/slurm_local.py``), ``python -m abcgs.cluster submit``, wait
  for the queue to empty, then ``collect`` (``dvc repro`` in the copy, restoring every stage from the run cache).
  Its wall time runs from ``submit`` to the end of ``collect``, and the per-job times come from the run folder.
  By default every job asks for all of the node's cores, so the jobs run one after the other with the thread
  counts of the plain run, and the comparison isolates what the cluster path adds; ``--resources FILE`` (e.g.
  experiments on one core each, side by side) changes that, and the thread counts then move the metrics by up to
  5e-5, relative.

It prints the walls and the ratio of their medians, whether every headline metric (``out/*/metrics.json`` and
``out/*/fit_metrics.json``, timings left out), every stylized and fitted PLY and every entry of ``dvc.lock``
(each stage's command, dep and out hashes, params) is the same in all runs, and writes it all to ``--json``.
Records that hold wall times (``stylize.json``, ``eval.json``, ...) differ between any two runs; with two or more
plain runs it also prints which ``dvc.lock`` entries differ between plain runs, and whether the cluster run
differs from the plain runs in any other. The goal is a ratio within 1.5: the scheduler, the clones and the
restores cost little next to the stages. ``--repeat N`` alternates the order (plain, cluster, cluster, plain,
...): on a shared machine the load changes from one run to the next. ``--first cluster`` starts with the cluster
run. Needs root and Debian's ``slurm-wlm`` and ``munge`` (installed when missing).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs.cluster.run import load_run, read_state
from eval.bench.regression import REDUCED, reduce
from eval.bench.repo_copy import copy_repo, run_in
from eval.record import bench_parser, write_record
from eval.slurm_local import LocalSlurm, install

TIMING_KEYS = re.compile(r"minutes|seconds|timings|_fps|speed")
"""Metric keys that measure time, not the result."""
DEFAULT_RESOURCES = {kind: {"cpus": os.cpu_count() or 1, "mem": "2G", "time": "01:00:00"}
                     for kind in ("prep", "scene", "experiment", "report")}


def results(repo: Path) -> dict:
    """Headline metrics without timings, and the SHA-256 of each fitted / stylized PLY, by file."""
    out: dict = {"metrics": {}, "ply": {}}
    for f in sorted((repo / "out").glob("*/*metrics.json")):
        data = json.loads(f.read_text())
        out["metrics"][f.relative_to(repo).as_posix()] = {k: v for k, v in data.items() if not TIMING_KEYS.search(k)}
    for f in sorted((repo / "out").rglob("point_cloud.ply")):
        out["ply"][f.relative_to(repo).as_posix()] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def differences(a: dict, b: dict) -> dict:
    """Metric values and PLY hashes that differ between two :func:`results`."""
    diff: dict = {"metrics": {}, "ply": sorted(k for k in set(a["ply"]) | set(b["ply"]) if a["ply"].get(k) != b["ply"].get(k))}
    for f in sorted(set(a["metrics"]) | set(b["metrics"])):
        ma, mb = a["metrics"].get(f, {}), b["metrics"].get(f, {})
        for k in sorted(set(ma) | set(mb)):
            if ma.get(k) != mb.get(k):
                diff["metrics"][f"{f}:{k}"] = [ma.get(k), mb.get(k)]
    return diff


def lock_entries(repo: Path) -> dict[str, str]:
    """``dvc.lock`` flattened to ``stage:field:path -> value`` (cmd, each dep's and out's md5, each param)."""
    flat: dict[str, str] = {}
    for stage, entry in yaml.safe_load((repo / "dvc.lock").read_text())["stages"].items():
        flat[f"{stage}:cmd"] = str(entry.get("cmd"))
        for field in ("deps", "outs"):
            for item in entry.get(field, []):
                flat[f"{stage}:{field}:{item['path']}"] = str(item.get("md5") or item.get("hash"))
        for file, values in (entry.get("params") or {}).items():
            for key, value in values.items():
                flat[f"{stage}:params:{file}:{key}"] = json.dumps(value, sort_keys=True)
    return flat


def lock_differences(a: dict[str, str], b: dict[str, str]) -> list[str]:
    """The ``stage:field:path`` entries of two :func:`lock_entries` that differ or exist in one only."""
    return sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))


def lock_summary(plain: list[dict[str, str]], cluster: list[dict[str, str]]) -> dict:
    """The :func:`lock_entries` of the plain and the cluster runs compared: the entries that differ between any
    plain and any cluster run, those that differ between plain runs (``None`` with one plain run), and the first
    set less the second."""
    across = sorted({k for p in plain for c in cluster for k in lock_differences(p, c)})
    run_to_run = (sorted({k for n, p in enumerate(plain) for q in plain[n + 1:] for k in lock_differences(p, q)})
                  if len(plain) > 1 else None)
    return {"lock_equal": not across, "lock_entries": len(plain[0]), "lock_differences": across,
            "lock_differences_plain_vs_plain": run_to_run,
            "lock_differences_beyond_plain_vs_plain": None if run_to_run is None else sorted(set(across) - set(run_to_run))}


def run_plain(work: Path) -> dict:
    repo = copy_repo(work / "repo", reduce)
    t0 = time.perf_counter()
    proc = run_in(["dvc", "repro"], repo, timeout=7200)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"plain dvc repro failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return {"wall_s": round(wall, 1), "stages_run": len(re.findall(r"Running stage '", proc.stdout)),
            "results": results(repo), "lock": lock_entries(repo)}


def _cli(args: list[str], repo: Path, env: dict) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", "abcgs.cluster", *args], cwd=repo, env=env, capture_output=True,
                          text=True, timeout=3600)
    if proc.returncode != 0:
        raise SystemExit(f"abcgs.cluster {args[0]} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return proc


def _seconds(a: str, b: str) -> float:
    fmt = "%Y-%m-%dT%H:%M:%S%z"
    return time.mktime(time.strptime(b, fmt)) - time.mktime(time.strptime(a, fmt))


def run_cluster(work: Path, resources: dict) -> dict:
    repo = copy_repo(work / "repo", reduce)
    (work / "resources.yaml").write_text(yaml.safe_dump(resources))
    with LocalSlurm(work / "slurm") as slurm:
        env = {**slurm.env, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
        t0 = time.perf_counter()
        proc = _cli(["submit", "--cluster-dir", str(work / "shared"), "--resources", str(work / "resources.yaml")],
                    repo, env)
        run = Path(re.search(r"^run (\S+)", proc.stdout, re.M).group(1))
        while subprocess.run(["squeue", "-h"], env=env, capture_output=True, text=True).stdout.strip():
            time.sleep(1)
        queue_done = time.perf_counter() - t0
        _cli(["collect", str(run)], repo, env)
        wall = time.perf_counter() - t0
        collect = json.loads((run / "collect.json").read_text())
    jobs = {}
    for name in load_run(run).plan.jobs:
        rec = read_state(run, name) or {}
        jobs[name] = {"state": rec.get("state"), "wall_s": _seconds(rec["started"], rec["ended"]) if rec.get("ended") else None,
                      "ran": len(rec.get("ran") or []), "restored": len(rec.get("restored") or [])}
    return {"wall_s": round(wall, 1), "jobs_done_s": round(queue_done, 1), "collect_s": round(wall - queue_done, 1),
            "collect_ran": collect["ran"], "collect_restored": len(collect["restored"]), "jobs": jobs,
            "stages_run": sum(j["ran"] for j in jobs.values()), "resources": resources, "results": results(repo),
            "lock": lock_entries(repo)}


def _median(xs: list[float]) -> float:
    xs = sorted(xs)
    return (xs[len(xs) // 2] + xs[(len(xs) - 1) // 2]) / 2


def main(argv: list[str] | None = None) -> dict:
    ap = bench_parser(__doc__)
    ap.prog = "python -m eval run cluster"
    ap.add_argument("--resources", type=Path, help="per-kind resources for the cluster run (default: see the code)")
    ap.add_argument("--first", choices=("plain", "cluster"), default="plain", help="which run goes first")
    ap.add_argument("--repeat", type=int, default=1, help="rounds; the order alternates (plain, cluster, cluster, "
                    "plain, ...) so that a drift of the machine's speed reaches both alike; medians are compared")
    ap.add_argument("--work", type=Path, help="keep the copies here (default: a temporary folder)")
    a = ap.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # stop the cluster and remove the copies on kill
    install()
    resources = yaml.safe_load(a.resources.read_text()) if a.resources else DEFAULT_RESOURCES
    load_before = os.getloadavg()
    runs: dict[str, list[dict]] = {"plain": [], "cluster": []}
    order = [a.first, "cluster" if a.first == "plain" else "plain"]
    with tempfile.TemporaryDirectory(prefix="abcgs-bench-cluster-", dir=a.work) as tmp:
        for i in range(a.repeat):
            for which in (order if i % 2 == 0 else order[::-1]):
                print(f"[bench.cluster] round {i + 1}: {which} run ...", flush=True)
                work = Path(tmp) / f"{which}{i}"
                runs[which].append(run_plain(work) if which == "plain" else run_cluster(work, resources))
                print(f"[bench.cluster] round {i + 1}: {which}: {runs[which][-1]['wall_s']:.1f} s", flush=True)
    plain, cluster = (_median([r["wall_s"] for r in runs[k]]) for k in ("plain", "cluster"))
    diffs = [differences(p["results"], c["results"]) for p in runs["plain"] for c in runs["cluster"]]
    locks = lock_summary([r.pop("lock") for r in runs["plain"]], [r.pop("lock") for r in runs["cluster"]])
    ratio = cluster / plain
    out = {"loadavg_before": [round(x, 2) for x in load_before], "reduced": dict(REDUCED), "order": order,
           "repeat": a.repeat,
           "plain_wall_s": [r["wall_s"] for r in runs["plain"]], "cluster_wall_s": [r["wall_s"] for r in runs["cluster"]],
           "plain_median_s": plain, "cluster_median_s": cluster, "ratio": round(ratio, 3),
           "metrics_equal": not any(d["metrics"] for d in diffs), "ply_equal": not any(d["ply"] for d in diffs),
           "differences": [d for d in diffs if d["metrics"] or d["ply"]],
           **locks,
           "plain": runs["plain"], "cluster": runs["cluster"]}
    print(f"plain dvc repro: {', '.join(f'{r:.1f}' for r in out['plain_wall_s'])} s "
          f"({runs['plain'][0]['stages_run']} stages)")
    for c in runs["cluster"]:
        print(f"one-node Slurm:  {c['wall_s']:.1f} s (jobs {c['jobs_done_s']:.1f} s + collect {c['collect_s']:.1f} s; "
              f"{c['stages_run']} stages in jobs, collect ran {len(c['collect_ran'])})")
    print(f"ratio cluster / plain (medians): {ratio:.2f} (goal <= 1.5)")
    print(f"metrics equal: {out['metrics_equal']}; PLYs equal: {out['ply_equal']}; dvc.lock equal: {out['lock_equal']} "
          f"({len(out['lock_differences'])} of {out['lock_entries']} entries differ)")
    if out["lock_differences_plain_vs_plain"] is not None:
        beyond = out["lock_differences_beyond_plain_vs_plain"]
        print(f"  two plain runs differ in {len(out['lock_differences_plain_vs_plain'])} entries; cluster vs plain "
              f"differs beyond those in {len(beyond)}" + (": " + ", ".join(beyond) if beyond else ""))
    for k in out["lock_differences"][:40]:
        print(f"  dvc.lock {k}")
    for d in out["differences"][:1]:
        for k, (va, vb) in list(d["metrics"].items())[:20]:
            print(f"  {k}: plain {va} / cluster {vb}")
    if a.json:
        write_record(a.json, out, argv)
        print(f"wrote {a.json}")
    return out


if __name__ == "__main__":
    main()
