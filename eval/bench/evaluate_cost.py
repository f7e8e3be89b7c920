"""Evaluation cost beside the stylization's: the evaluate stage's parts in wall and CPU seconds, and the ratio of the
evaluation to the stylization, for one experiment's outputs.

    python -m eval run evaluate_cost --experiment tiny_single
    python -m eval run evaluate_cost --experiment fern_starry_night_fast --out out --json out/bench/evaluate_cost.json

Runs nothing: reads what the stages already wrote, ``out/E/eval_info.json`` (``eval_timings_s``: the renders, the
render-speed passes, content, consistency, FID/KID, Gram and the whole evaluation, wall and CPU seconds of the
process, :mod:`abcgs.evaluation.record`) and ``out/E/stylize_info.json`` (``stylize_seconds``, wall). Prints one row
per part with its share of the stylization's seconds, then the ratio evaluation / stylization against ``--target``.

The CPU seconds say how much of the machine a part had (cores = CPU / wall): on a machine others share, both stages'
wall seconds grow with the others' load, and a ratio of two wall times measured under different loads says more about
the load than about the stages. The stylize record holds wall seconds only. Records written before the evaluation
recorded CPU seconds and its total show ``-`` there, and the total is the sum of the parts.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
from abcgs import layout
from abcgs.errors import InputError
from abcgs.io.metrics import info_path
from eval.record import bench_parser, write_record

PARTS = (("render", "render_s"), ("speed passes", "speed_s"), ("content", "content_s"),
         ("consistency", "consistency_s"), ("fid_kid", "fid_s"), ("gram", "gram_s"), ("objects", "objects_s"))
"""Row name → the wall-seconds key of ``eval_timings_s`` (its CPU key: ``*_cpu_s``)."""


def _read(path: Path, stage: str, experiment: str) -> dict:
    if not path.is_file():
        raise InputError(f"{path} is missing: run dvc repro {stage}@{experiment} first")
    return json.loads(path.read_text(encoding="utf-8"))


def cost(eval_info: dict, stylize_info: dict, target: float = 0.5) -> dict:
    """The record of :func:`main`: per part ``{"wall_s", "cpu_s"}`` (None where not recorded), the evaluation's
    total, the stylization's seconds and their ratio."""
    t = eval_info.get("eval_timings_s") or {}
    if not t:
        raise InputError("the evaluation record has no eval_timings_s")
    parts = {}
    for name, key in PARTS:
        if key == "speed_s" and key not in t and eval_info.get("speed", {}).get("fps_passes_s"):
            t = {**t, key: sum(eval_info["speed"]["fps_passes_s"])}  # an older record: the passes' own times
        if key in t:
            parts[name] = {"wall_s": float(t[key]), "cpu_s": t.get(f"{key.removesuffix('_s')}_cpu_s")}
    summed = sum(p["wall_s"] for p in parts.values())
    total = {"wall_s": float(t.get("total_s", summed)), "cpu_s": t.get("total_cpu_s")}
    if "total_s" in t:
        rest = total["wall_s"] - summed
        rest_cpu = None if total["cpu_s"] is None or any(p["cpu_s"] is None for p in parts.values()) else (
            total["cpu_s"] - sum(p["cpu_s"] for p in parts.values()))
        parts["other"] = {"wall_s": rest, "cpu_s": rest_cpu}
    stylize_s = stylize_info.get("stylize_seconds")
    if not stylize_s:
        raise InputError("the stylize record has no stylize_seconds")
    ratio = total["wall_s"] / float(stylize_s)
    return {"stylize_s": float(stylize_s), "parts": parts, "evaluation": total, "ratio": ratio, "target": target,
            "met": ratio <= target}


def table(experiment: str, rec: dict) -> str:
    """The printed report of :func:`cost`'s record."""
    def num(v, fmt="8.2f"):
        return f"{v:{fmt}}" if v is not None else f"{'-':>{fmt.split('.')[0]}}"

    def row(name, p):
        cores = p["cpu_s"] / p["wall_s"] if p["cpu_s"] is not None and p["wall_s"] > 0 else None
        return (f"{name:<18} {num(p['wall_s'])} {num(p['cpu_s'])} {num(cores, '6.2f')} "
                f"{num(p['wall_s'] / rec['stylize_s'], '10.3f')}")

    lines = [f"experiment {experiment}: stylization {rec['stylize_s']:.1f} s (stylize_seconds, wall)",
             f"{'part':<18} {'wall s':>8} {'cpu s':>8} {'cores':>6} {'/ stylize':>10}"]
    lines += [row(name, p) for name, p in rec["parts"].items()]
    lines.append(row("evaluation", rec["evaluation"]))
    lines.append(f"evaluation / stylization = {rec['ratio']:.3f} (target <= {rec['target']}: "
                 f"{'met' if rec['met'] else 'NOT met'})")
    return "\n".join(lines)


def _parser():
    ap = bench_parser(__doc__)
    ap.add_argument("--experiment", required=True, help="a key of params.yaml's experiments (its out/ folder)")
    ap.add_argument("--out", type=Path, default=layout.OUT, help="the pipeline's output folder (default: out)")
    ap.add_argument("--target", type=float, default=0.5, help="the largest evaluation / stylization ratio wanted")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    e = layout.experiment(args.experiment, args.out)
    try:
        rec = cost(_read(info_path(e.eval_record), "evaluate", args.experiment),
                   _read(info_path(e.stylize_record), "stylize", args.experiment), args.target)
    except InputError as exc:
        print(f"evaluate_cost: {exc}", file=sys.stderr)
        return 2
    print(table(args.experiment, rec))
    if args.json:
        write_record(args.json, {"experiment": args.experiment, **rec}, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
