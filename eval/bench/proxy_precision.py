"""The perceptual proxy in float32 and in bfloat16 on one experiment's renders: time and how far the distances move.

    python -m eval run proxy_precision --experiment tiny_single [--out out] [--views 8] [--json PATH]

Reads what the stages wrote: the scene's evaluation reference (``out/S/reference``: the original renders, the flows
and the pairs' occlusion masks) and the experiment's stylized renders (``out/E/stylize/renders``). Computes the
``lpips_proxy_vgg`` distances the evaluation computes, with the project's VGG-16: content (original against stylized,
the first ``--views`` views) and consistency (stylized view ``j`` warped into ``i`` against ``i``, masked; the first
``--views`` stored pairs), once with ``evaluate.proxy_precision: float32`` and once with ``bfloat16``, on the evaluation's
threads (``params.yaml``'s ``evaluate.num_threads`` and ``workers``). Prints per part the seconds of each, their ratio,
the largest change of a distance against :data:`abcgs.evaluation.content.PROXY_BF16_TOLERANCE`, and the change of the
mean; exits 1 when a change is over it.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs import layout
from abcgs.errors import InputError
from abcgs.evaluation.consistency import FlowCache, consistency
from abcgs.evaluation.content import PROXY_BF16_TOLERANCE, PerceptualDistance
from abcgs.evaluation.evaluate import load_stylize_run
from abcgs.evaluation.parallel import resolve_workers
from abcgs.evaluation.reference import load_reference
from abcgs.features.weights import resolve_vgg16
from abcgs.io.images import load_image
from abcgs.io.metrics import info_path
from abcgs.params import load_params
from abcgs.sfm.model import read_scene
from eval.record import bench_parser, write_record

PRECISIONS = ("float32", "bfloat16")


def load_views(out: Path, experiment: str, scene: str, params) -> tuple[list, list, FlowCache, list]:
    """The original renders, the stored flows and masks and the pairs of the scene's reference
    (:func:`abcgs.evaluation.reference.load_reference`, which checks them), and the stylized renders in its view order
    (:func:`abcgs.evaluation.evaluate.load_stylize_run`)."""
    s, e = layout.scene(scene, out), layout.experiment(experiment, out)
    cameras = read_scene(s.colmap.root).cameras
    ref = load_reference(s.reference, cameras, params.evaluate, scene=scene)
    stems = [Path(c.name).stem for c in cameras]
    _, _, pngs = load_stylize_run(e.stylize, info_path(e.stylize_record), experiment, stems)
    stylized = [load_image(p) for p in pngs[: len(ref.originals)]]
    flows = FlowCache.precomputed(ref.originals, ref.flows, {}, ref.masks)
    return ref.originals, stylized, flows, [*ref.pairs.short, *ref.pairs.long]


def measure(originals, stylized, flows, pairs, views: int, workers: int) -> dict:
    """Per part (content, consistency): each precision's seconds and distances, the time ratio and the changes."""
    state, info = resolve_vgg16(None)
    nets = {p: PerceptualDistance("proxy", vgg_state=state, vgg_info=info.model_dump(), precision=p) for p in PRECISIONS}
    o, s = originals[:views], stylized[:views]
    jobs = {"content": lambda pd: pd.distances(o, s, workers=workers),
            "consistency": lambda pd: [r.perceptual for r in consistency(
                originals, stylized, pairs[:views], flows, pd, workers=workers).pairs]}
    parts = {}
    for part, job in jobs.items():
        row = {}
        for p, pd in nets.items():
            t = time.perf_counter()
            d = job(pd)
            row[p] = {"seconds": time.perf_counter() - t, "distances": [float(x) for x in d]}
        a, b = np.array(row["float32"]["distances"]), np.array(row["bfloat16"]["distances"])
        change = np.abs(b - a)
        parts[part] = {**row, "speedup": row["float32"]["seconds"] / row["bfloat16"]["seconds"],
                       "max_change": float(change.max()), "max_relative_change": float((change / np.abs(a)).max()),
                       "change_of_mean": float(abs(b.mean() - a.mean())),
                       "within_tolerance": bool(change.max() <= PROXY_BF16_TOLERANCE)}
    return parts


def main(argv: list[str] | None = None) -> int:
    ap = bench_parser(__doc__)
    ap.add_argument("--experiment", required=True, help="a key of params.yaml's experiments (its out/ folder)")
    ap.add_argument("--scene", default=None, help="the experiment's scene (default: params.yaml's)")
    ap.add_argument("--out", type=Path, default=layout.OUT, help="the pipeline's output folder (default: out)")
    ap.add_argument("--views", type=int, default=8, help="views (content) and pairs (consistency) measured")
    args = ap.parse_args(argv)
    try:
        params = load_params()
        scene = args.scene or params.experiments[args.experiment].scene
        originals, stylized, flows, pairs = load_views(args.out, args.experiment, scene, params)
    except (InputError, KeyError) as exc:
        print(f"proxy_precision: {exc}", file=sys.stderr)
        return 2
    if params.evaluate.num_threads is not None:  # the evaluation's threads
        torch.set_num_threads(params.evaluate.num_threads)
    workers = resolve_workers(params.evaluate.workers)
    parts = measure(originals, stylized, flows, pairs, args.views, workers)
    h, w = np.shape(originals[0])[:2]
    print(f"{args.experiment}: {len(originals)} views of {w} x {h}, {workers} workers; tolerance {PROXY_BF16_TOLERANCE}")
    for part, r in parts.items():
        print(f"{part:<12} float32 {r['float32']['seconds']:7.2f} s  bfloat16 {r['bfloat16']['seconds']:7.2f} s  "
              f"x{r['speedup']:.2f}  largest change {r['max_change']:.1e} ({r['max_relative_change']:.1e} of the "
              f"value), of the mean {r['change_of_mean']:.1e}: {'within' if r['within_tolerance'] else 'OUTSIDE'}")
    if args.json:
        write_record(args.json, {"experiment": args.experiment, "scene": scene, "views": len(originals),
                                 "size": [int(h), int(w)], "workers": workers, "tolerance": PROXY_BF16_TOLERANCE,
                                 "parts": parts}, argv)
    return 0 if all(r["within_tolerance"] for r in parts.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
