"""Masks from strokes on one view (or two) of an object-centred capture, scored on reference views round it.

    python -m eval run strokes --scene miku --work /work/bench/miku --json docs/measurements/miku_strokes.json \\
        --figure docs/img/masks/miku_strokes.jpg
    python -m eval run strokes --scene bonsai --work out/bench --json docs/measurements/bonsai_strokes.json \\
        --figure docs/img/masks/bonsai_strokes.jpg

``--scene S`` reads ``eval/data/S/``: ``strokes.json`` names the fitted scene under ``--work`` (``work_colmap``: the
reconstruction's folder with ``sparse/``, ``images/`` and ``scene.json``; ``work_ply``: the fitted Gaussians; as
``python -m eval run fit --scene <data>/scenes/S --work W`` leaves them), the labels, the strokes of a reference
annotation on several views spread round the capture (``reference``), the test strokes on one view (``test``) and,
optionally, strokes on a second view (``side``) for the two-view case; ``reference/<stem>.png`` are the reference
label maps (values as the page saves them: 0 none, 1..n, 255 undecided; undecided pixels are not scored). Strokes
are in the pixels of ``image_size`` and scale with the views. ``--make-reference`` re-makes the maps: the page's cut
(:func:`abcgs.masks.grabcut.segment`, colour, fill on) of each view's strokes on its photo, checked by eye on the
overlays it writes (``--figure``).

The test, as a user runs it: the strokes cut on the page (colour, fill on) and saved as the page saves them
(:meth:`~abcgs.masks.grabcut.Segmentation.saved_map`: undecided gaps stay undecided), then the ``masks`` stage
(:func:`abcgs.masks.content.make_content_masks`; ``masks`` defaults unless options say otherwise) on the fitted
scene. Printed per reference view that was not stroked: IoU per label against the reference and the share of its
pixels left unlabelled (0); and the share of unlabelled pixels over all views and of unlabelled Gaussians. The goal:
IoU ≥ 0.85 per label (≥ 0.9 from two views) and ≤ 2 % unlabelled pixels on each scored view. Printed beside it, the
bound the fitted scene's geometry sets (:func:`geometry_bound`) and each view's render PSNR against its photo.
"""

from __future__ import annotations

import argparse
import json
import logging
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs.gaussians import GaussianModel
from abcgs.gaussians.ply import read_ply
from abcgs.io.images import load_image, load_labels, save_image, save_labels, to_uint8
from abcgs.layout import ColmapDir
from abcgs.masks.content import ContentMasks, label_paths_in, make_content_masks, recut_outputs
from abcgs.masks.grabcut import segment
from abcgs.masks.lifting import NO_VOTE, LiftResult, lift_labels, render_label_map
from abcgs.masks.params import UNDECIDED, FieldParams, LiftParams, MaskParams, RefineParams
from abcgs.masks.strokes import Stroke
from abcgs.sfm.model import read_scene
from abcgs.types import CalibratedScene
from eval.labels import LabelScores, score_labels, stroke_overlay
from eval.record import bench_parser, write_record

DATA = Path(__file__).resolve().parents[1] / "data"
GOAL_IOU = {1: 0.85, 2: 0.9}
"""Per-label IoU goal by the number of stroked views."""
GOAL_UNLABELLED = 0.02


def view_strokes(items: list[dict], spec: dict, cam) -> list[Stroke]:
    """The strokes of ``items`` at ``cam``'s size: ``strokes.json`` holds them in the pixels of ``spec["image_size"]``
    (the undistorted views they were drawn on); another reconstruction's undistortion gives views a few pixels
    larger or smaller, and the strokes scale with them."""
    w0, h0 = spec["image_size"]
    scale = np.array([cam.width / w0, cam.height / h0])
    return [Stroke(s.label, s.points * scale, s.radius) for s in (Stroke.from_json(d) for d in items)]


def reference_map(path: Path, cam) -> np.ndarray:
    """A reference label map (at its camera's size; ``--make-reference`` cuts them on this reconstruction's views);
    undecided → NO_VOTE."""
    ref = load_labels(path)
    if ref.shape != (cam.height, cam.width):
        raise SystemExit(f"{path} is {ref.shape[1]}x{ref.shape[0]} but view {cam.name} is {cam.width}x{cam.height}: "
                         "re-make the reference maps on this reconstruction (--make-reference)")
    return np.where(ref == UNDECIDED, NO_VOTE, ref)


def render_psnr(model, cam, photo: np.ndarray) -> float:
    """PSNR (dB) of the fitted scene's render of ``cam`` against its photo: where it is low, the view's camera or the
    scene's geometry there is off, and no label rendered into it can follow the photo."""
    from abcgs.gaussians import render

    with torch.no_grad():
        img = render(model, cam)[0].clamp(0, 1).numpy(force=True)
    return float(-10 * np.log10(np.mean((img - photo) ** 2)))


def make_reference(scene, spec: dict, out: Path, check: Path | None, only: list[str] | None = None) -> None:
    """Cut each reference view's strokes as the page does and write ``out/<stem>.png``."""
    from abcgs.viz import image_grid

    by_stem = {Path(c.name).stem: i for i, c in enumerate(scene.cameras)}
    rows = []
    out.mkdir(parents=True, exist_ok=True)
    for stem, items in spec["reference"].items():
        if only and stem not in only:
            continue
        if stem not in by_stem:
            raise SystemExit(f"reference view {stem} is not in this reconstruction; make the reference on one that has it")
        i = by_stem[stem]
        img = load_image(scene.image_paths[i])
        strokes = view_strokes(items, spec, scene.cameras[i])
        seg = segment(to_uint8(img), strokes, fill=True)
        save_labels(out / f"{stem}.png", seg.saved_map())
        rows.append([img, stroke_overlay(img, seg.saved_map(), strokes), stroke_overlay(img, seg.saved_map())])
        print(stem, {int(k): int(v) for k, v in zip(*np.unique(seg.saved_map(), return_counts=True))})
    if check is not None:
        save_image(check, image_grid(rows, ["view", "reference (strokes black, undecided white)", "reference"],
                                     height=scene.cameras[0].height))


def geometry_bound(model, cams, by_stem: dict, refs: dict, scored: list[str], n_labels: int,
                   photos: dict[str, np.ndarray] | None = None, refine: FieldParams | None = None) -> dict:
    """What the fitted scene's geometry allows: every reference map (the stroked view's too) lifted (Eq. 2) and
    rendered into each scored view, its own map included, scored like the test. A label rendered from the Gaussians
    cannot follow the photo better than this where the view's camera or the geometry is off. With the scored views'
    ``photos`` (stem → ``(H, W, 3) uint8``) and ``refine``'s edge settings, the rendered labels are refined against
    each photo as the stage refines them (:func:`abcgs.masks.field.refine_labels`): the bound of the refined maps."""
    from abcgs.masks.field import refine_labels
    from abcgs.masks.lifting import render_label_weights

    lifted = lift_labels(model, [cams[by_stem[s]] for s in refs], list(refs.values()), n_labels, LiftParams())
    maps = {}
    for s in scored:
        if photos is None or refine is None or refine.edge_radius <= 0:
            maps[s] = render_label_map(model, lifted.labels, n_labels, cams[by_stem[s]])
        else:
            img, alpha = render_label_weights(model, lifted.labels, n_labels, cams[by_stem[s]])
            maps[s] = refine_labels(img.numpy(), alpha.numpy(), photos[s], refine)
    scores = score_labels(maps, {s: refs[s] for s in scored}, n_labels)
    return {"per_view": scores.iou, "mean_iou": scores.mean_iou, "worst_iou": scores.worst_per_label(absent=1.0)}


def case_record(scores: LabelScores, goal_iou: float) -> dict:
    """A case's record of its scored views' :func:`eval.labels.score_labels`: per view its IoU per label against its
    reference and the share of its pixels at 0; the worst of each over the views (nan for a label no view scores), and
    whether the goal is met."""
    per_view = {s: {"iou": scores.iou[s], "unlabelled": scores.unlabelled[s]} for s in scores.iou}
    worst = scores.worst_per_label(absent=float("nan"))
    worst_unl = max(scores.unlabelled.values())
    return {"per_view": per_view, "worst_iou": worst, "worst_unlabelled": worst_unl,
            "goal_met": all(not v < goal_iou for v in worst.values()) and worst_unl <= GOAL_UNLABELLED}


def _parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = bench_parser(__doc__)
    ap.add_argument("--scene", default="bonsai", help="eval/data/<scene>/ (bonsai, miku)")
    ap.add_argument("--work", type=Path, default=Path("out/bench"),
                    help="eval.bench.fit's --work: holds the strokes.json's work_colmap and work_ply")
    ap.add_argument("--data", type=Path, default=None, help="strokes.json and reference/ (default eval/data/<scene>)")
    ap.add_argument("--make-reference", action="store_true", help="re-make reference/ from the reference strokes")
    ap.add_argument("--only", nargs="*", default=None, help="--make-reference: these views only")
    ap.add_argument("--cases", nargs="*", default=None, choices=("one", "two"),
                    help="strokes on the test view (one), and on it and the side view (two); default both, where "
                         "strokes.json has a side view")
    ap.add_argument("--compare-zero", action="store_true", help="also run with undecided gaps saved as 0")
    ap.add_argument("--propagate-split", action="store_true", help="masks.lift.propagate_split: true")
    ap.add_argument("--propagate-along", choices=("position", "surface"), default="position",
                    help="masks.lift.propagate_along")
    ap.add_argument("--output", choices=("render", "recut"), default="recut",
                    help="masks.refine.output: the scored views' maps rendered from the Gaussians, or cut once more on "
                         "their photos from them (both are recorded with recut)")
    ap.add_argument("--order", choices=("together", "nearest_first"), default="together",
                    help="masks.refine.order")
    ap.add_argument("--small-regions", choices=("drop", "core"), default="drop", help="masks.refine.small_regions")
    ap.add_argument("--figure", type=Path, default=None, help="the stroked view and the scored ones, overlaid")
    return ap


@dataclass
class Bench:
    """A fitted scene with its annotation (``strokes.json``) and reference label maps.

    Attributes:
        scene: the reconstruction (cameras, photos). model: the fitted Gaussians. spec: ``strokes.json``.
        by_stem: view stem → camera index. refs: the reference maps ``(H, W) int64`` (NO_VOTE where undecided) of the
            reference views this reconstruction has, by stem. n_labels: the annotation's labels.
    """

    scene: CalibratedScene
    model: GaussianModel
    spec: dict
    by_stem: dict[str, int]
    refs: dict[str, np.ndarray]
    n_labels: int


def run_case(bench: Bench, views: list[dict], params: MaskParams, output: str, prefix: str,
             zero: bool = False) -> tuple[dict, ContentMasks, dict]:
    """One case as a user runs it: the strokes of ``views`` (``strokes.json`` entries) cut on the page and saved
    (undecided gaps as 0 with ``zero``), the ``masks`` stage with ``params``, the views not stroked scored; with
    ``output`` ``recut``, the scored views cut once more from the final labels and scored again.

    Returns:
        the case's record, the stage's result, and per stroked view its strokes and the page's cut.
    """
    cams, n_labels, by_stem = bench.scene.cameras, bench.n_labels, bench.by_stem
    cuts = {}
    with tempfile.TemporaryDirectory(prefix=prefix) as d:
        for v in views:
            i = by_stem[v["view"]]
            strokes = view_strokes(v["strokes"], bench.spec, cams[i])
            cut = segment(to_uint8(load_image(bench.scene.image_paths[i])), strokes, fill=True)  # the page: colour only
            cuts[v["view"]] = (strokes, cut)
            save_labels(Path(d) / f"{v['view']}.png", cut.labels if zero else cut.saved_map())
        t = time.perf_counter()
        res = make_content_masks(bench.model, cams, label_paths_in(Path(d), cams), params, bench.scene.image_paths,
                                 show_progress=False)
        seconds = time.perf_counter() - t
    scored = [s for s in bench.refs if s not in cuts]
    refs = {s: bench.refs[s] for s in scored}
    r = case_record(score_labels({s: res.view_labels[by_stem[s]] for s in scored}, refs, n_labels),
                    GOAL_IOU[len(views)])
    if output == "recut":
        # masks.refine.output: recut, on the scored views only: each view's cut depends on the final labels and
        # its own photo alone, so these are the maps the stage writes for them with that option
        t = time.perf_counter()
        lifted = LiftResult(res.gaussian_labels, torch.zeros(0), res.gaussian_decided)
        res.view_labels = recut_outputs(bench.model, cams, bench.scene.image_paths, lifted, n_labels, res.view_labels,
                                        skip={by_stem[v] for v in cuts}, params=params,
                                        only={by_stem[s] for s in scored})
        r = {"render": r} | case_record(score_labels({s: res.view_labels[by_stem[s]] for s in scored}, refs, n_labels),
                                        GOAL_IOU[len(views)])
        r["recut_seconds_per_view"] = (time.perf_counter() - t) / max(len(scored), 1)
    r.update({"stroked_views": list(cuts), "goal_iou": GOAL_IOU[len(views)],
              "strokes_per_label": {v: {str(k): sum(s.label == k for s in st) for k in range(1, n_labels + 1)}
                                    for v, (st, _) in cuts.items()},
              "page_cut_undecided": {v: float((~c.claimed).mean()) for v, (_, c) in cuts.items()},
              "unlabelled_pixels_all_views": {"mean": float(np.mean(list(res.unlabelled_pixels.values()))),
                                              "max": float(max(res.unlabelled_pixels.values()))},
              "unlabelled_gaussians": res.unlabelled_gaussians, "propagated": res.propagated,
              "warnings": res.warnings, "seconds": seconds})
    return r, res, cuts


def _print_iou_table(head: str, r: dict, n_labels: int) -> None:
    """Per scored view of a :func:`case_record` its IoU per label and unlabelled share, then the worst of each."""
    print(head + f" {'unlabelled':>10}")
    for s, v in r["per_view"].items():
        print(f"{s:>16} " + " ".join(f"{v['iou'].get(str(k), float('nan')):10.3f}" for k in range(1, n_labels + 1))
              + f" {v['unlabelled']:10.1%}")
    print(f"{'worst':>16} " + " ".join(f"{r['worst_iou'][str(k)]:10.3f}" for k in range(1, n_labels + 1))
          + f" {r['worst_unlabelled']:10.1%}")


def _print_report(out: dict) -> None:
    """The tables of a :func:`main` record: each case's scores, then the geometry's bound and the render PSNRs."""
    names, n_views = out["labels"], out["views"]
    n_labels = len(names)
    missing = out["reference_views_not_registered"]
    print(f"{out['scene']}, {n_views} views, {out['n_gaussians']:,} Gaussians"
          + (f"; reference views not registered: {', '.join(missing)}" if missing else ""))
    head = f"{'view':>16} " + " ".join(f"{names[str(k)][:10]:>10}" for k in range(1, n_labels + 1))
    for title, r in out["cases"].items():
        print(f"\n{title}: strokes on {', '.join(r['stroked_views'])} ({r['strokes_per_label']} per label); the page's "
              f"cut left {r['page_cut_undecided']} undecided; masks stage {r['seconds']:.0f} s, "
              f"{r['propagated']} Gaussians propagated")
        if "render" in r:
            print("the final labels rendered (masks.refine.output: render):")
            _print_iou_table(head, r["render"], n_labels)
            print(f"each scored view cut once more from them (masks.refine.output: recut; "
                  f"{r['recut_seconds_per_view']:.1f} s a view):")
        _print_iou_table(head, r, n_labels)
        print(f"all {n_views} views: unlabelled pixels mean {r['unlabelled_pixels_all_views']['mean']:.1%}, max "
              f"{r['unlabelled_pixels_all_views']['max']:.1%} (rendered); unlabelled Gaussians "
              f"{r['unlabelled_gaussians']:.1%}; goal (IoU ≥ {r['goal_iou']}, ≤ {GOAL_UNLABELLED:.0%} unlabelled on "
              f"each scored view): {'met' if r['goal_met'] else 'not met'}")
    bound, psnr = out["geometry_bound"], out["render_psnr_db"]
    print(f"\nthe geometry's bound: all {len(out['reference_views'])} reference maps lifted and rendered back; render "
          "PSNR vs photo")
    print(head + f" {'PSNR dB':>10}")
    for s, v in bound["per_view"].items():
        print(f"{s:>16} " + " ".join(f"{v.get(str(k), float('nan')):10.3f}" for k in range(1, n_labels + 1))
              + f" {psnr[s]:10.2f}")
    print(f"{'worst':>16} " + " ".join(f"{bound['worst_iou'][str(k)]:10.3f}" for k in range(1, n_labels + 1)))
    print(f"total {out['seconds']:.0f} s")


@dataclass(frozen=True)
class FittedCase:
    """A labelled scene of ``eval/data/<scene>/`` and its fit: ``strokes.json`` (``spec``), the reconstruction and the
    fitted Gaussians it names under the work folder, each view's index by file stem (``by_stem``) and the reference
    label maps of the views the reconstruction holds (``refs``, stem → ``(H, W) int64``)."""

    spec: dict
    scene: CalibratedScene
    model: GaussianModel
    by_stem: dict[str, int]
    refs: dict[str, np.ndarray]


def load_case(data: Path, scene_name: str, work: Path) -> FittedCase:
    """The :class:`FittedCase` of ``data`` (``eval/data/<scene>``) fitted under ``work`` (``eval.bench.fit --work``);
    ``SystemExit`` naming the fit's command when the fit is missing."""
    spec = json.loads((data / "strokes.json").read_text())
    colmap, ply = work / spec["work_colmap"], work / spec["work_ply"]
    if not ColmapDir(colmap).scene.is_file() or not ply.is_file():
        raise SystemExit(f"no fitted {scene_name} under {work} ({colmap}, {ply}): run python -m eval run fit "
                         f"--scene <data>/scenes/{scene_name} --work {work} first")
    scene = read_scene(colmap)
    by_stem = {Path(c.name).stem: i for i, c in enumerate(scene.cameras)}
    refs = {s: reference_map(data / "reference" / f"{s}.png", scene.cameras[by_stem[s]])
            for s in spec["reference"] if s in by_stem}
    return FittedCase(spec, scene, read_ply(ply), by_stem, refs)


def main(argv: list[str] | None = None) -> dict:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(message)s")

    data = args.data or DATA / args.scene
    if args.make_reference:
        spec = json.loads((data / "strokes.json").read_text())
        scene = read_scene(args.work / spec["work_colmap"])
        make_reference(scene, spec, data / "reference", args.figure, args.only)
        return {}

    t0 = time.perf_counter()
    case = load_case(data, args.scene, args.work)
    spec, scene, model, by_stem, refs = case.spec, case.scene, case.model, case.by_stem, case.refs
    cams = scene.cameras
    missing = [s for s in spec["reference"] if s not in by_stem]
    bench = Bench(scene, model, spec, by_stem, refs, len(spec["labels"]))
    cases = args.cases or (["one", "two"] if "side" in spec else ["one"])
    stroked_views = {"one": [spec["test"]], "two": [spec["test"], spec.get("side")]}
    params = MaskParams(source="given", lift=LiftParams(propagate_split=args.propagate_split,
                                                        propagate_along=args.propagate_along),
                        refine=RefineParams(order=args.order, small_regions=args.small_regions))
    results, extra = {}, {}
    for case in cases:
        if any(v is None for v in stroked_views[case]):
            raise SystemExit(f"{data / 'strokes.json'} has no side view for the two-view case")
        results[case], res, cuts = run_case(bench, stroked_views[case], params, args.output, f"abcgs-{args.scene}-")
        extra[case] = (res, cuts)
        if args.compare_zero:
            results[case + "_undecided_saved_as_0"] = run_case(bench, stroked_views[case], params, args.output,
                                                               f"abcgs-{args.scene}-", zero=True)[0]
    scored_one = [s for s in refs if s != spec["test"]["view"]]
    bound = geometry_bound(model, cams, by_stem, refs, scored_one, bench.n_labels)
    psnr = {s: render_psnr(model, cams[by_stem[s]], load_image(scene.image_paths[by_stem[s]])) for s in refs}
    out = {"scene": spec.get("title", args.scene), "views": len(cams), "n_gaussians": model.num_gaussians,
           "labels": spec["labels"], "reference_views": list(refs), "reference_views_not_registered": missing,
           "propagate_split": args.propagate_split, "propagate_along": args.propagate_along,
           "refine_order": args.order, "refine_output": args.output, "refine_small_regions": args.small_regions,
           "cases": results, "geometry_bound": bound, "render_psnr_db": psnr,
           "goal": {"iou": {str(k): v for k, v in GOAL_IOU.items()}, "unlabelled": GOAL_UNLABELLED}}
    out["seconds"] = time.perf_counter() - t0
    _print_report(out)
    if args.figure:
        _figure(args.figure, scene, by_stem, refs, extra)
    if args.json:
        write_record(args.json, out, argv)
    return out


def _figure(path: Path, scene, by_stem: dict, refs: dict, extra: dict) -> None:
    """Per case: a row of the stroked views (strokes and the page's cut, then the stage's labels, for each), a row of
    the reference views' labels; last row the references. The column captions name the reference views."""
    from abcgs.viz import image_grid

    def photo(s):
        return load_image(scene.image_paths[by_stem[s]])

    rows = []
    n_cols = max(len(refs), 4)
    for res, cuts in extra.values():
        top = []
        for v, (strokes, cut) in cuts.items():
            top += [stroke_overlay(photo(v), cut.saved_map(), strokes),
                    stroke_overlay(photo(v), res.view_labels[by_stem[v]])]
        rows.append(top + [np.ones_like(top[0])] * (n_cols - len(top)))
        rows.append([stroke_overlay(photo(s), res.view_labels[by_stem[s]]) for s in refs])
    rows.append([stroke_overlay(photo(s), r) for s, r in refs.items()])
    save_image(path, image_grid(rows, list(refs), height=150))


if __name__ == "__main__":
    main()
