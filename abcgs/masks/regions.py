"""A stroke's region in its photo: what a correction on the masks page says beyond the pixels it covers.

A dot or a short stroke on a view already labelled in 3-D means "this part is label k". The pixels it covers bind
the few Gaussians under them (:mod:`abcgs.masks.field`); the part it lies in is larger. :func:`stroke_regions` takes,
for each connected stroke, the photo's pixels connected to it whose colour stays within ``tolerance`` (CIE ΔE*ab,
CIELAB of the photo) of the stroke's mean colour and that lie within ``reach`` of it: a flood fill of the stroke's
colour bounded by the photo's edges and by a disc. Where two strokes' regions meet, each pixel goes to the one nearer
in colour. The map is the correction's evidence (``masks.field.correction: region``): it is computed from the photo
and the strokes alone, so the ``masks`` stage, reading the label map the page saved, weighs the same evidence as the
page did, and knows it for a correction's regions (:func:`are_view_regions`): their pixels beyond the strokes weigh
``masks.field.region_weight`` of a cut's.
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


def stroke_regions(photo: np.ndarray, strokes: np.ndarray, reach_px: int, tolerance: float) -> np.ndarray:
    """Each stroke's region in ``photo`` (module docstring), ``(H, W) int64``: the stroke's label (0 the background
    brush) in its region, :data:`~abcgs.masks.lifting.NO_VOTE` elsewhere; stroke pixels keep their own label.

    Args:
        photo: ``(H, W, 3) uint8`` RGB.
        strokes: ``(H, W) int`` seed map, -1 where no stroke, else the stroke's label.
        reach_px: how far from its stroke a region reaches, in pixels (0: the strokes alone).
        tolerance: the largest CIELAB distance (ΔE*ab) from the stroke's mean colour a region's pixel may have.
    """
    h, w = strokes.shape
    if photo.shape[:2] != (h, w):
        raise ValueError(f"the photo is {photo.shape[1]}x{photo.shape[0]}, the strokes {w}x{h}")
    out = np.where(strokes >= 0, strokes, NO_VOTE).astype(np.int64)
    if reach_px <= 0 or tolerance <= 0 or not (strokes >= 0).any():
        return out
    lab = photo_lab(photo)
    best = np.full((h, w), np.inf, np.float32)  # colour distance of the region that holds each pixel
    for k in np.unique(strokes[strokes >= 0]):
        n, comp = cv2.connectedComponents((strokes == k).astype(np.uint8), connectivity=8)
        for c in range(1, n):
            mine = comp == c
            ys, xs = np.nonzero(mine)
            y0, y1 = max(0, ys.min() - reach_px), min(h, ys.max() + reach_px + 1)
            x0, x1 = max(0, xs.min() - reach_px), min(w, xs.max() + reach_px + 1)
            box = mine[y0:y1, x0:x1]
            near = cv2.distanceTransform((~box).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE) <= reach_px
            dist = np.linalg.norm(lab[y0:y1, x0:x1] - lab[y0:y1, x0:x1][box].mean(0), axis=-1)
            cand = (near & (dist <= tolerance)) | box
            m, parts = cv2.connectedComponents(cand.astype(np.uint8), connectivity=4)
            touched = np.unique(parts[box])
            region = np.isin(parts, touched[touched > 0])
            sub_best = best[y0:y1, x0:x1]
            take = region & (dist < sub_best)
            sub_best[take] = dist[take]
            out[y0:y1, x0:x1][take] = k
    return np.where(strokes >= 0, strokes, out).astype(np.int64)


def view_regions(photo: np.ndarray, strokes: np.ndarray, params: FieldParams) -> np.ndarray:
    """:func:`stroke_regions` of a view's ``strokes`` ``(H, W) int`` on its ``photo`` ``(H, W, 3) uint8`` as the masks
    page makes them: reach ``params.correction_reach`` × the view's shorter side, tolerance ``params.region_tolerance``."""
    reach = int(round(params.correction_reach * min(strokes.shape)))
    return stroke_regions(photo, strokes, reach, params.region_tolerance)


def are_view_regions(label_map: np.ndarray, photo: np.ndarray, strokes: np.ndarray | None,
                     params: FieldParams) -> bool:
    """Whether a painted view's ``label_map`` ``(H, W) int`` (0..L, :data:`NO_VOTE` undecided) is its ``strokes``'
    regions (:func:`view_regions`, what the page saves for a correction) rather than a cut of the view: with
    ``correction: region``, the map equals them pixel for pixel."""
    if strokes is None or params.correction != "region" or not (strokes >= 0).any():
        return False
    if photo.shape[:2] != label_map.shape or strokes.shape != label_map.shape:
        return False
    return bool(np.array_equal(view_regions(photo, strokes, params), np.asarray(label_map, np.int64)))
