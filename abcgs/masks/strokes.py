"""The strokes a user paints on a view and the segmentation a cut makes of them: the types the masks page
(:mod:`abcgs.masks.page`) and the label algorithms share.

- :class:`Stroke` — one brush stroke in a view's pixels, read from the page's JSON with clear errors.
- :func:`rasterize_strokes` — strokes → a seed map (-1 none, 0 the background brush, k label k).
- :class:`Segmentation` — one view's labels, which pixels something decided, and how sure the cut is.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import cv2
import numpy as np

from abcgs.errors import InputError
from abcgs.masks.params import UNDECIDED

BACKGROUND = 0
"""Stroke label of the background brush: certain background for every label, unassigned (0) in the saved map."""


@dataclass
class Stroke:
    """One brush stroke in image pixel coordinates.

    Attributes:
        label: 1..N paints that label; :data:`BACKGROUND` (0) is the background brush.
        points: ``(P, 2) float`` x (right), y (down) of the polyline, pixel j spanning [j, j + 1) as in the
            browser; a single point is a dot.
        radius: brush radius in pixels.
    """

    label: int
    points: np.ndarray
    radius: float = 3.0

    @classmethod
    def from_json(cls, data: dict) -> Stroke:
        """``{"label": int, "points": [[x, y], …], "radius": float}`` → :class:`Stroke` (clear errors on bad input: a
        label must be an integer 0..254, not a number that rounds to one)."""
        try:
            label = data["label"]
            if not isinstance(label, int) or isinstance(label, bool):
                raise TypeError(f"the label must be an integer, not {json.dumps(label)[:40]}")
            pts = np.asarray(data["points"], dtype=np.float64).reshape(-1, 2)
            radius = float(data.get("radius", 3.0))
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise InputError(f"a stroke must be {{'label': int, 'points': [[x, y], ...], 'radius': float}}: {exc}") from exc
        if label < 0 or label >= UNDECIDED:
            raise InputError(f"stroke label {label} is outside 0..{UNDECIDED - 1} (0 is the background brush)")
        if len(pts) == 0 or not np.isfinite(pts).all() or not (0 < radius < 1e4):
            raise InputError("a stroke needs at least one finite point and a radius > 0")
        return cls(label, pts, radius)

    def to_json(self) -> dict:
        return {"label": self.label, "points": self.points.tolist(), "radius": self.radius}


def rasterize_strokes(strokes: list[Stroke], hw: tuple[int, int], scale: float = 1.0) -> np.ndarray:
    """Strokes → seed map ``(H, W) int64``: -1 = no stroke, 0 = background brush, k = label k.

    Later strokes paint over earlier ones. ``scale`` multiplies the coordinates and radii (segmenting a
    downscaled copy of the view).
    """
    seeds = np.full(hw, -1, np.int16)
    shift = 4  # sub-pixel precision of cv2's drawing: coordinates in 1/16 px
    for s in strokes:
        pts = np.round((s.points * scale - 0.5) * (1 << shift)).astype(np.int32)
        r = max(1, int(round(s.radius * scale * (1 << shift))))
        colour = int(s.label)
        thick = max(1, int(round(2 * s.radius * scale)))
        if len(pts) == 1:
            cv2.circle(seeds, tuple(int(v) for v in pts[0]), r, colour, -1, cv2.LINE_8, shift)
        else:
            cv2.polylines(seeds, [pts.reshape(-1, 1, 2)], False, colour, thick, cv2.LINE_8, shift)
            for p in (pts[0], pts[-1]):  # round caps
                cv2.circle(seeds, tuple(int(v) for v in p), r, colour, -1, cv2.LINE_8, shift)
    return seeds.astype(np.int64)


@dataclass
class Segmentation:
    """The label map of one view and what decided it.

    Attributes:
        labels: ``(H, W) int64``, 0 = unassigned, k = label k.
        claimed: ``(H, W) bool``: a cut, a stroke or the gap fill gave the pixel its value (the background's
            included); False where nothing did and the 0 means "undecided" rather than "unassigned".
        probability: per label k, GrabCut's foreground probability ``(H, W) float32`` (its colour models' posterior).
        margin: ``(H, W) float32`` in 0..1, how sure the cut is at each pixel: ``|2p - 1|`` of the winning cut's
            foreground probability ``p`` (0 where its two colour models agree, 1 where one alone explains the pixel),
            1 on strokes, :data:`abcgs.masks.grabcut.FILL_MARGIN` where the gap fill decided, 0 where nothing claimed the pixel.
        seconds: time spent.
        saved: ``(H, W) int64`` what the page saves of the view instead of the claimed labels, or None.
    """

    labels: np.ndarray
    claimed: np.ndarray
    probability: dict[int, np.ndarray] = field(default_factory=dict)
    margin: np.ndarray | None = None
    seconds: float = 0.0
    saved: np.ndarray | None = None

    def saved_map(self) -> np.ndarray:
        """The label PNG's content ``(H, W) int64``: ``saved`` where given (what the page's 3-D labels keep of the
        view, :meth:`abcgs.masks.field.LabelField.saved_of`), else the labels, 0 where the background was decided,
        and :data:`UNDECIDED` where nothing claimed the pixel."""
        if self.saved is not None:
            return np.asarray(self.saved, np.int64)
        return np.where(self.claimed, self.labels, UNDECIDED).astype(np.int64)

    def counts(self) -> dict[int, int]:
        vals, cnt = np.unique(self.labels, return_counts=True)
        return {int(v): int(c) for v, c in zip(vals, cnt)}
