"""What stylization should do to the SH bands above DC of a degree-3 scene: the measurement behind
``stylize.higher_sh``'s default (docs/SPLATS.md "SH bands").

    python -m eval run sh_bands --scene ../shared/data/scenes/fern --style ../shared/data/styles/starry_night.jpg \\
        --json docs/measurements/sh_bands_fern.json --figure docs/img/splats/sh_bands_fern.jpg

Fits the scene with SH degree 3 (reconstruction and fit cached in ``--work``), colour-matches it to the painting and
stylizes it once per :data:`abcgs.stylize.params.HigherSH` mode with the same seed and schedule. Per mode, over every
view: the Gram distance to the painting (lower: more stylized), and the view-dependent part of the stylized colour —
the render minus the same scene rendered with its DC term only — as (a) its mean absolute size and (b) its
correlation with the original scene's view-dependent part (the original's colour "shining through": 1 means the
stylized scene still carries the photo's highlights, 0 none of them). The figure shows three views per mode and
the view-dependent part amplified ×4 around grey.
"""

from __future__ import annotations

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
from abcgs.features.vgg import VGG16Features
from abcgs.features.weights import resolve_vgg16
from abcgs.fit.params import FitParams, StrategyParams
from abcgs.fit.training import fit
from abcgs.gaussians import GaussianModel, render
from abcgs.gaussians.ply import read_ply, write_ply
from abcgs.io.images import save_image
from abcgs.layout import ColmapDir
from abcgs.params import load_params
from abcgs.sfm.model import read_scene
from abcgs.sources.params import SceneParams
from abcgs.sources.reconstruct import reconstruct_scene
from abcgs.stylize.colormatch import color_match_and_refit
from abcgs.stylize.loop import stylize
from abcgs.stylize.params import ColorMatchParams, HigherSH
from abcgs.stylize.sh_bands import with_higher_sh
from abcgs.viz import image_grid
from eval.bench.stylize import gram_distance
from eval.record import bench_parser, write_record


def dc_only(model: GaussianModel) -> GaussianModel:
    return GaussianModel(model.means, model.quats, model.log_scales, model.opacity_logits, model.sh0,
                         torch.zeros_like(model.shN))


@torch.no_grad()
def view_dependent(model: GaussianModel, cam) -> np.ndarray:
    """``(H, W, 3)`` render minus the DC-only render: the view-dependent part of the colour."""
    return (render(model, cam)[0].clamp(0, 1) - render(dc_only(model), cam)[0].clamp(0, 1)).numpy()


def label_cell(text: str) -> np.ndarray:
    import cv2

    img = np.full((150, 170, 3), 255, np.uint8)
    cv2.putText(img, text, (6, 80), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def fitted_degree3(scene_dir: Path, work: Path, iterations: int, scale: float):
    colmap = work / scene_dir.name / "colmap"
    if not ColmapDir(colmap).scene.is_file():
        reconstruct_scene(SceneParams.at(scene_dir, "photos"), colmap)
    scene = read_scene(colmap)
    ply = work / scene_dir.name / f"gs_sh3_{iterations}" / "point_cloud.ply"
    if not ply.is_file():
        params = FitParams(iterations=iterations, sh_degree=3, sh_degree_interval=max(1, iterations // 6),
                           resolution_scale=scale, max_gaussians=120_000, threads=0,
                           strategy=StrategyParams(refine_start=min(500, iterations // 10), refine_every=100,
                                                   refine_stop=int(0.6 * iterations), reset_every=max(1000, iterations // 2)))
        write_ply(ply, fit(scene, params, progress=True).model)
    return scene, read_ply(ply)


def main(argv=None) -> dict:
    ap = bench_parser(__doc__)
    ap.add_argument("--scene", type=Path, required=True)
    ap.add_argument("--style", type=Path, required=True)
    ap.add_argument("--work", type=Path, default=Path("out/bench"))
    ap.add_argument("--params", type=Path, default=Path("params.yaml"))
    ap.add_argument("--fit-iterations", type=int, default=2000)
    ap.add_argument("--fit-scale", type=float, default=0.5, help="fit and stylize at this fraction of the image size")
    ap.add_argument("--iterations", type=int, default=150, help="stylize.optim.iterations")
    ap.add_argument("--color-pass-iterations", type=int, default=50)
    ap.add_argument("--refit-iterations", type=int, default=100)
    ap.add_argument("--fit-only", action="store_true")
    ap.add_argument("--figure", type=Path, default=None)
    args = ap.parse_args(argv)

    scene, original = fitted_degree3(args.scene, args.work, args.fit_iterations, args.fit_scale)
    if args.fit_only:
        return {}
    cams = [c.scaled(args.fit_scale) for c in scene.cameras]
    params = load_params(args.params)
    sd, info = resolve_vgg16(params.vgg)
    base = params.stylize.with_schedule(args.iterations, args.color_pass_iterations)
    vgg = VGG16Features(sd, base.layers, feature_scale=info.feature_scale)
    groups = build_groups(TransferSpec(scene=args.scene.name, transfer="single", style="style"), {"style": str(args.style)},
                          {}, set(), vgg, style_height=base.style_height, layers=base.layers)
    labels = torch.zeros(original.num_gaussians, dtype=torch.long)
    view_labels = [np.zeros((c.height, c.width), np.int64) for c in cams]
    cm = color_match_and_refit(original, scene, labels, view_labels, groups,
                               ColorMatchParams(refit_iterations=args.refit_iterations, resolution_scale=args.fit_scale))
    style_img = load_style(str(args.style), base.style_height)
    vd_orig = [view_dependent(original, c) for c in cams]
    shown = [0, len(cams) // 2, len(cams) - 1]
    rows, labels_row, out = [], [], {"scene": str(args.scene), "style": str(args.style), "n_gaussians": original.num_gaussians,
                                      "sh_degree": original.sh_degree, "views": len(cams), "width": cams[0].width,
                                      "stylize": {"iterations": args.iterations, "color_pass_iterations": args.color_pass_iterations},
                                      "original": {"vd_mean_abs": float(np.mean([np.abs(v).mean() for v in vd_orig]))},
                                      "modes": {}}
    with torch.no_grad():
        rows.append([render(original, cams[i])[0].clamp(0, 1).numpy() for i in shown]
                    + [np.clip(0.5 + 4 * vd_orig[shown[0]], 0, 1)])
    labels_row.append("original (degree 3)")
    for mode in get_args(HigherSH):
        sp = base.model_copy(update={"higher_sh": mode})
        t0 = time.perf_counter()
        res = stylize(with_higher_sh(cm.model, original, mode), cams, view_labels, labels, groups, vgg, sp,
                      depth_model=original, progress=False)
        seconds = time.perf_counter() - t0
        vd = [view_dependent(res.model, c) for c in cams]
        corr = float(np.corrcoef(np.concatenate([v.ravel() for v in vd]), np.concatenate([v.ravel() for v in vd_orig]))[0, 1]) \
            if any(np.abs(v).max() > 0 for v in vd) else 0.0
        rec = {"gram_distance": gram_distance(res.model, cams, vgg, style_img, base.layers),
               "vd_mean_abs": float(np.mean([np.abs(v).mean() for v in vd])), "vd_corr_with_original": corr,
               "seconds": seconds}
        out["modes"][mode] = rec
        print(f"{mode:>10}: Gram {rec['gram_distance']:.4g}, view-dependent |Δ| {rec['vd_mean_abs']:.4f}, "
              f"correlation with the original's {corr:.3f} ({seconds:.0f} s)")
        with torch.no_grad():
            rows.append([render(res.model, cams[i])[0].clamp(0, 1).numpy() for i in shown]
                        + [np.clip(0.5 + 4 * vd[shown[0]], 0, 1)])
        labels_row.append(mode)
    out["vgg_weights"] = info.model_dump()
    if args.json:
        write_record(args.json, out, argv)
    if args.figure:
        grid = image_grid([[label_cell(name)] + r for name, r in zip(labels_row, rows)],
                          ["higher_sh", f"view {shown[0]}", f"view {shown[1]}", f"view {shown[2]}",
                           f"view-dependent x4, view {shown[0]}"], height=150)
        save_image(args.figure, grid)
    return out


if __name__ == "__main__":
    main()
