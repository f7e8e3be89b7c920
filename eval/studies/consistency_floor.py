"""How much of a warp-error consistency number is the measurement: optical flow vs the scene's own geometry.

    python -m eval run consistency_floor --colmap out/bench/fern/colmap --scene-ply out/bench/fern/gs/point_cloud.ply \\
        --ply fast=out/quality/fern/runs/starry_night__fast-*/point_cloud.ply [--ply name=path ...] [--json out.json]

For the fitted (unstylized) scene and each given stylized PLY, renders every view and prints the short/long
masked warp RMSE twice: with the evaluation's optical flow (``--flow``, default DIS, computed on the
unstylized renders exactly as ``evaluate`` does, over the same pairs: ``--pairs``, default ``pose``,
:mod:`abcgs.evaluation.pairs`) and with correspondences from the unstylized scene's rendered depth and the camera
poses (:func:`abcgs.evaluation.consistency.depth_correspondence`, occlusion by a depth test, alpha > 0.95). The
unstylized scene's row is the floor of each measurement: everything it scores is flow error (or depth blur at
edges), not inconsistency. Its flow columns are the library's floor (:func:`abcgs.evaluation.reference.compute_floor`,
what the ``reference`` stage stores and ``evaluate`` reports as ``short_rmse_floor``/``long_rmse_floor``). A
stylized scene's excess over that row is what the stylization costs. Diagnostic only; the headline metric stays
the flow-based one the paper defines.
"""

from __future__ import annotations

import glob
import time
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs.errors import InputError
from abcgs.evaluation.consistency import (
    FlowCache,
    consistency,
    depth_correspondence,
    make_flow_estimator,
    warp_error,
)
from abcgs.evaluation.pairs import consistency_pairs
from abcgs.evaluation.reference import compute_floor, render_views
from abcgs.gaussians import render
from abcgs.gaussians.ply import read_ply
from abcgs.sfm.model import read_scene
from eval.record import bench_parser, write_record


def _resolve(spec: str) -> tuple[str, Path]:
    name, sep, pattern = spec.partition("=")
    if not sep:
        raise InputError(f"--ply expects name=path, got {spec!r}")
    hits = sorted(glob.glob(pattern))
    if len(hits) != 1:
        raise InputError(f"--ply {name}: {pattern!r} matches {len(hits)} files; give exactly one")
    return name, Path(hits[0])


def depth_rmse(stylized: list[np.ndarray], corr: dict, pairs: list[tuple[int, int]]) -> float:
    errs = [warp_error(i, j, stylized, *corr[(i, j)], None).rmse for i, j in pairs]
    return float(np.nanmean(errs))


def main(argv=None) -> dict:
    ap = bench_parser(__doc__)
    ap.add_argument("--colmap", type=Path, required=True, help="reconstruct output (sparse/, images/, scene.json)")
    ap.add_argument("--scene-ply", type=Path, required=True, help="the fitted, unstylized scene")
    ap.add_argument("--ply", action="append", default=[], metavar="NAME=PATH", help="a scene to measure (glob ok)")
    ap.add_argument("--gaps", default="1,7", help="short,long view gaps (as evaluate.short_term_gap/long_term_gap)")
    ap.add_argument("--pairs", default="pose", choices=("pose", "index"), help="view order before pairing (as evaluate.pairs)")
    ap.add_argument("--flow", default="dis", help="flow method (auto | raft | dis | deepflow | dualtvl1)")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    measured = [("unstylized scene (floor)", args.scene_ply)] + [_resolve(s) for s in args.ply]  # fail before work
    t0 = time.perf_counter()
    scene = read_scene(args.colmap)
    cams = scene.cameras
    base = read_ply(args.scene_ply)
    gaps = [int(g) for g in args.gaps.split(",")]
    pairs = consistency_pairs(cams, args.pairs, *gaps)
    kinds = ("short", "long")
    depths, alphas, originals = [], [], []
    with torch.no_grad():
        for c in cams:
            img, alpha, meta = render(base, c, render_mode="RGB+ED")
            originals.append(img.clamp(0, 1).numpy())
            depths.append(meta.depth[..., 0].numpy())
            alphas.append(alpha[..., 0].numpy())
    corr = {}
    for kind in kinds:
        for i, j in pairs.of(kind):
            corr[(i, j)] = depth_correspondence(depths[i], depths[j], cams[i].K, cams[i].viewmat, cams[j].K,
                                                cams[j].viewmat, valid_i=alphas[i] > 0.95)
    estimator = make_flow_estimator(args.flow)
    flows = FlowCache(originals, estimator)
    floor = compute_floor(originals, pairs, flows)
    rows = []
    for k, (name, path) in enumerate(measured):
        styled = originals if k == 0 else render_views(read_ply(path), cams, "auto")[0]
        row = {"name": name, "ply": str(path)}
        for kind in kinds:
            row[f"{kind}_rmse_flow"] = (floor.of(kind).rmse if k == 0 else
                                        consistency(originals, styled, pairs.of(kind), flows, None).rmse)
            row[f"{kind}_rmse_depth"] = depth_rmse(styled, corr, pairs.of(kind))
        rows.append(row)
        print(f"{name:34s} flow short/long {row['short_rmse_flow']:.4f}/{row['long_rmse_flow']:.4f}   "
              f"depth short/long {row['short_rmse_depth']:.4f}/{row['long_rmse_depth']:.4f}", flush=True)
    valid = {kind: float(np.mean([corr[p][1].mean() for p in pairs.of(kind)])) for kind in kinds}
    flow_valid = {kind: floor.of(kind).valid_fraction for kind in kinds}
    out = {"rows": rows, "gaps": [pairs.short_gap, pairs.long_gap], "pairs": pairs.to_json(),
           "flow": estimator.provenance(), "n_views": len(cams), "depth_valid_fraction": valid,
           "flow_valid_fraction": flow_valid, "seconds": time.perf_counter() - t0,
           "how": "masked warp RMSE (images in [0, 1]); flow as evaluate computes it on the unstylized renders; depth: "
                  "the unstylized scene's normalised expected depth, alpha > 0.95, 2 % occlusion tolerance"}
    print(f"{len(cams)} views, {args.pairs} pairs, gaps {out['gaps']}, flow {estimator.provenance()['implementation']}, "
          f"valid fraction flow {flow_valid['short']:.2f}/{flow_valid['long']:.2f}, depth "
          f"{valid['short']:.2f}/{valid['long']:.2f}; {out['seconds']:.0f} s")
    if args.json:
        write_record(args.json, out, argv)
    return out


if __name__ == "__main__":
    main()
