"""The colour match's re-fit with and without densification, on a fitted scene: Gaussians, fit to the recoloured
images and seconds.

    python -m eval run colormatch_refit --layout out/tiny/colmap --ply out/tiny/gs/point_cloud.ply \
        --style data/tiny/styles/paint.png --json out/bench/colormatch_refit_tiny.json

``--layout`` is a scene as the ``reconstruct`` stage writes it (``read_scene``), ``--ply`` its fit. The colour match
is the single transfer of ``--style`` with ``params.yaml``'s ``colormatch`` section, and the re-fit's length follows
the views' size as the stage's does unless ``--steps`` is given. It runs twice from the same start:
densifying every ``--refine-every`` steps (default 50, the authors'), every Gaussian carrying its fitted row, and
with the Gaussians kept fixed (``refine_every`` 0). Each run reports its Gaussians, how many fitted rows have more than
one descendant, the PSNR of its renders against the recoloured training images over every view, and its seconds.
With ``--labels`` (the masks stage's ``gaussian_labels.npy``) it also renders the fitted labels by row into every view
and reports the share of labelled pixels that match the fitted scene's label map. The style features are not used by
the colour match, so a VGG-16 with random weights builds the matching group.
"""

from __future__ import annotations

import time
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs.features.matching import build_groups
from abcgs.features.params import TransferSpec
from abcgs.features.vgg import VGG16Features, random_state_dict
from abcgs.fit.evaluation import evaluate
from abcgs.gaussians import fitted_rows
from abcgs.gaussians.ply import read_ply
from abcgs.masks.lifting import render_label_map
from abcgs.params import load_params
from abcgs.sfm.model import read_scene
from abcgs.stylize.colormatch import color_match_and_refit
from abcgs.stylize.params import ColorMatchParams
from eval.record import bench_parser, write_record

ROOT = Path(__file__).resolve().parents[2]


def label_agreement(model, labels: torch.Tensor, refitted, cameras) -> float:
    """Share of the pixels labelled in either map where the fitted scene's label map and the re-fitted one's (labels
    by fitted row) agree, over ``cameras``."""
    n = int(labels.max()) + 1
    rows = fitted_rows(refitted)
    same = seen = 0
    for cam in cameras:
        before = render_label_map(model, labels, n, cam)
        after = render_label_map(refitted, labels[rows], n, cam)
        on = (before > 0) | (after > 0)
        same, seen = same + int((before == after)[on].sum()), seen + int(on.sum())
    return same / max(seen, 1)


def run(scene, model, groups, params: ColorMatchParams, densify: bool, labels: torch.Tensor | None) -> dict:
    """One colour match and re-fit of ``model`` with ``params``; ``densify`` False sets ``refine_every`` to 0."""
    single = torch.zeros(model.num_gaussians, dtype=torch.long)  # one group: every Gaussian, every pixel
    view_labels = [np.zeros((c.height, c.width), np.int64) for c in scene.cameras]
    t0 = time.perf_counter()
    res = color_match_and_refit(model, scene, single, view_labels, groups,
                                params if densify else params.model_copy(update={"refine_every": 0}),
                                background=scene.background)
    seconds = time.perf_counter() - t0
    cams = [c if params.resolution_scale == 1.0 else c.scaled(params.resolution_scale) for c in scene.cameras]
    ev = evaluate(res.model, cams, res.images, "auto", background=torch.tensor(scene.background.color))
    counts = np.bincount(fitted_rows(res.model).numpy(), minlength=model.num_gaussians)
    return {"densify": densify, "n_gaussians": res.model.num_gaussians, "refit_steps": len(res.history),
            "fitted_rows_with_descendants": int((counts > 1).sum()), "fitted_rows_gone": int((counts == 0).sum()),
            "psnr_to_recoloured": ev.psnr, "ssim_to_recoloured": ev.ssim, "seconds": seconds,
            "label_agreement": None if labels is None else label_agreement(model, labels, res.model, scene.cameras)}


def main(argv: list[str] | None = None) -> None:
    ap = bench_parser(__doc__)
    ap.add_argument("--layout", type=Path, required=True, help="the scene's layout (out/<scene>/colmap)")
    ap.add_argument("--ply", type=Path, required=True, help="its fitted Gaussians (out/<scene>/gs/point_cloud.ply)")
    ap.add_argument("--style", type=Path, required=True, help="the painting")
    ap.add_argument("--refine-every", type=int, default=50, help="the densifying run's colormatch.refine_every")
    ap.add_argument("--steps", type=int, default=None, help="re-fit steps (default: by the views' size)")
    ap.add_argument("--labels", type=Path, default=None,
                    help="the fitted Gaussians' labels (the masks stage's gaussian_labels.npy)")
    args = ap.parse_args(argv)
    scene, model = read_scene(args.layout), read_ply(args.ply)
    params = load_params(ROOT / "params.yaml").colormatch
    if args.steps is not None:
        params = params.model_copy(update={"refit_iterations": args.steps})
    params = params.model_copy(update={"refine_every": args.refine_every})
    vgg = VGG16Features(random_state_dict(0), ["relu3_1"])
    groups = build_groups(TransferSpec(scene="s", transfer="single", style="p"), {"p": str(args.style)}, {}, set(),
                          vgg, style_height=64, layers=["relu3_1"])
    labels = None if args.labels is None else torch.from_numpy(np.load(args.labels, allow_pickle=False)).long()
    rows = [run(scene, model, groups, params, densify, labels) for densify in (True, False)]
    print(f"{'re-fit':<12}{'steps':>6}{'Gaussians':>11}{'rows grown':>12}{'rows gone':>11}{'PSNR dB':>9}{'SSIM':>7}"
          f"{'s':>7}{'labels kept':>13}")
    for r in rows:
        kept = "-" if r["label_agreement"] is None else f"{r['label_agreement']:.3f}"
        print(f"{'densifying' if r['densify'] else 'fixed':<12}{r['refit_steps']:>6}{r['n_gaussians']:>11,}"
              f"{r['fitted_rows_with_descendants']:>12,}{r['fitted_rows_gone']:>11,}{r['psnr_to_recoloured']:>9.2f}"
              f"{r['ssim_to_recoloured']:>7.3f}{r['seconds']:>7.1f}{kept:>13}")
    if args.json:
        write_record(args.json, {"layout": str(args.layout), "ply": str(args.ply), "style": str(args.style),
                                 "fitted_gaussians": model.num_gaussians, "runs": rows}, argv)


if __name__ == "__main__":
    main()
