"""Masks from strokes, end to end on the tiny scene: a simulated user's strokes on one view → GrabCut labels →
lifted onto a fitted scene (Eq. 2) → scored on every other view against the scene's true labels.

    python -m eval run paint_iou                                   # prints the table; about 1 min on 2 cores
    python -m eval run paint_iou --json docs/measurements/paint_iou_tiny.json --figure paint_iou.png

Steps, all in a temporary folder:

1. :func:`abcgs.scene.synthetic.make_tiny_scene` (it ships the true label maps in ``masks/``).
2. The user: at most ``--strokes`` strokes per label on view ``--view`` (:func:`simulated_strokes`: straight strokes
   through the deepest points of each true region, i.e. on its medial axis, kept ``--radius`` + 2 px inside), then
   Segment; with ``--rounds`` ≥ 2, fewer strokes first and corrections after each cut (:func:`simulated_session`).
3. :func:`abcgs.masks.grabcut.segment` cuts that view from the strokes; its IoU against the view's true labels is
   printed as ``2-D``.
4. ``reconstruct`` and a short ``fit`` (``--iterations``, densifying every 25 steps) of the scene.
5. :func:`abcgs.masks.content.make_content_masks` with the strokes' mask as the only given mask, as the ``masks``
   stage runs it for the tiny scene (``masks.refine.enabled``: Eq. 2 lifting, then the cross-view refinement that
   re-cuts the other views on colour and rendered depth); the lifted labels rendered into every other view are scored
   against the true labels (undistorted like the views). Also scored: the same mask without refinement (``lift
   only``: the stage's default, ``masks.field``), and view 000's true mask lifted with refinement (``true mask``):
   what a perfect cut on the page would give.

The goal printed is IoU ≥ 0.9 per label on every other view (the worst view counts).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import cv2
import numpy as np

from abcgs.gaussians import GaussianModel
from abcgs.io.images import load_image, load_labels, save_labels
from abcgs.masks.content import ContentMasks, label_paths_in, make_content_masks
from abcgs.masks.grabcut import segment
from abcgs.masks.params import LiftParams, MaskParams, RefineParams
from abcgs.masks.strokes import Stroke
from abcgs.types import CalibratedScene
from eval.labels import overlay, score_labels
from eval.record import bench_parser, write_record

GOAL = 0.9
"""Per-label IoU the lifted stroke masks should reach on every other view (the worst one counts)."""


def simulated_strokes(truth: np.ndarray, n_strokes: int = 3, radius: float = 3.0, min_length: float = 6.0) -> list[Stroke]:
    """A user's strokes inside each true region: straight strokes through the region's deepest points.

    For each label (1..max), up to ``n_strokes`` times: take the point deepest inside the region (largest distance to
    its edge: on the medial axis) that is not yet near a stroke, and draw through it the longest straight segment, in
    one of eight directions, that stays ``radius + 2`` px inside the region.

    Args:
        truth: ``(H, W) int`` true labels, 0 = none.

    Returns:
        the strokes, in pixel coordinates (x, y of pixel centres).
    """
    out: list[Stroke] = []
    margin = radius + 2.0
    for k in range(1, int(truth.max()) + 1):
        region = (truth == k).astype(np.uint8)
        if not region.any():
            continue
        depth = cv2.distanceTransform(np.pad(region, 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
        inside = depth > margin
        free = inside.copy()
        for _ in range(n_strokes):
            if not free.any():
                break
            y, x = np.unravel_index(np.argmax(np.where(free, depth, 0)), depth.shape)
            best = None
            for ang in np.arange(8) * np.pi / 8:
                d = np.array([np.cos(ang), np.sin(ang)])
                ends = []
                for sign in (1, -1):
                    t = 0.0
                    while True:
                        px, py = x + sign * (t + 1) * d[0], y + sign * (t + 1) * d[1]
                        ix, iy = int(round(px)), int(round(py))
                        if not (0 <= iy < truth.shape[0] and 0 <= ix < truth.shape[1] and inside[iy, ix]):
                            break
                        t += 1
                    ends.append(np.array([x, y]) + sign * t * d)
                length = float(np.linalg.norm(ends[0] - ends[1]))
                if best is None or length > best[0]:
                    best = (length, ends)
            length, (a, b) = best
            if length < min_length:
                pts = np.array([[x, y]], float)
            else:
                pts = np.linspace(b, a, max(2, int(length // 4) + 1))
            out.append(Stroke(k, pts + 0.5, radius))
            taken = np.zeros_like(region)
            ip = np.round(pts).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(taken, [ip], False, 1, 1)
            cv2.circle(taken, tuple(int(v) for v in ip[0, 0]), 1, 1, -1)
            # spread the strokes out: the next one starts away from this one
            far = cv2.distanceTransform((taken == 0).astype(np.uint8), cv2.DIST_L2, 5)
            free &= far > max(2 * radius + 2, 0.2 * np.sqrt(region.sum()))
    return out


def simulated_session(
    image: np.ndarray, truth: np.ndarray, n_strokes: int = 3, rounds: int = 2, radius: float = 3.0
) -> tuple[list[Stroke], list[dict]]:
    """A user at the page: strokes, Segment, then corrections, with at most ``n_strokes`` strokes per label in all.

    Round 1 draws ``n_strokes - (rounds - 1)`` strokes per label (:func:`simulated_strokes`). Each later round
    segments, and for each label draws one stroke inside the largest part of its true region that the cut gave to
    another label (or left unassigned), as a user fixes what the overlay shows wrong.

    Args:
        image: ``(H, W, 3)`` RGB. truth: ``(H, W) int`` true labels.

    Returns:
        all strokes, and per round ``{"strokes": per-label count, "iou": per label}`` of the cut after the round.
    """
    first = max(1, n_strokes - (rounds - 1))
    strokes = simulated_strokes(truth, first, radius)
    n_labels = int(truth.max())
    log_rounds = []
    seg = None
    for _ in range(rounds):
        if seg is not None:
            for k in range(1, n_labels + 1):
                if sum(s.label == k for s in strokes) >= n_strokes:
                    continue
                missed = (truth == k) & (seg.labels != k)
                n, comp, stats, _ = cv2.connectedComponentsWithStats(missed.astype(np.uint8), connectivity=4)
                if n <= 1:
                    continue
                biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
                fix = simulated_strokes(np.where(comp == biggest, k, 0), 1, radius=min(radius, 2.0))
                strokes += [Stroke(k, s.points, s.radius) for s in fix]
        seg = segment(image, strokes)
        log_rounds.append({
            "strokes": {str(k): sum(s.label == k for s in strokes) for k in range(1, n_labels + 1)},
            "iou": score_labels({0: seg.labels}, {0: truth}, n_labels).iou[0],
        })
    return strokes, log_rounds


def _lifted_record(views: list[np.ndarray], truth: dict[int, np.ndarray], skip: int, n_labels: int) -> dict:
    """Per label: mean and worst IoU of ``views`` against ``truth`` over every view but ``skip``
    (:func:`eval.labels.score_labels`), and the mean pixel agreement (nan if a view's truth assigns no pixel)."""
    scores = score_labels(views, {i: t for i, t in sorted(truth.items()) if i != skip}, n_labels)
    return {"iou_per_label": scores.per_label_summary(), "pixel_agreement": scores.mean_agreement(empty_views="count")}


def _parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = bench_parser(__doc__)
    ap.add_argument("--view", default="000", help="the view the user draws on (image stem)")
    ap.add_argument("--strokes", type=int, default=3, help="strokes per label, at most, in all rounds")
    ap.add_argument("--rounds", type=int, default=1,
                    help="segment → correct rounds; 2 or more: the first round draws fewer strokes, later ones fix errors")
    ap.add_argument("--radius", type=float, default=3.0, help="brush radius (px)")
    ap.add_argument("--iterations", type=int, default=1500, help="fit steps (the tiny pipeline's fit.iterations)")
    ap.add_argument("--work", type=Path, default=None, help="keep the scene, reconstruction and fit here")
    ap.add_argument("--layout", choices=("forward", "orbit"), default="forward",
                    help="the tiny scene's layout (orbit: object-centred, --views cameras on a ring)")
    ap.add_argument("--views", type=int, default=16, help="the tiny scene's n_views")
    ap.add_argument("--propagate-along", choices=("position", "surface"), default="position",
                    help="masks.lift.propagate_along of every lift")
    ap.add_argument("--figure", type=Path, default=None, help="strokes, cut, and the lifted labels in three other views")
    return ap


@contextlib.contextmanager
def _work_folder(work: Path | None) -> Iterator[Path]:
    """``work`` (created if missing, kept), or a temporary folder removed on leaving."""
    if work is None:
        with tempfile.TemporaryDirectory(prefix="abcgs-paint-iou-") as tmp:
            yield Path(tmp)
    else:
        work.mkdir(parents=True, exist_ok=True)
        yield work


def _reconstruct_and_fit(tiny: Path, user: Path, work: Path, iterations: int) -> tuple[CalibratedScene, GaussianModel]:
    """The user's folder ``user`` reconstructed into ``work/colmap`` and fitted for ``iterations`` steps (densifying
    every 25); the tiny scene ``tiny`` with its true label maps reconstructed into ``work/colmap_truth`` by the same
    seeded SfM, so that its undistorted true maps match the user's views (checked: the same cameras)."""
    from abcgs.fit.params import FitParams, StrategyParams
    from abcgs.fit.training import fit
    from abcgs.sfm.model import read_scene
    from abcgs.sfm.params import ReconstructParams
    from abcgs.sources.params import SceneParams
    from abcgs.sources.reconstruct import reconstruct_scene

    rp = ReconstructParams()
    reconstruct_scene(SceneParams.at(user, "photos"), work / "colmap", rp)  # images/ and the strokes' masks/
    reconstruct_scene(SceneParams.at(tiny, "photos"), work / "colmap_truth", rp)  # the same model, seeded; the true masks/
    scene = read_scene(work / "colmap")
    truth_scene = read_scene(work / "colmap_truth")
    for a, b in zip(scene.cameras, truth_scene.cameras):
        assert a.name == b.name and np.allclose(a.viewmat, b.viewmat) and np.allclose(a.K, b.K), "SfM not repeatable"
    it = iterations
    fp = FitParams(iterations=it, test_every=0, max_gaussians=30_000,
                   strategy=StrategyParams(refine_start=min(50, it // 6), refine_every=25,
                                           refine_stop=int(0.8 * it), reset_every=10 * it))
    return scene, fit(scene, fp, progress=False).model


def _lift_three_ways(model: GaussianModel, scene: CalibratedScene, work: Path, view: str,
                     propagate_along: str) -> tuple[ContentMasks, ContentMasks, ContentMasks, float]:
    """The ``masks`` stage on the fitted scene three ways: the strokes' mask of ``view`` (``work/colmap/masks``) with
    refinement, the same without, and ``view``'s true mask alone (copied to ``work/truth_mask_of_view``) with it.

    Returns:
        the three results and the seconds of the first (lift, refine and render).
    """
    only_truth = work / "truth_mask_of_view"
    shutil.rmtree(only_truth, ignore_errors=True)
    only_truth.mkdir()
    shutil.copy(work / "colmap_truth" / "masks" / f"{view}.png", only_truth)
    cams, photos = scene.cameras, scene.image_paths
    t_lift = time.perf_counter()
    lift = LiftParams(propagate_along=propagate_along)
    refine = RefineParams(enabled=True)  # the re-cut is an option of the stage (off by default): these columns run it
    given, truth = label_paths_in(work / "colmap" / "masks", cams), label_paths_in(only_truth, cams)
    lifted = make_content_masks(model, cams, given, MaskParams(source="given", lift=lift, refine=refine), photos,
                                show_progress=False)
    seconds_lift = time.perf_counter() - t_lift
    lift_only = make_content_masks(model, cams, given,
                                   MaskParams(source="given", lift=lift, refine=RefineParams(enabled=False)))
    ceiling = make_content_masks(model, cams, truth, MaskParams(source="given", lift=lift, refine=refine), photos,
                                 show_progress=False)
    return lifted, lift_only, ceiling, seconds_lift


def _print_result(result: dict, n_views: int) -> None:
    """The table of a :func:`main` record: per label the page's cut, lift only, lifted + refined and true mask IoUs
    over the ``n_views`` views scored."""
    n_labels = len(result["strokes_per_label"])
    strokes_score, ceiling_score = result["lifted_from_strokes"], result["lifted_from_true_mask"]
    lift_only_score = result["lifted_from_strokes_without_refinement"]
    print(f"tiny scene, view {result['view']}: {len(result['strokes'])} strokes ({result['strokes_per_label']} per "
          f"label, {len(result['rounds'])} round(s)); fit {result['fit']['iterations']} steps, "
          f"{result['fit']['n_gaussians']:,} Gaussians")
    print(f"{'label':>5} {'cut (2-D)':>10} {'lift only':>10} {'lifted + refined: mean':>23} {'worst':>6} "
          f"{'true mask: mean':>16} {'worst':>6}")
    for k in range(1, n_labels + 1):
        s, c = strokes_score["iou_per_label"][str(k)], ceiling_score["iou_per_label"][str(k)]
        o = lift_only_score["iou_per_label"][str(k)]
        print(f"{k:>5} {result['cut_iou'][str(k)]:10.3f} {o['mean']:10.3f} {s['mean']:23.3f} {s['min']:6.3f} "
              f"{c['mean']:16.3f} {c['min']:6.3f}")
    print(f"IoU on the {n_views} other views; goal ≥ {GOAL} per label on every view: "
          f"{'met' if result['goal_met'] else 'not met'}. Pixel agreement {strokes_score['pixel_agreement']:.3f} "
          f"(true mask {ceiling_score['pixel_agreement']:.3f}); {result['seconds']['total']:.0f} s")


def main(argv: list[str] | None = None) -> dict:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING)

    from abcgs.scene.params import TinySceneParams
    from abcgs.scene.synthetic import make_tiny_scene
    from abcgs.sfm.colmap import set_colmap_log_level

    set_colmap_log_level("error")
    t0 = time.perf_counter()
    with _work_folder(args.work) as work:
        tiny = make_tiny_scene(work / "tiny_source", TinySceneParams(layout=args.layout, n_views=args.views))
        stems = sorted(p.stem for p in (tiny / "images").glob("*.png"))
        if args.view not in stems:
            raise SystemExit(f"--view {args.view}: the tiny scene's views are {stems[0]}..{stems[-1]}")
        image = load_image(tiny / "images" / f"{args.view}.png")
        truth_raw = load_labels(tiny / "masks" / f"{args.view}.png")
        n_labels = int(truth_raw.max())

        t_seg = time.perf_counter()
        strokes, rounds = simulated_session(image, truth_raw, args.strokes, args.rounds, args.radius)
        cut = segment(image, strokes)
        seconds_segment = time.perf_counter() - t_seg

        # the user's scene folder after Save: the views and one label PNG
        user = work / "scene"
        shutil.rmtree(user, ignore_errors=True)
        shutil.copytree(tiny / "images", user / "images")
        save_labels(user / "masks" / f"{args.view}.png", cut.saved_map())  # as the page saves it
        t_fit = time.perf_counter()
        scene, model = _reconstruct_and_fit(tiny, user, work, args.iterations)
        seconds_fit = time.perf_counter() - t_fit

        cams = scene.cameras
        src = {Path(c.name).stem: i for i, c in enumerate(cams)}[args.view]
        truth = {i: load_labels(work / "colmap_truth" / "masks" / f"{Path(c.name).stem}.png") for i, c in enumerate(cams)}
        lifted, lift_only, ceiling, seconds_lift = _lift_three_ways(model, scene, work, args.view, args.propagate_along)
        strokes_score = _lifted_record(lifted.view_labels, truth, src, n_labels)

        result = {
            "scene": f"tiny (layout {args.layout}, {args.views} views)", "view": args.view, "radius": args.radius,
            "propagate_along": args.propagate_along,
            "strokes_per_label": {str(k): sum(s.label == k for s in strokes) for k in range(1, n_labels + 1)},
            "strokes": [{"label": s.label, "radius": s.radius, "from": s.points[0].round(2).tolist(),
                         "to": s.points[-1].round(2).tolist()}
                        for s in strokes],  # straight strokes: their ends
            "rounds": rounds,
            "cut_iou": score_labels({0: cut.labels}, {0: truth_raw}, n_labels).iou[0],
            "lifted_from_strokes": strokes_score,
            "lifted_from_strokes_without_refinement": _lifted_record(lift_only.view_labels, truth, src, n_labels),
            "lifted_from_true_mask": _lifted_record(ceiling.view_labels, truth, src, n_labels),
            "goal": GOAL,
            "goal_met": all(v["min"] >= GOAL for v in strokes_score["iou_per_label"].values()),
            "fit": {"iterations": args.iterations, "n_gaussians": model.num_gaussians},
            "seconds": {"segment": seconds_segment, "reconstruct_and_fit": seconds_fit,
                        "lift_refine_and_render": seconds_lift,
                        "total": time.perf_counter() - t0},
        }
        _print_result(result, len(cams) - 1)
        if args.figure:
            _figure(args.figure, work / "colmap", scene, strokes, cut.labels, image, lifted.view_labels, src)
        if args.json:
            write_record(args.json, result, argv)
        return result

def _figure(path: Path, colmap: Path, scene, strokes: list[Stroke], cut: np.ndarray, image: np.ndarray,
            views: list[np.ndarray], src: int) -> None:
    """Row 1: the strokes and the cut on the drawn view; row 2: the lifted labels in three other views."""
    from abcgs.io.images import save_image
    from abcgs.masks.strokes import rasterize_strokes
    from abcgs.viz import colorize_labels, image_grid

    seeds = rasterize_strokes(strokes, cut.shape)
    drawn = image.copy()
    drawn[seeds > 0] = colorize_labels(seeds[seeds > 0]) / 255.0
    n = len(scene.cameras)
    others = [i for i in range(n) if i != src]
    show = [others[round(t * (len(others) - 1))] for t in (0.3, 0.65, 1.0)]
    top = image_grid([[drawn, overlay(image, cut), overlay(load_image(scene.image_paths[src]), views[src])]],
                     ["the drawn view: strokes", "its colour cut (the page)", "the masks stage's labels"], height=180)
    bottom = image_grid([[overlay(load_image(scene.image_paths[i]), views[i]) for i in show]],
                        [f"view {Path(scene.cameras[i].name).stem}: the masks stage's labels" for i in show], height=180)
    width = max(top.shape[1], bottom.shape[1])  # undistorted views differ in width by a pixel or two
    rows = [np.pad(g, ((0, 0), (0, width - g.shape[1]), (0, 0)), constant_values=255) for g in (top, bottom)]
    save_image(path, np.vstack(rows))


if __name__ == "__main__":
    main()
