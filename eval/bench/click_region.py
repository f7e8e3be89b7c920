"""A click's colour region on the masks page (:func:`abcgs.masks.regions.view_regions`), by colour alone and bounded
by the steps of the view's depth rendered from the fit (``masks.field.region_depth_step``), side by side.

    python -m eval run click_region --scene miku --work /work/bench/miku --view 20240212_003928 --at 206 195 \\
        --figure docs/img/masks/miku_click_region.png

``--scene S`` and ``--work W`` are the scripted user's (:mod:`eval.bench.scripted_user`: the fit under ``W`` of
``eval/data/S``); ``--at X Y`` is the click's pixel in the view (a dot of ``--radius`` pixels), ``--label`` its label.
Each panel shows the view's photo, the region in the label's colour, the click black and, on the second, the depth's
steps grey. Printed: each region's share of the view and of the reference label there (``eval/data/S/reference``).
"""

from __future__ import annotations

from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np

from abcgs.io.images import load_image, save_image, to_uint8
from abcgs.masks.lifting import rendered_depth
from abcgs.masks.params import FieldParams
from abcgs.masks.regions import depth_steps, view_regions
from abcgs.masks.strokes import Stroke, rasterize_strokes
from eval.bench.strokes import DATA, load_case
from eval.labels import stroke_overlay
from eval.record import bench_parser


def main(argv: list[str] | None = None) -> int:
    ap = bench_parser(__doc__)
    ap.add_argument("--scene", default="miku", help="eval/data/<scene>/ (strokes.json, reference/)")
    ap.add_argument("--work", type=Path, required=True, help="where eval.bench.fit left the fitted scene")
    ap.add_argument("--view", required=True, help="the view's file stem")
    ap.add_argument("--at", type=float, nargs=2, required=True, metavar=("X", "Y"), help="the click, in pixels")
    ap.add_argument("--label", type=int, default=1, help="the click's label")
    ap.add_argument("--radius", type=float, default=4.0, help="the dot's radius (pixels)")
    ap.add_argument("--figure", type=Path, required=True, help="write the two panels here (PNG)")
    args = ap.parse_args(argv)
    case = load_case(DATA / args.scene, args.scene, args.work)
    if args.view not in case.by_stem:
        ap.error(f"no view {args.view} in the fit of {args.scene}: one of {', '.join(sorted(case.by_stem)[:5])}, …")
    index = case.by_stem[args.view]
    cam = case.scene.cameras[index]
    photo = to_uint8(load_image(case.scene.image_paths[index]))
    click = [Stroke(args.label, np.array([args.at]), args.radius)]
    seeds = rasterize_strokes(click, (cam.height, cam.width))
    params = FieldParams()
    depth = rendered_depth(case.model, cam)
    panels, names = [], []
    ref = case.refs.get(args.view)
    for name, p, d in (("colour alone", params.model_copy(update={"region_depth_step": 0.0}), None),
                       (f"depth steps over {params.region_depth_step:g}", params, depth)):
        region = view_regions(photo, seeds, p, d)
        mine = region == args.label
        on_label = "" if ref is None else f", {(ref[mine] == args.label).mean():.0%} of it on the label's reference"
        print(f"{name}: the region covers {mine.mean():.1%} of the view{on_label}")
        panel = photo / 255.0
        if d is not None:
            panel[depth_steps(depth, params.region_depth_step, (cam.height, cam.width)) & ~mine] = 0.5
        panel = np.where(mine[..., None], stroke_overlay(photo / 255.0, np.full(mine.shape, args.label), click), panel)
        panel[seeds >= 0] = 0.0
        panels.append(panel)
        names.append(f"{name}: {mine.mean():.1%} of the view")
    from abcgs.viz import image_grid

    save_image(args.figure, image_grid([panels], names, height=cam.height))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
