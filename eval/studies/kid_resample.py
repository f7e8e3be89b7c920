"""How stable is the KID proxy of a quality study: re-measure it with more patches and several patch draws.

    python eval/studies/kid_resample.py --study out/quality/fern [--patches-per-image 10] [--draws 5] [--methods fast,nnfm]

The evaluate stage's KID proxy (TF-Inception pool features of random 96-px crops: ``fid_patches_per_image`` = 2
crops per render, as many from the painting) compares 40 crops with 40 on fern's 20 views — one draw of the crops.
This script reads the study's ``study.json``, renders each listed run's stylized scene for every view, and for
``--draws`` independent crop draws (same crop size, ``--patches-per-image`` crops per render, as many from the
painting) computes KID (unbiased MMD², the exact estimate over all crops). It prints, per painting and method, the
mean ± std over draws and how often each method wins within a draw, so a difference between two methods can be
read against the spread of the measurement itself. Writes ``kid_resample.json`` beside ``study.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import abcgs  # noqa: F401  (before torch: abcgs sets OpenMP's wait policy, see abcgs/__init__.py)

# isort: split
import numpy as np
import torch

from abcgs.errors import InputError
from abcgs.evaluation.evaluate import render_views
from abcgs.evaluation.fid import TFInception, mmd2_unbiased, random_patches, resize_short_side
from abcgs.features.matching import load_style
from abcgs.io.atomic import write_json
from abcgs.io.ply import read_ply
from abcgs.sfm.colmap import read_colmap_scene


def _run_dir(runs: Path, record: dict) -> Path | None:
    """The folder of the study's run ``record``: ``<name>-<digest>`` whose run.json has the record's key (the
    folder's digest is the study's cache key, which differs from the record's ``key``)."""
    for d in sorted(runs.glob(f"{record['name']}-*")):
        rec = d / "run.json"
        if rec.is_file() and json.loads(rec.read_text()).get("key") == record["key"]:
            return d
    return None


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--study", type=Path, required=True, help="the quality study's work folder (with study.json)")
    ap.add_argument("--patches-per-image", type=int, default=10)
    ap.add_argument("--patch-size", type=int, default=96)
    ap.add_argument("--draws", type=int, default=5)
    ap.add_argument("--methods", default="fast,nnfm", help="methods (default variant) to compare")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    record = args.study / "study.json"
    if not record.is_file():
        raise InputError(f"{record} does not exist: run eval/quality_study.py first")
    study = json.loads(record.read_text())
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    runs = {(r["style"], r["method"]): r for r in study["runs"] if r["variant"] == "default" and r["method"] in methods}
    colmap = Path(study["scene_fit"]["colmap"])
    scene = read_colmap_scene(colmap / "sparse", colmap / "images")
    inception = TFInception()
    t0 = time.perf_counter()
    out: dict = {"patches_per_image": args.patches_per_image, "patch_size": args.patch_size, "draws": args.draws,
                 "n_views": len(scene.cameras), "paintings": {}}
    for style, path in study["styles"].items():
        mine = {m: runs[(style, m)] for m in methods if (style, m) in runs}
        if len(mine) < 2:
            continue
        renders = {}
        for m, r in mine.items():
            run_dir = _run_dir(args.study / "runs", r)
            if run_dir is None or not (run_dir / "point_cloud.ply").is_file():
                raise InputError(f"run {r['name']} has no point_cloud.ply under {args.study / 'runs'}")
            renders[m], _ = render_views(read_ply(run_dir / "point_cloud.ply"), scene.cameras, "auto")
        h, w = next(iter(renders.values()))[0].shape[:2]
        painting = [resize_short_side(load_style(path, 0), min(h, w))]
        n = len(scene.cameras) * args.patches_per_image
        kids: dict[str, list[float]] = {m: [] for m in mine}
        for d in range(args.draws):
            f_s = inception.features(random_patches(painting, n, args.patch_size, np.random.default_rng([d, 2])))
            for m in mine:
                f_r = inception.features(random_patches(renders[m], n, args.patch_size, np.random.default_rng([d, 1])))
                kids[m].append(mmd2_unbiased(f_s, f_r))
        wins = {m: int(sum(kids[m][d] == min(kids[k][d] for k in mine) for d in range(args.draws))) for m in mine}
        out["paintings"][style] = {m: {"kid_mean": float(np.mean(v)), "kid_std": float(np.std(v)), "kids": v,
                                       "wins": wins[m], "study_kid": mine[m]["metrics"]["kid_tf_inception"]}
                                   for m, v in kids.items()}
        line = "  ".join(f"{m} {np.mean(v):.4f} ± {np.std(v):.4f} (wins {wins[m]}/{args.draws}; study {mine[m]['metrics']['kid_tf_inception']:.4f})"
                         for m, v in kids.items())
        print(f"{style:24s} {line}", flush=True)
    out["seconds"] = time.perf_counter() - t0
    out["how"] = (f"{args.patches_per_image} crops of {args.patch_size} px per render and as many from the painting, "
                  f"{args.draws} independent draws, exact unbiased MMD² on TF-Inception pool features ({inception.path})")
    print(f"{out['how']}; {out['seconds']:.0f} s")
    write_json(args.study / "kid_resample.json", out)
    return out


if __name__ == "__main__":
    main()
