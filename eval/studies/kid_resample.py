"""How stable is the KID proxy: re-measure it with more patches and several patch draws.

    python -m eval run kid_resample [--params params.yaml] [--root out] [--patches-per-image 10] [--draws 5]

The evaluate stage's KID proxy (TF-Inception pool features of random 96-px crops: ``fid_patches_per_image`` = 2
crops per render, as many from the painting) compares 40 crops with 40 on fern's 20 views — one draw of the crops.
This script reads the experiments of a pipeline run (``params.yaml`` and the stylize stage's saved renders in
``out/<experiment>/stylize/renders``; for a DVC experiment, check it out first, e.g. with
``python -m eval run experiment show``'s worktree or ``dvc exp apply``), groups the single-painting experiments
by colour match, and for ``--draws`` independent crop draws (``--patches-per-image`` crops per render, as many from
the painting) computes KID (unbiased MMD², the exact estimate over all crops) of every method. It prints, per
colour match and method, the mean ± std over draws and how often each method wins within a draw, so a difference
between two methods can be read against the spread of the measurement itself. Writes ``--json``.
"""

from __future__ import annotations

import time
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs.errors import InputError
from abcgs.evaluation.fid import TFInception, mmd2_unbiased, random_patches, resize_short_side
from abcgs.features.matching import load_style
from abcgs.io.images import load_image
from abcgs.params import load_params
from eval.record import bench_parser, write_record


def main(argv=None) -> dict:
    ap = bench_parser(__doc__, json_help="write the record here (default: out/bench/kid_resample.json)")
    ap.set_defaults(json=Path("out/bench/kid_resample.json"))
    ap.add_argument("--params", type=Path, default=Path("params.yaml"))
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--patches-per-image", type=int, default=10)
    ap.add_argument("--patch-size", type=int, default=96)
    ap.add_argument("--draws", type=int, default=5)
    ap.add_argument("--methods", default="fast,nnfm", help="methods to compare")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    params = load_params(args.params)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    by_match: dict[str, dict[str, str]] = {}
    for name, exp in params.experiments.items():
        if exp.method in methods and params.colormatches[exp.colormatch].transfer == "single":
            by_match.setdefault(exp.colormatch, {})[exp.method] = name
    inception = TFInception()
    t0 = time.perf_counter()
    out: dict = {"patches_per_image": args.patches_per_image, "patch_size": args.patch_size, "draws": args.draws,
                 "colormatches": {}}
    for match, runs in by_match.items():
        if len(runs) < 2:
            continue
        renders = {}
        for m, name in runs.items():
            pngs = sorted((args.root / name / "stylize" / "renders").glob("*.png"))
            if not pngs:
                raise InputError(f"{args.root / name / 'stylize' / 'renders'} holds no renders: run dvc repro first")
            renders[m] = [load_image(p) for p in pngs]
        h, w = next(iter(renders.values()))[0].shape[:2]
        painting = [resize_short_side(load_style(params.data.styles[params.colormatches[match].style], 0), min(h, w))]
        n = len(next(iter(renders.values()))) * args.patches_per_image
        kids: dict[str, list[float]] = {m: [] for m in runs}
        for d in range(args.draws):
            f_s = inception.features(random_patches(painting, n, args.patch_size, np.random.default_rng([d, 2])))
            for m in runs:
                f_r = inception.features(random_patches(renders[m], n, args.patch_size, np.random.default_rng([d, 1])))
                kids[m].append(mmd2_unbiased(f_s, f_r))
        wins = {m: int(sum(kids[m][d] == min(kids[k][d] for k in runs) for d in range(args.draws))) for m in runs}
        out["colormatches"][match] = {m: {"kid_mean": float(np.mean(v)), "kid_std": float(np.std(v)), "kids": v,
                                          "wins": wins[m]} for m, v in kids.items()}
        line = "  ".join(f"{m} {np.mean(v):.4f} ± {np.std(v):.4f} (wins {wins[m]}/{args.draws})" for m, v in kids.items())
        print(f"{match:24s} {line}", flush=True)
    out["seconds"] = time.perf_counter() - t0
    out["how"] = (f"{args.patches_per_image} crops of {args.patch_size} px per render and as many from the painting, "
                  f"{args.draws} independent draws, exact unbiased MMD² on TF-Inception pool features ({inception.path})")
    print(f"{out['how']}; {out['seconds']:.0f} s")
    write_record(args.json, out, argv)
    return out


if __name__ == "__main__":
    main()
