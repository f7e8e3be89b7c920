"""Wall time, core use and peak memory of every pipeline stage, from a clean copy of this repository.

    python -m eval run pipeline                           # the default params (tiny scene)
    python -m eval run pipeline --set fit.iterations=300 --json out/bench/pipeline_tiny.json
    python -m eval run pipeline --params my_params.yaml   # e.g. a real scene × paintings (absolute paths)
    python -m eval run pipeline --targets fit@tiny        # one stage and what it needs
    python -m eval run pipeline --compare before.json after.json   # two runs' JSON side by side, no run
    python -m eval run pipeline --compare ab.json --paintings 3   # a --baseline run, projected to 3 paintings
    python -m eval run pipeline --baseline 0a3aad0 --baseline-params old.yaml --params new.yaml --json ba.json

How it measures: the working tree is copied into a fresh git + DVC repository (``eval/bench/repo_copy.py``: no
outputs, empty cache, as a clean clone after ``make install``: the C++ extension is built, or loaded, before
anything is timed), ``--params`` replaces its ``params.yaml`` and ``--set`` changes keys in it. ``dvc dag`` gives the stages in an order that respects their edges; then each stage runs alone
(``dvc repro --single-item <stage>``) inside a fresh Python wrapper process that reports, from
``getrusage(RUSAGE_CHILDREN)``, the CPU seconds (user + system) of the stage's processes and their peak
resident set size. Per stage it prints wall seconds, CPU seconds / wall (core use: 1.0 = one core busy) and
peak RSS, then the totals (peak = the largest stage's), and writes everything to ``--json`` with the machine
(``os.cpu_count()``, load average before the run) so that figures from different days can be compared. Run on
an idle machine for figures you quote: other work shows up as lower core use and longer walls.

Before/after: ``--baseline REV`` copies that git revision as a second clean repository (``git archive``; its
params from ``--baseline-params``, since an older revision may read another schema) and runs both pipelines'
stages interleaved — one stage of each in turn, which goes first alternating — so that a change of the
machine's speed during the hours this takes reaches both runs alike. This machine's speed does drift: on
2026-11-25 the same stages' code ran 1.3–1.9× slower an hour apart, and a before run and an after run made one
after the other could not be compared. Both copies build their C++ extension before anything is timed.
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
from dataclasses import dataclass
from pathlib import Path

import yaml

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs.dotted import set_dotted
from eval.bench.repo_copy import copy_repo, copy_revision, run_in
from eval.record import bench_parser, write_record

ROOT = Path(__file__).resolve().parents[2]

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


SIMD_FLAGS = ("avx2", "fma", "avx512f", "avx512_bf16", "amx_bf16")
"""CPU flags that change the figures: torch's kernels, which kernel variant loads (abcgs/render/kernel_variants.py) and
the bf16 search."""


def cpu_description() -> dict:
    """The CPU's model name and which of :data:`SIMD_FLAGS` it has (``/proc/cpuinfo``; empty elsewhere)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return {}
    model = re.search(r"^model name\s*:\s*(.+)$", text, re.M)
    flags = re.search(r"^flags\s*:\s*(.+)$", text, re.M)
    have = set(flags.group(1).split()) if flags else set()
    return {"model": model.group(1).strip() if model else None, "simd": [f for f in SIMD_FLAGS if f in have]}


def run_stage(repo: Path, name: str, label: str = "") -> dict:
    """Run one stage alone in ``repo`` (``dvc repro --single-item``) in a fresh wrapper process; print and return
    its wall seconds, CPU seconds, core use and peak RSS."""
    proc = run_in([sys.executable, "-c", WRAPPER, "dvc", "repro", "--single-item", name], repo, timeout=None)
    rec = json.loads(proc.stdout.strip().splitlines()[-1])
    if rec["rc"] != 0:
        raise RuntimeError(f"stage {name} failed{f' ({label})' if label else ''}:\n{rec['tail']}")
    rec.pop("tail")
    rec["stage"] = name
    rec["core_use"] = rec["cpu_s"] / max(rec["wall_s"], 1e-9)
    print(f"  {label}{name:34s} {rec['wall_s']:8.1f} s  cpu/wall {rec['core_use']:4.2f}  "
          f"peak RSS {rec['peak_rss_mib']:7.0f} MiB", flush=True)
    return rec


def bench(repo: Path, stages: list[str], on_stage=None) -> list[dict]:
    """Every stage in turn; ``on_stage(rows)`` after each (e.g. to save the stages measured so far)."""
    rows: list[dict] = []
    for name in stages:
        rows.append(run_stage(repo, name))
        if on_stage is not None:
            on_stage(rows)
    return rows


def warm_up(repo: Path) -> None:
    """Make the copy's C++ kernels loadable before anything is timed, as in an installed checkout: a copy whose
    ``csrc/`` equals the installed kernels' sources loads those; another revision's sources are built in place
    (``setup.py build_ext --inplace``), or, for a revision whose kernels compile at first use, on this import."""
    load = [sys.executable, "-c", "import abcgs.render.cpu as c; c.load_extension()"]
    if run_in(load, repo, timeout=1800).returncode != 0 and (repo / "setup.py").is_file():
        run_in([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], repo, timeout=1800)
        run_in(load, repo, timeout=60)


def bench_interleaved(base: Path, base_stages: list[str], cur: Path, cur_stages: list[str],
                      on_stage=None) -> tuple[list, list]:
    """Both pipelines' stages in lockstep, the order alternating (baseline, current), (current, baseline), …, so
    that a machine whose speed drifts during the hours this takes slows both runs alike. ``on_stage(rows_b,
    rows_c)`` after each stage (e.g. to save what is measured so far: a run of hours may be cut off)."""
    rows_b: list[dict] = []
    rows_c: list[dict] = []
    for i in range(max(len(base_stages), len(cur_stages))):
        pair = [(base, base_stages, rows_b, "baseline "), (cur, cur_stages, rows_c, "current  ")]
        for repo, stages, rows, label in pair if i % 2 == 0 else pair[::-1]:
            if i < len(stages):
                rows.append(run_stage(repo, stages[i], label))
                if on_stage is not None:
                    on_stage(rows_b, rows_c)
    return rows_b, rows_c


def summary(rows: list[dict], wall: float | None = None) -> dict:
    """A run's stage rows with their totals: wall seconds (their sum, or ``wall`` when given), CPU seconds, core use
    and the peak resident memory (0 before any stage ended)."""
    total_wall = sum(r["wall_s"] for r in rows) if wall is None else wall
    total_cpu = sum(r["cpu_s"] for r in rows)
    return {"stages": rows, "total_wall_s": total_wall, "total_cpu_s": total_cpu,
            "core_use": total_cpu / max(total_wall, 1e-9),
            "peak_rss_mib": max((r["peak_rss_mib"] for r in rows), default=0.0)}


def compare(before: dict, after: dict) -> dict:
    """Two runs' figures side by side, by stage kind (``fit``, ``stylize``, … the part of a stage name before
    ``@``, summed over its instances: a per-scene stage and per-experiment copies compare as one line), with the
    ratio ``before / after`` of each kind's wall seconds and of the totals. Printed, and returned as a dict."""

    def by_kind(run: dict) -> dict[str, dict]:
        kinds: dict[str, dict] = {}
        for r in run["stages"]:
            k = kinds.setdefault(r["stage"].split("@")[0], {"wall_s": 0.0, "cpu_s": 0.0, "n": 0, "peak_rss_mib": 0.0})
            k["wall_s"] += r["wall_s"]
            k["cpu_s"] += r["cpu_s"]
            k["n"] += 1
            k["peak_rss_mib"] = max(k["peak_rss_mib"], r["peak_rss_mib"])
        return kinds

    a, b = by_kind(before), by_kind(after)
    rows = []
    print(f"{'stage kind':14s} {'before s':>9s} {'n':>3s} {'after s':>9s} {'n':>3s} {'ratio':>6s}")
    for kind in list(a) + [k for k in b if k not in a]:
        wa, wb = a.get(kind, {}).get("wall_s"), b.get(kind, {}).get("wall_s")
        ratio = wa / wb if wa and wb else None
        rows.append({"kind": kind, "before_s": wa, "after_s": wb, "before_n": a.get(kind, {}).get("n", 0),
                     "after_n": b.get(kind, {}).get("n", 0), "ratio": ratio})
        fmt = lambda v: f"{v:9.1f}" if v is not None else f"{'-':>9s}"  # noqa: E731
        print(f"{kind:14s} {fmt(wa)} {rows[-1]['before_n']:3d} {fmt(wb)} {rows[-1]['after_n']:3d} "
              f"{(f'{ratio:6.2f}' if ratio else '     -')}")
    total = before["total_wall_s"] / after["total_wall_s"]
    print(f"{'total':14s} {before['total_wall_s']:9.1f}     {after['total_wall_s']:9.1f}     {total:6.2f}"
          f"   ({before['total_wall_s'] / 60:.1f} → {after['total_wall_s'] / 60:.1f} min; peak RSS "
          f"{before['peak_rss_mib']:.0f} → {after['peak_rss_mib']:.0f} MiB)")
    return {"kinds": rows, "total_ratio": total, "before_total_s": before["total_wall_s"],
            "after_total_s": after["total_wall_s"]}


#: Stage kinds that a painting brings (its colour match(es), and per method a stylization, an evaluation and an
#: export); the others (make_tiny, reconstruct, fit, masks, reference, export_scene, report) run once per scene.
PER_PAINTING_KINDS = ("colormatch", "stylize", "evaluate", "export")


def project_paintings(before: dict, after: dict, paintings: int, measured: int = 1) -> dict:
    """The totals of ``before`` and ``after`` projected from ``measured`` paintings to ``paintings``: the
    per-scene stages as measured, the per-painting kinds (:data:`PER_PAINTING_KINDS`) scaled by
    ``paintings / measured``. An extrapolation from measured stages (it assumes every painting costs what the
    measured ones did), printed and returned as such."""
    if paintings < 1 or measured < 1:
        raise SystemExit(f"--paintings and --measured-paintings must be >= 1 (got {paintings}, {measured})")
    out = {}
    for name, run in (("before", before), ("after", after)):
        per_painting = sum(r["wall_s"] for r in run["stages"] if r["stage"].split("@")[0] in PER_PAINTING_KINDS)
        per_scene = sum(r["wall_s"] for r in run["stages"]) - per_painting
        out[name] = {"per_scene_s": per_scene, "per_painting_s": per_painting / measured,
                     "projected_s": per_scene + per_painting * paintings / measured}
    out["ratio"] = out["before"]["projected_s"] / out["after"]["projected_s"]
    out["paintings"], out["measured_paintings"] = paintings, measured
    print(f"projected to {paintings} painting(s) from {measured} measured (per-scene stages once, "
          f"{'/'.join(PER_PAINTING_KINDS)} × {paintings}/{measured}; an extrapolation):")
    for name in ("before", "after"):
        o = out[name]
        print(f"  {name:6s} per scene {o['per_scene_s']:8.1f} s + per painting {o['per_painting_s']:8.1f} s "
              f"→ {o['projected_s']:8.1f} s ({o['projected_s'] / 60:.1f} min)")
    print(f"  ratio before / after {out['ratio']:.2f}")
    return out


def _read_runs(paths: list[Path]) -> tuple[dict, dict]:
    """(before, after) from two single-run JSONs, or from one ``--baseline`` run's JSON (baseline, current)."""
    runs = []
    for path in paths:
        try:
            runs.append(json.loads(path.read_text()))
        except (OSError, ValueError) as exc:
            raise SystemExit(f"--compare: cannot read {path} as a bench_pipeline JSON ({exc})") from exc
    if len(runs) == 1:
        if not {"baseline", "current"} <= set(runs[0]):
            raise SystemExit(f"--compare: {paths[0]} is not a --baseline run's JSON (no 'baseline' / 'current'); "
                             "give two runs' JSON files instead")
        complete = runs[0].get("complete")
        runs = [{**runs[0]["baseline"], "complete": complete}, {**runs[0]["current"], "complete": complete}]
    sources = [paths[0]] * 2 if len(paths) == 1 else paths
    for path, run in zip(sources, runs):
        if "stages" not in run or "total_wall_s" not in run:
            raise SystemExit(f"--compare: {path} is not a bench_pipeline JSON (no 'stages' / 'total_wall_s')")
        if run.get("complete") is False:  # saved after each stage of a run that did not finish
            print(f"[bench_pipeline] {path}: an unfinished run, {len(run['stages'])} of {run.get('stage_count', '?')} "
                  "stages measured; its totals are the measured stages' only")
    return runs[0], runs[1]


def params_editor(params_file: Path | None, sets: list[str]):
    """An ``edit_params`` for :func:`eval.bench.repo_copy.copy_repo`: replace ``params.yaml`` by ``params_file`` (when
    given), then apply the ``KEY=VALUE`` changes (YAML values) of ``sets``."""

    def edit(params: dict) -> None:
        if params_file is not None:
            params.clear()
            params.update(yaml.safe_load(params_file.read_text()))
        for item in sets:
            key, _, value = item.partition("=")
            set_dotted(params, key, yaml.safe_load(value))

    return edit


def _parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = bench_parser(__doc__)
    ap.add_argument("--params", type=Path, default=None, help="params file to run (default: this repository's)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="change a key (YAML value)")
    ap.add_argument("--targets", nargs="*", default=None, help="only these stages and the ones they need")
    ap.add_argument("--work", type=Path, default=None, help="where the copy goes (default: a temporary folder)")
    ap.add_argument("--baseline", default=None, metavar="REV",
                    help="also run this git revision's pipeline, its stages interleaved with the working tree's "
                    "(a before/after comparison that machine-speed drift affects alike)")
    ap.add_argument("--baseline-params", type=Path, default=None,
                    help="params file for the baseline (default: --params; an older revision may need its own schema)")
    ap.add_argument("--compare", nargs="+", type=Path, default=None, metavar="JSON",
                    help="print two earlier runs' JSON (BEFORE AFTER), or one --baseline run's JSON, side by side "
                    "(per stage kind and total) instead of running")
    ap.add_argument("--paintings", type=int, default=None, metavar="K",
                    help="with --compare: also project both totals to K paintings (per-scene stages once, "
                    "per-painting stages scaled)")
    ap.add_argument("--measured-paintings", type=int, default=1, metavar="M",
                    help="with --paintings: how many paintings the compared runs had (default 1)")
    return ap


HOW = ("each stage alone (dvc repro --single-item) in a fresh wrapper process; CPU and peak RSS from "
       "getrusage(RUSAGE_CHILDREN); a clean copy of the working tree with an empty DVC cache")
"""How the figures are measured, stored with them."""


@dataclass
class PipelineCopy:
    """A clean copy of a pipeline to time: its folder, its stages in run order, the params file it was given (None:
    the repository's ``params.yaml``) and the ``--set`` changes made to it."""

    repo: Path
    stages: list[str]
    params: Path | None
    sets: list[str]


def compare_files(paths: list[Path], paintings: int | None, measured: int) -> dict:
    """``--compare``: two runs' JSON files (or one ``--baseline`` run's) side by side, and with ``paintings`` both
    totals projected to that many paintings from ``measured``."""
    if len(paths) > 2:
        raise SystemExit("--compare takes BEFORE AFTER, or one --baseline run's JSON")
    before, after = _read_runs(paths)
    result = compare(before, after)
    if paintings is not None:
        result["projection"] = project_paintings(before, after, paintings, measured)
    return result


def time_against_baseline(base: PipelineCopy, revision: str, current: PipelineCopy, machine: dict,
                          json_path: Path | None, argv: list[str] | None = None) -> dict:
    """Both copies' stages interleaved (:func:`bench_interleaved`); the record is saved to ``json_path`` after each
    stage (``complete: false``) and at the end with the comparison of the two, with the provenance of the command line
    ``argv``."""
    machine["loadavg_before"] = os.getloadavg()
    print(f"[bench_pipeline] baseline {revision} ({len(base.stages)} stages, {base.repo}) and the working "
          f"tree ({len(current.stages)} stages, {current.repo}) interleaved; {os.cpu_count()} CPUs, load average "
          f"{machine['loadavg_before'][0]:.2f}", flush=True)

    def ab_result(rows_b: list[dict], rows_c: list[dict], complete: bool) -> dict:
        return {
            "baseline": {**summary(rows_b), "revision": revision, "params": str(base.params or "params.yaml"),
                         "stage_count": len(base.stages)},
            "current": {**summary(rows_c), "params": str(current.params or "params.yaml"), "set": current.sets,
                        "stage_count": len(current.stages)},
            "machine": machine, "complete": complete,
            "how": HOW + "; the two pipelines' stages alternate (baseline first on even steps, current first "
                         "on odd ones) and each total is the sum of its stages' walls",
        }

    def save_partial(rows_b: list[dict], rows_c: list[dict]) -> None:
        if json_path:
            write_record(json_path, ab_result(rows_b, rows_c, complete=False), argv)

    rows_b, rows_c = bench_interleaved(base.repo, base.stages, current.repo, current.stages, on_stage=save_partial)
    result = ab_result(rows_b, rows_c, complete=True)
    result["comparison"] = compare(result["baseline"], result["current"])
    if json_path:
        write_record(json_path, result, argv)
    return result


def time_alone(current: PipelineCopy, machine: dict, json_path: Path | None, argv: list[str] | None = None) -> dict:
    """The copy's stages in turn (:func:`bench`); the record is saved to ``json_path`` after each stage
    (``complete: false``) and at the end, with the total wall time and the provenance of the command line ``argv``."""
    machine["loadavg_before"] = os.getloadavg()
    print(f"[bench_pipeline] {len(current.stages)} stages in {current.repo}; {os.cpu_count()} CPUs, load average "
          f"{machine['loadavg_before'][0]:.2f}", flush=True)
    t0 = time.perf_counter()

    def record(rows: list[dict], complete: bool, wall: float | None = None) -> dict:
        return {**summary(rows, wall), "params": str(current.params or "params.yaml"), "set": current.sets,
                "machine": machine, "how": HOW, "complete": complete, "stage_count": len(current.stages)}

    def save_partial(rows: list[dict]) -> None:
        if json_path:
            write_record(json_path, record(rows, complete=False), argv)

    rows = bench(current.repo, current.stages, on_stage=save_partial)
    total_wall = time.perf_counter() - t0
    result = record(rows, complete=True, wall=total_wall)
    print(f"[bench_pipeline] total {total_wall / 60:.1f} min wall, cpu/wall {result['core_use']:.2f}, "
          f"peak RSS {result['peak_rss_mib']:.0f} MiB")
    if json_path:
        write_record(json_path, result, argv)
    return result


def main(argv: list[str] | None = None) -> dict:
    args = _parser().parse_args(argv)
    if args.compare is not None:
        return compare_files(args.compare, args.paintings, args.measured_paintings)
    if args.paintings is not None:
        raise SystemExit("--paintings projects earlier runs: use it with --compare")

    machine = {"cpus": os.cpu_count(), "cpu": cpu_description(), "platform": platform.platform()}
    print(f"[bench_pipeline] CPU {machine['cpu'].get('model')} ({', '.join(machine['cpu'].get('simd', []))})",
          flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        repo = copy_repo(work / "repo", params_editor(args.params, args.set))
        current = PipelineCopy(repo, stage_order(repo, args.targets), args.params, args.set)
        warm_up(repo)
        if args.baseline is None:
            return time_alone(current, machine, args.json, argv)
        base_params = args.baseline_params or args.params
        # the same --set changes to both runs
        base_repo = copy_revision(work / "baseline", args.baseline, params_editor(base_params, args.set))
        base = PipelineCopy(base_repo, stage_order(base_repo, args.targets), base_params, args.set)
        warm_up(base_repo)
        return time_against_baseline(base, args.baseline, current, machine, args.json, argv)

if __name__ == "__main__":
    main()
