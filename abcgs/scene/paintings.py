"""The tiny scene's two procedural paintings (:func:`make_paintings`): brush strokes along a swirling flow field, a
different palette in each of three wavy regions for ``paint`` (its region map is the semantic transfer's), broader
strokes and a few hard-edged circles for ``paint2``. Seeded, so the files are byte-identical for one seed."""

from __future__ import annotations

import cv2
import numpy as np


def _region_labels(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Three wavy regions ``(h, w) int64``: 1 = top band, 2 = lower left, 3 = lower right."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    ph = rng.uniform(0, 2 * np.pi, size=2)
    horizon = h * (0.45 + 0.06 * np.sin(x / w * 2 * np.pi * 1.5 + ph[0]))
    divide = w * (0.5 + 0.08 * np.sin(y / h * 2 * np.pi + ph[1]))
    return np.where(y < horizon, 1, np.where(x < divide, 2, 3)).astype(np.int64)


def _strokes(rng: np.random.Generator, h: int, w: int, palette: np.ndarray, n: int, swirl: float) -> np.ndarray:
    """A canvas ``(h, w, 3) uint8`` covered in brush strokes following a swirling flow field."""
    canvas = np.empty((h, w, 3), np.uint8)
    canvas[:] = palette[0]
    ph = rng.uniform(0, 2 * np.pi, size=3)
    for _ in range(n):
        x, y = rng.uniform(0, w), rng.uniform(0, h)
        pts = [(x, y)]
        length = int(rng.integers(4, 12))
        for _ in range(length):
            ang = swirl * np.sin(x / w * 6 + ph[0]) + swirl * np.cos(y / h * 5 + ph[1]) + ph[2]
            x, y = x + 3.0 * np.cos(ang), y + 3.0 * np.sin(ang)
            pts.append((x, y))
        colour = palette[rng.integers(0, len(palette))].astype(np.float64) + rng.normal(0, 18, size=3)
        colour = tuple(int(c) for c in np.clip(colour, 0, 255))
        thick = int(rng.integers(2, 7))
        cv2.polylines(canvas, [np.round(np.array(pts)).astype(np.int32)], False, colour, thick, cv2.LINE_AA)
    return canvas


_PAINT_PALETTES = (  # RGB; vivid blues/yellows/greens, unlike the scene's muted browns and greys
    np.array([[20, 40, 120], [40, 90, 200], [90, 150, 240], [230, 230, 250], [250, 210, 40]]),
    np.array([[240, 190, 20], [250, 140, 0], [255, 230, 120], [180, 90, 10], [60, 40, 120]]),
    np.array([[10, 110, 60], [40, 170, 90], [150, 220, 60], [0, 60, 40], [220, 40, 90]]),
)
_PAINT2_PALETTE = np.array([[200, 20, 40], [250, 80, 150], [120, 0, 140], [30, 20, 30], [250, 240, 220], [255, 120, 40]])


def make_paintings(rng: np.random.Generator, height: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Two procedural paintings (4:3, ``height`` px high) and the 3-region label map of the first.

    ``paint``: swirling strokes, a different palette in each labelled region (sky blues, yellows, greens).
    ``paint2``: reds/magentas/purples with broader strokes and a few hard-edged geometric shapes.
    Returns ``({"paint": (H, W, 3), "paint2": (H, W, 3)} float32 in [0, 1], labels (H, W) int64)``.
    """
    h, w = height, round(height * 4 / 3)
    labels = _region_labels(rng, h, w)
    paint = np.zeros((h, w, 3), np.uint8)
    for lab, pal in enumerate(_PAINT_PALETTES, start=1):
        layer = _strokes(rng, h, w, pal, n=int(0.04 * h * w), swirl=1.4)
        paint[labels == lab] = layer[labels == lab]
    paint2 = _strokes(rng, h, w, _PAINT2_PALETTE, n=int(0.03 * h * w), swirl=0.6)
    for _ in range(6):
        colour = tuple(int(c) for c in _PAINT2_PALETTE[rng.integers(0, len(_PAINT2_PALETTE))])
        cx, cy, r = int(rng.integers(0, w)), int(rng.integers(0, h)), int(rng.integers(h // 16, h // 6))
        cv2.circle(paint2, (cx, cy), r, colour, max(2, h // 64), cv2.LINE_AA)
    styles = {"paint": paint.astype(np.float32) / 255.0, "paint2": paint2.astype(np.float32) / 255.0}
    return styles, labels
