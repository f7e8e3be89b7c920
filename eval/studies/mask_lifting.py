"""One user mask → every view: lift label PNGs of some views onto a fitted scene (Eq. 2) and score the result
on the views left out.

    # the user's path: label PNGs (numbers or paint colours) named like the views, lifted from one of them
    python -m eval run mask_lifting --colmap out/tiny/colmap --ply out/tiny/gs/point_cloud.ply \\
        --masks out/tiny/colmap/masks --lift 000 --figure lifted.png --json lifted.json

    # no masks at hand: GrabCut (box + depth seeds) segments every view on its own, one of them is lifted and
    # the others score it (agreement with an independent per-view segmentation, not with a hand-drawn truth)
    python -m eval run mask_lifting --colmap out/bench/fern/colmap --ply out/bench/fern/gs/point_cloud.ply \\
        --grabcut-box 0.1,0.0,0.9,1.0 --masks out/bench/fern/grabcut_masks --lift image000 --figure fig.png

Prints, per label, the IoU of the lifted masks against the given masks on every held-out view (mean and
worst), the pixel agreement, and the seconds it took; ``--figure`` draws the lifted-from view with its mask
and three other views with their given mask (where there is one) beside the lifted labels.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs.errors import InputError
from abcgs.gaussians.ply import read_ply
from abcgs.io.images import load_image, save_image
from abcgs.masks.content import grabcut_view, label_paths_in, read_given_masks
from abcgs.masks.lifting import lift_labels, propagate_unseen, render_label_map
from abcgs.masks.params import GrabCutParams, LiftParams
from abcgs.sfm.model import read_scene
from abcgs.viz import colorize_labels, image_grid
from eval.labels import overlay, score_labels
from eval.record import bench_parser, write_record


def write_grabcut_masks(model, cams: list, stems: list[str], box: tuple[float, float, float, float], out: Path) -> None:
    """A GrabCut mask of every view (:func:`abcgs.masks.content.grabcut_view`, seeded by ``box``: x0, y0, x1, y1 as
    fractions of the view) written to ``out/<stem>.png`` in label colours, as a paint program would save it."""
    out.mkdir(parents=True, exist_ok=True)
    for c, stem in zip(cams, stems):
        seg = grabcut_view(model, c, GrabCutParams(box=box))
        save_image(out / f"{stem}.png", colorize_labels(seg))


def _figure(path: Path, scene, given: dict[int, np.ndarray], views: dict[int, np.ndarray], lift_idx: list[int],
            show: list[int] | None) -> None:
    """The first lifted-from view (its photo, its mask, the lifted labels), then a row each for the views ``show``
    (default: three spread over the views not lifted from), with their given mask where there is one."""
    cams = scene.cameras
    if show is None:
        rest = [i for i in range(len(cams)) if i not in lift_idx]
        show = [rest[round(t * (len(rest) - 1))] for t in (0.25, 0.6, 1.0)] if len(rest) >= 3 else rest
    rows = []
    src = lift_idx[0]
    img = load_image(scene.image_paths[src])
    rows.append([img, overlay(img, given[src]), overlay(img, views[src])])
    for i in show:
        img = load_image(scene.image_paths[i])
        ref = overlay(img, given[i]) if i in given else np.ones_like(img)
        rows.append([img, ref, overlay(img, views[i])])
    source = f"{cams[src].name}'s mask alone" if len(lift_idx) == 1 else "the masks of " + ", ".join(
        cams[i].name for i in lift_idx)
    save_image(path, image_grid(rows, ["view", "given mask (held out below row 1)", f"lifted from {source}"],
                                height=180))


def main(argv: list[str] | None = None) -> dict:
    ap = bench_parser(__doc__)
    ap.add_argument("--colmap", type=Path, required=True, help="reconstruct output (sparse/, images/, scene.json)")
    ap.add_argument("--ply", type=Path, required=True, help="the fitted scene")
    ap.add_argument("--masks", type=Path, required=True, help="folder of label PNGs named like the views")
    ap.add_argument("--lift", default=None, help="comma-separated view stems to lift from (default: the first mask)")
    ap.add_argument("--grabcut-box", default=None,
                    help="x0,y0,x1,y1 (fractions): first write a GrabCut mask of every view into --masks")
    ap.add_argument("--show", default=None, help="comma-separated view stems for the figure (default: three spread out)")
    ap.add_argument("--no-propagate", action="store_true", help="leave Gaussians no lifted view sees unlabelled")
    ap.add_argument("--figure", type=Path, default=None)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()

    scene = read_scene(args.colmap)
    cams, model = scene.cameras, read_ply(args.ply)
    stems = [Path(c.name).stem for c in cams]
    if args.grabcut_box:
        write_grabcut_masks(model, cams, stems, tuple(float(v) for v in args.grabcut_box.split(",")), args.masks)
    given, palette = read_given_masks(label_paths_in(args.masks, cams), cams)
    if not given:
        raise InputError(f"no label PNG in {args.masks} is named like a view ({stems[0]}.png, …)")
    lift_stems = args.lift.split(",") if args.lift else [stems[min(given)]]
    unknown = [s for s in lift_stems if s not in stems or stems.index(s) not in given]
    if unknown:
        raise InputError(f"--lift names views without a mask in {args.masks}: {unknown}")
    lift_idx = [stems.index(s) for s in lift_stems]
    held = [i for i in sorted(given) if i not in lift_idx]
    n_labels = int(max(m.max() for m in given.values()))
    lp = LiftParams()
    lifted = lift_labels(model, [cams[i] for i in lift_idx], [given[i] for i in lift_idx], n_labels, lp)
    if not args.no_propagate:  # Gaussians no lifted view sees take their 3-D neighbours' label (LiftParams.propagate)
        lifted, _ = propagate_unseen(model, lifted, lp)
    views = {i: render_label_map(model, lifted.labels, n_labels, cams[i]) for i in range(len(cams))}
    scores = score_labels(views, {i: given[i] for i in held}, n_labels)
    result = {
        "lifted_from": [cams[i].name for i in lift_idx], "heldout_views": [cams[i].name for i in held],
        "n_labels": n_labels, "palette": {str(k): list(v) for k, v in palette.items()},
        "iou_per_label": scores.per_label_summary(),
        "pixel_agreement": scores.mean_agreement(empty_views="skip"),
        "gaussians_per_label": {str(k): int(v) for k, v in lifted.counts().items()},
        "masks": str(args.masks), "grabcut_box": args.grabcut_box, "propagated": not args.no_propagate,
        "seconds": time.perf_counter() - t0,
    }
    print(f"lifted {len(lift_idx)} view(s) onto {model.num_gaussians:,} Gaussians; scored on {len(held)} held-out view(s)")
    for k, v in result["iou_per_label"].items():
        print(f"  label {k}: IoU mean {v['mean']:.3f}, worst {v['min']:.3f} over {v['n_views']} views")
    if result["pixel_agreement"] is not None:
        print(f"  pixel agreement {result['pixel_agreement']:.3f}; {result['seconds']:.1f} s")
    if args.figure:
        _figure(args.figure, scene, given, views, lift_idx,
                [stems.index(s) for s in args.show.split(",")] if args.show else None)
    if args.json:
        write_record(args.json, result, argv)
    return result

if __name__ == "__main__":
    main()
