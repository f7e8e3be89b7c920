"""Benchmark ABC-GS stylization on a real scene: content preservation, style distance, time split.

    python -m eval run stylize --scene ../shared/data/scenes/fern \
        --style ../shared/data/styles/starry_night.jpg --json out/bench/stylize_fern_starry.json

Needs the fitted scene of ``eval/bench/fit.py`` (``out/bench/<scene>/{colmap,gs}``). Runs single-image
transfer: colour match + re-fit, then the stylization passes with ``params.yaml``'s ``stylize`` section
(overridable on the command line). Reports, over all views:

- ``ssim``: SSIM between renders of the original scene and of the stylized scene (content preservation);
- ``gram_distance``: mean over views of ‖G(render) − G(style)‖²_F / C² with G the Gram matrix of the
  relu3_1..3 features normalised by the number of positions (Gatys), for the colour-matched start and
  the final scene, and its relative drop;
- wall time per iteration and its split between render, VGG, style loss, backward and optimiser step.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import get_args

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs.features.matching import build_groups, load_style
from abcgs.features.params import TransferSpec
from abcgs.features.vgg import VGG16Features, downsample_half, extract_features
from abcgs.features.weights import resolve_vgg16
from abcgs.fit.metrics import ssim as ssim_metric
from abcgs.gaussians import render
from abcgs.gaussians.ply import read_ply, write_ply
from abcgs.io.images import save_image
from abcgs.losses.terms import gram_matrix
from abcgs.params import load_params
from abcgs.sfm.model import read_scene
from abcgs.stylize.colormatch import color_match_and_refit
from abcgs.stylize.loop import stylize
from abcgs.stylize.params import ColorMatchParams, StylizeParams
from abcgs.types import CandidateProducts, KnnSearch
from abcgs.viz import image_grid
from eval.record import bench_parser, write_record


@torch.no_grad()
def gram_distance(model, cameras, vgg, style_img: np.ndarray, layers) -> float:
    fs = extract_features(vgg, torch.from_numpy(style_img).permute(2, 0, 1)[None], layers)[0]
    gs = gram_matrix(fs.reshape(fs.shape[0], -1))
    d = []
    for cam in cameras:
        img = render(model, cam)[0].clamp(0, 1).permute(2, 0, 1)[None]
        fr = extract_features(vgg, downsample_half(img), layers)[0]
        d.append(float(((gram_matrix(fr.reshape(fr.shape[0], -1)) - gs) ** 2).sum()))
    return float(np.mean(d))


def _parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = bench_parser(__doc__)
    ap.add_argument("--scene", type=Path, required=True)
    ap.add_argument("--style", type=Path, required=True)
    ap.add_argument("--work", type=Path, default=Path("out/bench"))
    ap.add_argument("--params", type=Path, default=Path("params.yaml"))
    ap.add_argument("--iterations", type=int, default=None, help="override stylize.optim.iterations")
    ap.add_argument("--color-pass-iterations", type=int, default=None,
                    help="override stylize.optim.color_pass_iterations (the authors' schedule: 600 + 400)")
    ap.add_argument("--refit-iterations", type=int, default=200)
    ap.add_argument("--method", default="fast", choices=["fast", "nnfm", "knnfm", "gram"])
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--knn-search", choices=get_args(KnnSearch), default=None,
                    help="override stylize.fast.knn_search (the neighbour search of FAST/NNFM/KNNFM)")
    ap.add_argument("--projection-rank", type=int, default=None,
                    help="override stylize.fast.projection_rank (0: exact search; r > 0: the projected search)")
    ap.add_argument("--projection-candidates", type=int, default=None, help="override stylize.fast.projection_candidates")
    ap.add_argument("--projection-products", choices=get_args(CandidateProducts), default=None,
                    help="override stylize.fast.projection_products (the candidates' products: float32 or bfloat16)")
    return ap


def with_fast_overrides(sp: StylizeParams, **overrides) -> StylizeParams:
    """``sp`` with the ``stylize.fast`` settings of ``overrides`` that are not None (knn_search, projection_rank, …)."""
    fast_update = {key: value for key, value in overrides.items() if value is not None}
    if fast_update:
        sp = sp.model_copy(update={"fast": sp.fast.model_copy(update=fast_update)})
    return sp


@torch.no_grad()
def _content_ssim(original, stylized, color_matched, cameras, style_img: np.ndarray) -> tuple[list[float], list[list]]:
    """SSIM of the stylized scene's render against the original's, per view; and for every 7th view a figure row
    (original, style, colour-matched, stylized; ``(H, W, 3)`` float in [0, 1])."""
    ssims, rows = [], []
    for i, cam in enumerate(cameras):
        a = render(original, cam)[0].clamp(0, 1)
        b = render(stylized, cam)[0].clamp(0, 1)
        ssims.append(ssim_metric(b, a))
        if i % 7 == 0:
            rows.append([a.numpy(), style_img, render(color_matched, cam)[0].clamp(0, 1).numpy(), b.numpy()])
    return ssims, rows


def main(argv=None) -> dict:
    args = _parser().parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)

    params = load_params(args.params)
    sp = with_fast_overrides(params.stylize.with_schedule(args.iterations, args.color_pass_iterations),
                             knn_search=args.knn_search, projection_rank=args.projection_rank,
                             projection_candidates=args.projection_candidates,
                             projection_products=args.projection_products)
    base = args.work / args.scene.name
    scene = read_scene(base / "colmap")
    original = read_ply(base / "gs" / "point_cloud.ply")
    sd, info = resolve_vgg16(params.vgg)
    vgg = VGG16Features(sd, sp.layers, feature_scale=info.feature_scale)
    exp = TransferSpec(scene=args.scene.name, transfer="single", style="style")
    groups = build_groups(exp, {"style": str(args.style)}, {}, set(), vgg, style_height=sp.style_height, layers=sp.layers)
    labels = torch.zeros(original.num_gaussians, dtype=torch.long)
    view_labels = [np.zeros((c.height, c.width), np.int64) for c in scene.cameras]

    t0 = time.perf_counter()
    cm = color_match_and_refit(original, scene, labels, view_labels, groups,
                               ColorMatchParams(refit_iterations=args.refit_iterations))
    t_cm = time.perf_counter() - t0
    res = stylize(cm.model, scene.cameras, view_labels, labels, groups, vgg, sp, method=args.method,
                  depth_model=original)

    style_img = load_style(str(args.style), sp.style_height)
    g_start = gram_distance(cm.model, scene.cameras, vgg, style_img, sp.layers)
    g_end = gram_distance(res.model, scene.cameras, vgg, style_img, sp.layers)
    g_orig = gram_distance(original, scene.cameras, vgg, style_img, sp.layers)
    ssims, rows = _content_ssim(original, res.model, cm.model, scene.cameras, style_img)
    n_it = max(1, res.timings.get("iterations", 1))
    split = {k: v / n_it for k, v in res.timings.items() if k != "iterations"}
    out = {
        "scene": str(args.scene), "style": str(args.style), "method": args.method,
        "iterations": int(res.timings.get("iterations", 0)), "refit_iterations": args.refit_iterations,
        "color_pass_iterations": sp.optim.color_pass_iterations,
        "ssim_mean": float(np.mean(ssims)), "ssim_per_view": ssims,
        "gram_distance": {"original": g_orig, "color_matched": g_start, "stylized": g_end,
                          "drop_from_color_matched": 1.0 - g_end / g_start},
        "seconds": {"colormatch_refit": t_cm, "stylize": res.seconds},
        "seconds_per_iteration": split, "vgg_weights": info.model_dump(),
        "fast": res.fast_stats, "n_gaussians": res.model.num_gaussians,
    }
    print(f"SSIM(original, stylized) = {out['ssim_mean']:.3f} over {len(ssims)} views")
    print(f"Gram distance: original {g_orig:.4g}, colour-matched {g_start:.4g}, stylized {g_end:.4g} "
          f"(drop {100 * out['gram_distance']['drop_from_color_matched']:.1f}% from the colour-matched start)")
    step_s = sum(split.values())
    out["style_loss_share_of_step"] = split.get("style_loss", 0.0) / step_s if step_s > 0 else float("nan")
    print(f"time: colour match + re-fit {t_cm:.1f} s, stylize {res.seconds:.1f} s for {out['iterations']} iterations; "
          "per iteration: " + ", ".join(f"{k} {1000 * v:.0f} ms" for k, v in split.items()))
    print(f"{args.method} style loss: {100 * out['style_loss_share_of_step']:.1f}% of a main-pass step "
          f"({1000 * step_s:.0f} ms; {torch.get_num_threads()} torch threads, load {os.getloadavg()[0]:.2f})")
    if args.json:
        write_record(args.json, out, argv)
        save_image(args.json.with_suffix(".png"), image_grid(rows, ["original", "style", "colour-matched", "stylized"], height=200))
        write_ply(args.json.with_suffix(".ply"), res.model)
        write_ply(args.json.with_suffix(".colormatch.ply"), cm.model)  # the start (e.g. for eval/bench/knn_recall.py)
    return out

if __name__ == "__main__":
    main()
