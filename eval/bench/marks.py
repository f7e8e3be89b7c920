"""Where a scripted user's next mark goes and what it is (:mod:`eval.bench.scripted_user`): the wrong region a
target picks among the reference views' labels (:func:`next_region`), and a dot or a straight stroke inside it."""

from __future__ import annotations

from typing import Literal

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import cv2
import numpy as np

from abcgs.masks.strokes import Stroke

Clicks = Literal["dot", "stroke", "ideal"]
"""What each scripted mark is and gives the page: ``dot``, a dot (:func:`next_stroke`) that the page turns into a
region (``masks.field.correction``), as the click benchmarks (NoC) count; ``stroke``, a straight brush stroke across
the same wrong region (:func:`line_inside`), as a user paints on the page; ``ideal``, the dot and, as the view's
evidence, the whole wrong region it lies in with its reference label (:func:`largest_wrong_region`): a perfect part
mask per click, the most a better 2-D step could bring."""
Target = Literal["view", "pair", "gain"]
"""Where each scripted mark goes (:func:`next_region`): ``view``, the largest wrong region of the reference view that
is worst now (lowest mean IoU over its labels); ``pair``, the largest wrong region that involves the (view, label) pair
furthest below its goal (:func:`pair_goal`), and once every pair meets its goal, as ``view``: a user who fixes first
the part that is worst against what the geometry allows; ``gain``, the wrong region, on any reference view, whose
setting right would raise the mean IoU the most (:func:`costliest_wrong_region`): a user who looks over every view and
fixes the error that costs the most, wherever it is, the views already painted included."""
STROKE_LENGTH = 0.2
"""A scripted stroke's largest length, a share of the view's shorter side (74 pixels on miku's 493 × 370 views, where
the test strokes are 30–75 pixels long)."""

GOAL = {"strokes": 10, "mean_iou": 0.75, "pair_iou": 0.60, "below_bound": 0.05, "unlabelled": 0.02,
        "mean_drop": 0.01, "view_drop": 0.03}


def largest_wrong_region(pred: np.ndarray, truth: np.ndarray) -> tuple[int, np.ndarray] | None:
    """The largest connected region ``(H, W) bool`` of ``pred`` whose label differs from ``truth`` (pixels where
    ``truth`` is a label > 0) and its reference label; None when none is wrong."""
    best = None
    for k in np.unique(truth[truth > 0]):
        wrong = ((truth == k) & (pred != k)).astype(np.uint8)
        n, comp, stats, _ = cv2.connectedComponentsWithStats(wrong, connectivity=8)
        for c in range(1, n):
            area = stats[c, cv2.CC_STAT_AREA]
            if best is None or area > best[0]:
                best = (area, int(k), comp == c)
    return None if best is None else best[1:]


def costliest_wrong_region(maps: dict[str, np.ndarray],
                           refs: dict[str, np.ndarray]) -> tuple[str, tuple[int, np.ndarray]] | None:
    """Over the reference views ``refs`` and their labels ``maps``, the connected region ``(H, W) bool`` of pixels of
    reference label k labelled j ≠ k that, set right, would raise the view's IoU of k and of j the most together
    (k's intersection grows by the region, j's union shrinks by it), with its view and k; None when none is wrong."""
    best = None
    for v, truth in refs.items():
        pred = maps[v]
        labels = np.unique(truth[truth > 0])
        inter = {int(k): float(((truth == k) & (pred == k)).sum()) for k in labels}
        union = {int(k): max(1.0, float(((truth == k) | (pred == k)).sum())) for k in labels}
        for k in labels:
            for j in np.unique(pred[(truth == k) & (pred != k)]):
                n, comp, stats, _ = cv2.connectedComponentsWithStats(((truth == k) & (pred == j)).astype(np.uint8),
                                                                     connectivity=8)
                c = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
                area = float(stats[c, cv2.CC_STAT_AREA])
                gain = area / union[int(k)]
                if int(j) in inter:  # j scored in this view: its union loses the region
                    gain += inter[int(j)] / max(1.0, union[int(j)] - area) - inter[int(j)] / union[int(j)]
                if best is None or gain > best[0]:
                    best = (gain, v, int(k), comp == c)
    return None if best is None else (best[1], (best[2], best[3]))


def pair_goal(bound: dict, view: str, label: str) -> float:
    """The IoU the goal asks of pair (``view``, ``label``): min(0.60, its bound − 0.05), ``bound`` as
    :func:`eval.bench.strokes.geometry_bound` returns it (a pair the bound lacks: 0.60)."""
    return min(GOAL["pair_iou"], bound["per_view"][view].get(label, 1.0) - GOAL["below_bound"])


def next_region(maps: dict[str, np.ndarray], refs: dict[str, np.ndarray], iou: dict[str, dict[str, float]],
                target: Target = "view", bound: dict | None = None) -> tuple[str, tuple[int, np.ndarray]] | None:
    """The reference view and the wrong region there (its reference label and ``(H, W) bool``,
    :func:`largest_wrong_region`) that the next mark goes to, as ``target`` says (:data:`Target`), from each view's
    labels ``maps``, its reference ``refs`` and their IoU per label ``iou``; ``bound`` (for ``pair``) as
    :func:`pair_goal` takes it. None when no reference view has a wrong pixel."""
    if target == "gain":
        return costliest_wrong_region(maps, refs)
    if target == "pair":
        if bound is None:
            raise ValueError("target pair needs the bound each pair's goal is held against")
        short = {(v, k): pair_goal(bound, v, k) - x for v, per in iou.items() for k, x in per.items()}
        (v, k), gap = max(short.items(), key=lambda kv: kv[1])
        if gap > 0:  # the errors that involve label k: every other pixel as the reference has it
            mine = (refs[v] == int(k)) | (maps[v] == int(k))
            wrong = largest_wrong_region(np.where(mine, maps[v], refs[v]), refs[v])
            if wrong is not None:
                return v, wrong
    view_means = {v: float(np.mean(list(per.values()))) for v, per in iou.items()}
    worst = min(view_means, key=view_means.get)
    wrong = largest_wrong_region(maps[worst], refs[worst])
    return None if wrong is None else (worst, wrong)


def next_stroke(pred: np.ndarray, truth: np.ndarray, radius: float) -> Stroke | None:
    """A dot of the reference label at the interior-most pixel of the largest connected region of ``pred`` whose label
    differs from ``truth`` (:func:`largest_wrong_region`); None when none is wrong. Its radius is ``radius`` or less,
    to stay inside the region."""
    wrong = largest_wrong_region(pred, truth)
    return None if wrong is None else dot_inside(*wrong, radius)


def _interior(region: np.ndarray, radius: float) -> tuple[np.ndarray, int, int, float]:
    """``region``'s distance to its edge ``(H, W) float32``, its interior-most pixel (x, y) and the brush radius
    there that stays inside it (``radius`` or less, at least 1)."""
    dist = cv2.distanceTransform(np.pad(region, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
    y, x = np.unravel_index(int(np.argmax(dist)), dist.shape)
    return dist, int(x), int(y), float(max(1.0, min(radius, dist[y, x] - 1.0)))


def dot_inside(label: int, region: np.ndarray, radius: float) -> Stroke:
    """A dot of ``label`` at the interior-most pixel of ``region`` ``(H, W) bool`` (largest distance to its edge),
    of radius ``radius`` or less, to stay inside it."""
    _, x, y, r = _interior(region, radius)
    return Stroke(label, np.array([[x + 0.5, y + 0.5]]), r)


def line_inside(label: int, region: np.ndarray, radius: float, length: float) -> Stroke:
    """A straight stroke of ``label`` across ``region`` ``(H, W) bool``: through its interior-most pixel (as
    :func:`dot_inside`) along the region's longest axis (the principal axis of its pixels), ``length`` pixels long
    where the region has room for it (centred on that pixel where both ways do), its brush (``radius`` or less)
    inside the region all along."""
    dist, x, y, r = _interior(region, radius)
    ys, xs = np.nonzero(region)
    axis = np.array([1.0, 0.0])
    if len(xs) > 2:
        axis = np.linalg.eigh(np.cov(np.stack([xs, ys]).astype(np.float64)))[1][:, -1]
    room = []  # how far the brush stays inside, each way along the axis (up to the whole length)
    for sign in (-1.0, 1.0):
        t = 0
        while t + 1 <= length:
            px, py = np.rint([x + sign * (t + 1) * axis[0], y + sign * (t + 1) * axis[1]]).astype(int)
            if not (0 <= py < dist.shape[0] and 0 <= px < dist.shape[1]) or dist[py, px] < r + 1.0:
                break
            t += 1
        room.append(t)
    back = min(room[0], max(length / 2, length - room[1]))  # centred where both ways have room, else shifted
    ahead = min(room[1], length - back)
    ends = [[x + 0.5 + sign * t * axis[0], y + 0.5 + sign * t * axis[1]] for sign, t in ((-1.0, back), (1.0, ahead))]
    return Stroke(label, np.array(ends), r)
