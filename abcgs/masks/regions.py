"""A stroke's region in its photo: what a correction on the masks page says beyond the pixels it covers.

A dot or a short stroke on a view already labelled in 3-D means "this part is label k". The pixels it covers bind
the few Gaussians under them (:mod:`abcgs.masks.field`); the part it lies in is larger. :func:`stroke_regions` takes,
for each connected stroke, the photo's pixels connected to it whose colour stays within ``tolerance`` (CIE ΔE*ab,
CIELAB of the photo) of the stroke's mean colour and that lie within ``reach`` of it: a flood fill of the stroke's
colour bounded by the photo's edges, by a disc and, given the view's rendered depth, by the steps of that depth
(:func:`depth_steps`: an object's outline against what lies behind it, which colour alone misses where a pale part sits
before a pale wall). A click (:func:`is_click`: a dot, about as long as it is wide)
stands for the whole part it lies in and reaches further (``click_reach``, ``click_tolerance``) than a stroke, which
stands for the pixels along it. Where two strokes' regions meet, each pixel goes to the one nearer in colour. The map
is the correction's evidence (``masks.field.correction: region``). On a view the page once cut, only the strokes
the cut contradicts are corrections (:func:`corrections`), and their regions lie over the cut: they overrule it where
they reach and leave the rest of it (:func:`view_evidence`). Their pixels beyond the strokes weigh
``masks.field.region_weight`` of a cut's where the cut gave another label. All of it is computed from the photo, the
strokes, the saved map and the fitted Gaussians' depth, so the ``masks`` stage, reading what the page saved, weighs
the same evidence as the page.
"""

from __future__ import annotations

import cv2
import numpy as np

from abcgs.masks.lifting import NO_VOTE
from abcgs.masks.params import FieldParams


def photo_lab(photo: np.ndarray) -> np.ndarray:
    """``photo`` ``(H, W, 3) uint8`` RGB → CIELAB ``(H, W, 3) float32`` (L* 0..100, a*, b* about -128..127),
    lightly smoothed (3 × 3 Gaussian) so that a region is not broken by the sensor's noise."""
    lab = cv2.cvtColor(photo.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB)
    return cv2.GaussianBlur(lab, (3, 3), 0)


CLICK_ROUNDNESS = 0.5
"""A connected mark that fills at least this share of the disc round its longer side is a click (a dot: about as
long as it is wide), not a stroke (:func:`is_click`)."""


def is_click(mark: np.ndarray) -> bool:
    """Whether a connected mark ``(H, W) bool`` is a click, a dot that stands for the part it lies in, rather than a
    stroke along it: its pixels fill at least :data:`CLICK_ROUNDNESS` of the disc whose diameter is its longer side."""
    ys, xs = np.nonzero(mark)
    if not len(ys):
        return False
    side = max(ys.max() - ys.min(), xs.max() - xs.min()) + 1
    return len(ys) >= CLICK_ROUNDNESS * np.pi * (side / 2.0) ** 2


def depth_steps(depth: np.ndarray, step: float, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Where a view's rendered ``depth`` ``(h, w)`` (world units; 0 or less where nothing is rendered) steps, ``(H, W)
    bool`` at ``shape`` (default the depth's): the pixels whose inverse depth differs from a rendered 4-neighbour's by
    more than ``step`` × the larger of the two, brought to ``shape`` and widened by a pixel, so that no 4-connected
    region slips across a step diagonally. Where nothing is rendered there is no step: the depth says nothing there."""
    d = np.asarray(depth, np.float32)
    inv = np.where(np.isfinite(d) & (d > 0), 1.0 / np.maximum(d, 1e-12), 0.0).astype(np.float32)
    edge = np.zeros(inv.shape, bool)
    pairs = ((inv[:-1], inv[1:], edge[:-1], edge[1:]), (inv[:, :-1], inv[:, 1:], edge[:, :-1], edge[:, 1:]))
    for a, b, ea, eb in pairs:
        jump = (a > 0) & (b > 0) & (np.abs(a - b) > step * np.maximum(a, b))
        ea |= jump
        eb |= jump
    if shape is not None and tuple(shape) != edge.shape:
        edge = cv2.resize(edge.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST).astype(bool)
    return cv2.dilate(edge.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)


def stroke_regions(photo: np.ndarray, strokes: np.ndarray, reach_px: int, tolerance: float,
                   click: tuple[int, float] | None = None, barrier: np.ndarray | None = None) -> np.ndarray:
    """Each stroke's region in ``photo`` (module docstring), ``(H, W) int64``: the stroke's label (0 the background
    brush) in its region, :data:`~abcgs.masks.lifting.NO_VOTE` elsewhere; stroke pixels keep their own label.

    Args:
        photo: ``(H, W, 3) uint8`` RGB.
        strokes: ``(H, W) int`` seed map, -1 where no stroke, else the stroke's label.
        reach_px: how far from its stroke a region reaches, in pixels (0: the strokes alone).
        tolerance: the largest CIELAB distance (ΔE*ab) from the stroke's mean colour a region's pixel may have.
        click: ``(reach_px, tolerance)`` of a click's region instead (:func:`is_click`); None: as a stroke's.
        barrier: ``(H, W) bool`` pixels no region enters (:func:`depth_steps`), a stroke's own excepted; None: none.
    """
    h, w = strokes.shape
    if photo.shape[:2] != (h, w):
        raise ValueError(f"the photo is {photo.shape[1]}x{photo.shape[0]}, the strokes {w}x{h}")
    if barrier is not None and barrier.shape != (h, w):
        raise ValueError(f"the barrier is {barrier.shape[1]}x{barrier.shape[0]}, the strokes {w}x{h}")
    out = np.where(strokes >= 0, strokes, NO_VOTE).astype(np.int64)
    if not (strokes >= 0).any():
        return out
    lab = photo_lab(photo)
    best = np.full((h, w), np.inf, np.float32)  # colour distance of the region that holds each pixel
    for k in np.unique(strokes[strokes >= 0]):
        n, comp = cv2.connectedComponents((strokes == k).astype(np.uint8), connectivity=8)
        for c in range(1, n):
            mine = comp == c
            reach, tol = click if click is not None and is_click(mine) else (reach_px, tolerance)
            if reach <= 0 or tol <= 0:
                continue
            ys, xs = np.nonzero(mine)
            y0, y1 = max(0, ys.min() - reach), min(h, ys.max() + reach + 1)
            x0, x1 = max(0, xs.min() - reach), min(w, xs.max() + reach + 1)
            box = mine[y0:y1, x0:x1]
            near = cv2.distanceTransform((~box).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE) <= reach
            dist = np.linalg.norm(lab[y0:y1, x0:x1] - lab[y0:y1, x0:x1][box].mean(0), axis=-1)
            cand = near & (dist <= tol)
            if barrier is not None:
                cand &= ~barrier[y0:y1, x0:x1]
            cand |= box
            m, parts = cv2.connectedComponents(cand.astype(np.uint8), connectivity=4)
            touched = np.unique(parts[box])
            region = np.isin(parts, touched[touched > 0])
            sub_best = best[y0:y1, x0:x1]
            take = region & (dist < sub_best)
            sub_best[take] = dist[take]
            out[y0:y1, x0:x1][take] = k
    return np.where(strokes >= 0, strokes, out).astype(np.int64)


def view_regions(photo: np.ndarray, strokes: np.ndarray, params: FieldParams,
                 depth: np.ndarray | None = None) -> np.ndarray:
    """:func:`stroke_regions` of a view's ``strokes`` ``(H, W) int`` on its ``photo`` ``(H, W, 3) uint8`` as the masks
    page makes them: reach ``params.correction_reach`` × the view's shorter side and tolerance
    ``params.region_tolerance``; a click's ``click_reach`` and ``click_tolerance``; bounded by the steps of the view's
    rendered ``depth`` ``(h, w)`` (:func:`depth_steps`, ``params.region_depth_step``; None or 0: by colour alone)."""
    short = min(strokes.shape)
    barrier = None
    if depth is not None and params.region_depth_step > 0 and (strokes >= 0).any():
        barrier = depth_steps(depth, params.region_depth_step, strokes.shape)
    return stroke_regions(photo, strokes, int(round(params.correction_reach * short)), params.region_tolerance,
                          click=(int(round(params.click_reach * short)), params.click_tolerance), barrier=barrier)


def corrections(strokes: np.ndarray, cut: np.ndarray | None) -> np.ndarray:
    """The strokes of a seed map ``(H, W) int`` (-1 none, 0..L) that correct ``cut`` ``(H, W) int`` (0..L,
    :data:`~abcgs.masks.lifting.NO_VOTE`): each connected stroke of which some pixel the cut does not give the stroke's
    label; the others (the strokes the cut was seeded with, or that it agrees with) are left out (-1). No cut: all."""
    strokes = np.asarray(strokes, np.int64)
    if cut is None:
        return strokes
    out = strokes.copy()
    for k in np.unique(strokes[strokes >= 0]):
        n, comp = cv2.connectedComponents((strokes == k).astype(np.uint8), connectivity=8)
        agree = np.bincount(comp.ravel(), weights=(cut == k).ravel(), minlength=n)
        size = np.bincount(comp.ravel(), minlength=n)
        out[(comp > 0) & (agree == size)[comp]] = -1
    return out


def correction_regions(photo: np.ndarray, strokes: np.ndarray, params: FieldParams,
                       depth: np.ndarray | None = None) -> np.ndarray | None:
    """What a view's correcting ``strokes`` ``(H, W) int`` (:func:`corrections`) say beyond the pixels they cover, on
    its ``photo`` ``(H, W, 3) uint8`` (and its rendered ``depth``), as ``params.correction`` has it: ``region``, their
    colour regions (:func:`view_regions`); ``strokes``, the strokes alone (``(H, W) int64``,
    :data:`~abcgs.masks.lifting.NO_VOTE` elsewhere); ``cut``, None (the view is cut again instead). The masks page and the ``masks`` stage both lay them
    over the view's cut (:func:`view_evidence`), so that a correction on a view once cut overrules the cut where it
    lies and keeps the rest of it."""
    if params.correction == "cut":
        return None
    if params.correction == "strokes":
        return np.where(strokes >= 0, strokes, NO_VOTE).astype(np.int64)
    return view_regions(photo, strokes, params, depth)


def view_evidence(cut: np.ndarray | None, strokes: np.ndarray | None, photo: np.ndarray, params: FieldParams,
                  depth: np.ndarray | None = None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A painted view's cut and its corrections' regions ``(cut, regions)``, each ``(H, W) int64`` (0..L,
    :data:`~abcgs.masks.lifting.NO_VOTE`) or None, as the masks page sets them in its 3-D labels
    (:meth:`abcgs.masks.field.LabelField.set_view`) from the view's ``cut`` (None: the page never cut it), its
    ``strokes`` ``(H, W) int``, ``photo`` ``(H, W, 3) uint8`` and rendered ``depth`` ``(h, w)``
    (:meth:`~abcgs.masks.field.LabelField.depth_of`; None: the regions are not bounded by depth): its strokes that
    correct the cut (:func:`corrections`) and their regions (:func:`correction_regions`). The page saves the cut, or
    the regions of a view it never cut (:meth:`~abcgs.masks.field.LabelField.saved_of`); the ``masks`` stage passes
    that map as ``cut`` and gets the same pair back: a map equal to the regions of all the view's strokes is those
    regions, not a cut (which it can be only if no stroke corrects it: the regions keep their strokes' labels)."""
    if strokes is None or params.correction == "cut":
        return cut, None
    if cut is None:
        return None, correction_regions(photo, strokes, params, depth)
    cut, fixes = np.asarray(cut, np.int64), corrections(strokes, cut)
    if not (fixes >= 0).any():
        every = correction_regions(photo, strokes, params, depth)
        if np.array_equal(cut, every):
            return None, every
    return cut, correction_regions(photo, fixes, params, depth)
