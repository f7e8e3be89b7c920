"""A splat with no photos and no cameras, stylized end to end: the check behind docs/SPLATS.md "A splat with no photos".

    python -m eval run bare_splat --ply out/bench/fern/gs_sh3_2000/point_cloud.ply \\
        --style ../shared/data/styles/starry_night.jpg --json docs/measurements/bare_splat_fern.json \\
        --figure docs/img/splats/bare_splat_fern.jpg

Writes the fitted scene ``--ply`` as a ``.splat`` (SH degree 0, as the format holds) and forgets its cameras and
photos. Then, as the pipeline does for a scene that is only a splat: cameras made around it and its renders as photos
(:func:`abcgs.sources.bare_splat.read_splat_source`), the import with its check (:func:`abcgs.splats.importing.import_and_save`),
the colour match, the stylization, and the stylized scene given back as ``.splat``
(:func:`abcgs.splats.exporting.give_back`). Records the views' kind and count, the import check, the Gram distance
to the painting before and after, and the wall time of each step; the figure shows generated views before and after.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs.features.matching import build_groups, load_style
from abcgs.features.params import TransferSpec
from abcgs.features.vgg import VGG16Features
from abcgs.features.weights import resolve_vgg16
from abcgs.fit.params import FitParams
from abcgs.gaussians import GaussianModel, render
from abcgs.gaussians.ply import read_ply, write_ply
from abcgs.io.images import save_image
from abcgs.params import load_params
from abcgs.sources.bare_splat import read_splat_source
from abcgs.splats.exporting import give_back
from abcgs.splats.formats.splat import write_splat_file
from abcgs.splats.importing import import_and_save
from abcgs.splats.params import SplatViewsParams
from abcgs.splats.registry import read_splat
from abcgs.stylize.colormatch import color_match_and_refit
from abcgs.stylize.loop import stylize
from abcgs.stylize.params import ColorMatchParams
from abcgs.viz import image_grid
from eval.bench.stylize import gram_distance
from eval.record import bench_parser, write_record


def main(argv=None) -> dict:
    ap = bench_parser(__doc__)
    ap.add_argument("--ply", type=Path, required=True)
    ap.add_argument("--style", type=Path, required=True)
    ap.add_argument("--params", type=Path, default=Path("params.yaml"))
    ap.add_argument("--count", type=int, default=16)
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--color-pass-iterations", type=int, default=40)
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--figure", type=Path, default=None)
    args = ap.parse_args(argv)
    work = args.work or Path(tempfile.mkdtemp(prefix="bare_splat_"))
    fitted = read_ply(args.ply)
    splat = work / f"{args.ply.parent.parent.name}.splat"
    write_splat_file(splat, GaussianModel(fitted.means, fitted.quats, fitted.log_scales, fitted.opacity_logits,
                                          fitted.sh0, fitted.shN[:, :0]))
    rec: dict = {"source": str(args.ply), "splat": splat.name, "n_gaussians": fitted.num_gaussians, "seconds": {}}
    t = time.perf_counter()
    views = SplatViewsParams(count=args.count)
    source = read_splat_source(splat, work / "images", views)
    rec["seconds"]["views"] = time.perf_counter() - t
    cams = source.cameras
    rec["views"] = {"kind": source.metadata["views_kind"], "count": len(cams), "width": cams[0].width,
                    "height": cams[0].height}
    scene = source
    t = time.perf_counter()
    imported = import_and_save(scene, splat, "auto", FitParams(), work / "gs")
    rec["seconds"]["import"] = time.perf_counter() - t
    rec["import"] = {"check_psnr": imported["imported"]["check"]["psnr"], "heldout_psnr": imported["psnr"]}
    original = read_ply(work / "gs" / "point_cloud.ply")
    params = load_params(args.params)
    sd, info = resolve_vgg16(params.vgg)
    sp = params.stylize.with_schedule(args.iterations, args.color_pass_iterations)
    vgg = VGG16Features(sd, sp.layers, feature_scale=info.feature_scale)
    groups = build_groups(TransferSpec(scene="bare", transfer="single", style="style"), {"style": str(args.style)}, {},
                          set(), vgg, style_height=sp.style_height, layers=sp.layers)
    labels = torch.zeros(original.num_gaussians, dtype=torch.long)
    view_labels = [np.zeros((c.height, c.width), np.int64) for c in cams]
    t = time.perf_counter()
    cm = color_match_and_refit(original, scene, labels, view_labels, groups, ColorMatchParams(refit_iterations=100))
    rec["seconds"]["colormatch"] = time.perf_counter() - t
    t = time.perf_counter()
    res = stylize(cm.model, cams, view_labels, labels, groups, vgg, sp, depth_model=original)
    rec["seconds"]["stylize"] = time.perf_counter() - t
    style_img = load_style(str(args.style), sp.style_height)
    rec["gram_distance"] = {"original": gram_distance(original, cams, vgg, style_img, sp.layers),
                            "stylized": gram_distance(res.model, cams, vgg, style_img, sp.layers)}
    write_ply(work / "stylized.ply", res.model)
    rec["returned"] = give_back(work / "stylized.ply", work / "gs" / "splat_source.json", work / "returned")
    back = read_splat(work / "returned" / splat.name).model
    rec["returned"]["reads_back_gaussians"] = back.num_gaussians
    print(rec)
    if args.json:
        write_record(args.json, rec, argv)
    if args.figure:
        shown = [0, len(cams) // 3, 2 * len(cams) // 3]
        with torch.no_grad():
            rows = [[render(m, cams[i])[0].clamp(0, 1).numpy() for i in shown] for m in (original, res.model)]
        save_image(args.figure, image_grid(rows, [f"generated view {i}" for i in shown], height=180))
    return rec


if __name__ == "__main__":
    main()
