"""Masks from strokes: GrabCut guided by a user's scribbles (Rother et al. 2004), drawn on a local web page.

    python -m abcgs.masks.paint data/tiny                      # views of <scene>/images/ → <scene>/masks/<stem>.png
    python -m abcgs.masks.paint data/tiny --painting data/tiny/styles/paint.png \\
        --labels-out data/tiny/styles/paint_labels.png         # one painting → its region label map

The page (``static/paint.html``, plain JavaScript, nothing fetched from the network) is served on 127.0.0.1. Pick
a label, draw strokes over the objects of one or more views, press **Segment** to see the cut over the view, add
strokes where it is wrong, and press **Save**: every view with strokes gets a single-channel label PNG (0 =
unassigned, 1, 2, …; the format :func:`abcgs.masks.content.read_label_files` reads), written atomically. Views
without strokes get no file: the ``masks`` stage lifts labels from any subset of views (Eq. 2).

The segmentation is a pure function over arrays (:func:`segment`); the server only keeps strokes and results per
view. For each label k (and the background brush, when used), GrabCut runs once, k against the rest: k's strokes
are certain foreground (``GC_FGD``), every other stroke certain background (``GC_BGD``), unstroked pixels probable
background (``GC_PR_BGD``; GrabCut then moves them). The parts of k's cut that no k-stroke touches are dropped (a
stroke marks the region it lies in). Where cuts overlap, the one with the higher GrabCut foreground probability (the
posterior of its colour models) wins. Gaps no cut claims take, per connected gap, the label around it whose strokes
are nearest in colour, when it clearly is (``fill``, :data:`FILL_MAJORITY`; off, gaps stay 0). Pixels the background wins are 0. The cut uses colour only:
no depth cue, so no fitted scene is needed.
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import sys
import threading
import time
import webbrowser
from dataclasses import dataclass, field
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import cv2
import numpy as np

from abcgs.errors import AbcgsError, InputError
from abcgs.io.images import IMAGE_SUFFIXES, load_image, save_labels, to_uint8

log = logging.getLogger(__name__)

PAGE = Path(__file__).resolve().parent / "static" / "paint.html"
"""The drawing page (HTML + plain JavaScript in one file)."""

BACKGROUND = 0
"""Stroke label of the background brush: certain background for every label, unassigned (0) in the saved map."""

FILL_MAJORITY = 0.7
"""A gap between several cuts takes the label nearest in colour for at least this share of its pixels, or stays 0.
On the tiny scene's textured views a plain majority gives large gaps of wall to an object (box IoU 0.96 → 0.63 from
strokes that differed by 26 pixels); at 0.7 such gaps stay unassigned."""

GMM_COMPONENTS = 5
"""Gaussians per colour model in OpenCV's GrabCut (its model array is ``1 × 13·GMM_COMPONENTS``)."""

PALETTE = np.array(
    [[0, 0, 0], [230, 25, 75], [60, 180, 75], [255, 225, 25], [0, 130, 200], [245, 130, 48], [145, 30, 180],
     [70, 240, 240], [240, 50, 230], [210, 245, 60], [250, 190, 212], [0, 128, 128], [220, 190, 255],
     [170, 110, 40], [255, 250, 200], [128, 0, 0], [170, 255, 195]], np.uint8)
"""RGB of labels 0, 1, … (cycled past the end); the same colours as :func:`abcgs.masks.content.colorize_labels`."""


# ----------------------------------------------------------------------------------------------
# Strokes and segmentation: pure functions over arrays
# ----------------------------------------------------------------------------------------------


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
        """``{"label": int, "points": [[x, y], …], "radius": float}`` → :class:`Stroke` (clear errors on bad input)."""
        try:
            label = int(data["label"])
            pts = np.asarray(data["points"], dtype=np.float64).reshape(-1, 2)
            radius = float(data.get("radius", 3.0))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"a stroke must be {{'label': int, 'points': [[x, y], ...], 'radius': float}}: {exc}") from exc
        if label < 0 or label > 255:
            raise InputError(f"stroke label {label} is outside 0..255 (0 is the background brush)")
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
        probability: per label k, GrabCut's foreground probability ``(H, W) float32`` (its colour models' posterior).
        seconds: time spent.
    """

    labels: np.ndarray
    probability: dict[int, np.ndarray] = field(default_factory=dict)
    seconds: float = 0.0

    def counts(self) -> dict[int, int]:
        vals, cnt = np.unique(self.labels, return_counts=True)
        return {int(v): int(c) for v, c in zip(vals, cnt)}


def gmm_log_density(model: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Log density of OpenCV GrabCut's colour model at ``pixels``.

    Args:
        model: the ``(1, 65) float64`` array :func:`cv2.grabCut` fills (5 weights, 5 × 3 means, 5 × 3 × 3
            covariances, in the channel order of the image it was given).
        pixels: ``(N, 3)`` colours in that order, 0..255.

    Returns:
        ``(N,) float64``.
    """
    k = GMM_COMPONENTS
    flat = np.asarray(model, np.float64).reshape(-1)
    weights, means, covs = flat[:k], flat[k:4 * k].reshape(k, 3), flat[4 * k:13 * k].reshape(k, 3, 3)
    x = np.asarray(pixels, np.float64)
    terms = []
    for w, mu, cov in zip(weights, means, covs):
        if w <= 0:
            continue
        cov = cov + np.eye(3) * 1e-2  # a small ridge keeps a near-singular component invertible
        inv, logdet = np.linalg.inv(cov), np.linalg.slogdet(cov)[1]
        d = x - mu
        maha = np.einsum("ni,ij,nj->n", d, inv, d)
        terms.append(np.log(w) - 0.5 * (maha + logdet + 3 * np.log(2 * np.pi)))
    if not terms:
        return np.full(len(x), -np.inf)
    return np.logaddexp.reduce(np.stack(terms), axis=0)


def _grabcut_one(bgr: np.ndarray, seeds: np.ndarray, k: int, iterations: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """GrabCut of seed value ``k`` against the rest: ``(cut (H, W) bool, fg model, bg model)``."""
    mask = np.full(seeds.shape, cv2.GC_PR_BGD, np.uint8)
    mask[seeds >= 0] = cv2.GC_BGD
    mask[seeds == k] = cv2.GC_FGD
    if not (mask != cv2.GC_FGD).any():
        raise InputError(f"the strokes of {'the background' if k == BACKGROUND else f'label {k}'} cover the whole "
                         "view; leave some of it unpainted")
    bgd, fgd = np.zeros((1, 13 * GMM_COMPONENTS), np.float64), np.zeros((1, 13 * GMM_COMPONENTS), np.float64)
    cv2.setRNGSeed(0)
    try:
        cv2.grabCut(bgr, mask, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    except cv2.error as exc:
        raise InputError(f"GrabCut could not cut label {k}: {exc.err}") from exc
    return (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD), fgd, bgd


def _colour_distances(lab: np.ndarray, seeds: np.ndarray, centres: int = 24) -> dict[int, np.ndarray]:
    """Per seed value (label or background), each pixel's squared CIELAB distance to the nearest colour of its strokes.

    A value's stroke colours are summarised by up to ``centres`` k-means centres.

    Args:
        lab: ``(H, W, 3) float32`` CIELAB. seeds: ``(H, W)`` as :func:`rasterize_strokes` returns.

    Returns:
        ``{value: (H, W) float32}``.
    """
    flat = lab.reshape(-1, 3)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.5)
    out = {}
    for v in (int(v) for v in np.unique(seeds) if v >= 0):
        samples = np.ascontiguousarray(flat[seeds.reshape(-1) == v], np.float32)
        if len(samples) > centres:
            cv2.setRNGSeed(0)
            _, _, samples = cv2.kmeans(samples, centres, None, crit, 1, cv2.KMEANS_PP_CENTERS)
        d = np.full(flat.shape[0], np.inf, np.float32)
        for c in samples:
            d = np.minimum(d, ((flat - c) ** 2).sum(-1))
        out[v] = d.reshape(seeds.shape)
    return out


def fill_gaps(
    labels: np.ndarray, claimed: np.ndarray, lab: np.ndarray, seeds: np.ndarray, majority: float = FILL_MAJORITY
) -> np.ndarray:
    """Give each connected gap (where ``claimed`` is False) one of the values around it: the one whose strokes'
    colours are nearest for most of the gap's pixels. A gap that borders several values is filled only when that
    value wins at least ``majority`` of its pixels; else it is left as it was.

    Args:
        labels: ``(H, W) int`` values of the claimed pixels (0 may be a claimed value: the background).
        claimed: ``(H, W) bool``. lab: ``(H, W, 3) float32`` CIELAB of the view. seeds: its stroke raster.

    Returns:
        ``(H, W) int64``.
    """
    out = labels.astype(np.int64).copy()
    n, comp = cv2.connectedComponents((~claimed).astype(np.uint8), connectivity=4)
    if n <= 1:
        return out
    dist = _colour_distances(lab, seeds)
    ring = np.ones((3, 3), np.uint8)
    for c in range(1, n):
        gap = comp == c
        rim = cv2.dilate(gap.astype(np.uint8), ring).astype(bool) & claimed
        around = [int(v) for v in np.unique(out[rim]) if int(v) in dist] or sorted(dist)
        votes = np.bincount(np.stack([dist[v][gap] for v in around]).argmin(0), minlength=len(around))
        if len(around) == 1 or votes.max() >= majority * votes.sum():
            out[gap] = around[int(np.argmax(votes))]
    return out


def segment(
    image: np.ndarray,
    strokes: list[Stroke] | np.ndarray,
    *,
    iterations: int = 5,
    max_side: int = 1024,
    keep_touching: bool = True,
    fill: bool = True,
) -> Segmentation:
    """Label map of one view from strokes, by GrabCut per label (one label against the rest).

    For each label k with strokes (and for the background brush, when used): k's strokes are certain foreground,
    every other stroke certain background, the unstroked pixels probable background; GrabCut then fits its
    colour models and cuts. Parts of k's cut that none of k's strokes touch are dropped (``keep_touching``). A
    pixel claimed by several cuts goes to the one with the highest GrabCut foreground probability (the posterior of
    that cut's colour models). With ``fill``, each connected gap that no cut claims takes one of the values around it
    whose strokes are nearest in colour for most of its pixels (:func:`fill_gaps`), provided strokes of at least two
    kinds (labels, background) exist; else gaps stay 0. Pixels won by the background are 0.

    Args:
        image: ``(H, W, 3)`` RGB, ``uint8`` or float in ``[0, 1]``.
        strokes: :class:`Stroke` list in the image's pixel coordinates, or a seed map ``(H, W) int`` (-1 = none,
            0 = background, k = label k) as :func:`rasterize_strokes` makes.
        iterations: GrabCut iterations per label.
        max_side: views larger than this are cut at this size (longest side) and the labels scaled back up
            (nearest), which keeps one cut to a second or two on photo-sized views.
        keep_touching: drop the parts of a label's cut that none of its strokes touch.
        fill: give gaps between the cuts a label from around them (off: they stay unassigned, 0).

    Returns:
        :class:`Segmentation` with labels ``(H, W) int64`` at the image's full size.

    Raises:
        InputError: no label strokes, a seed map of the wrong size, or a cut GrabCut cannot start.
    """
    t0 = time.perf_counter()
    rgb = image if image.dtype == np.uint8 else to_uint8(np.asarray(image, np.float32))
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise InputError(f"segment needs an (H, W, 3) RGB image, got shape {rgb.shape}")
    h, w = rgb.shape[:2]
    scale = min(1.0, max_side / max(h, w))
    sh, sw = max(1, int(round(h * scale))), max(1, int(round(w * scale)))
    small = rgb if (sh, sw) == (h, w) else cv2.resize(rgb, (sw, sh), interpolation=cv2.INTER_AREA)
    if isinstance(strokes, np.ndarray):
        if strokes.shape != (h, w):
            raise InputError(f"the seed map is {strokes.shape[1]}x{strokes.shape[0]} but the image is {w}x{h}")
        seeds = strokes.astype(np.int64)
        if (sh, sw) != (h, w):
            seeds = cv2.resize(seeds.astype(np.int16), (sw, sh), interpolation=cv2.INTER_NEAREST).astype(np.int64)
    else:
        seeds = rasterize_strokes(strokes, (sh, sw), scale=sw / w)
    kinds = sorted(int(v) for v in np.unique(seeds) if v >= 0)
    if not any(k > 0 for k in kinds):
        raise InputError("no label strokes: draw over at least one region with a label (1, 2, …) before segmenting")
    bgr = cv2.cvtColor(small, cv2.COLOR_RGB2BGR)
    pixels = bgr.reshape(-1, 3).astype(np.float64)
    out = np.zeros((sh, sw), np.int64)
    best = np.full((sh, sw), -1.0, np.float32)
    prob: dict[int, np.ndarray] = {}
    for k in kinds:
        cut, fgd, bgd = _grabcut_one(bgr, seeds, k, iterations)
        if keep_touching:
            _, comp = cv2.connectedComponents(cut.astype(np.uint8), connectivity=8)
            touched = np.unique(comp[(seeds == k) & cut])
            cut = np.isin(comp, touched[touched > 0])
        lf, lb = gmm_log_density(fgd, pixels), gmm_log_density(bgd, pixels)
        p = (1.0 / (1.0 + np.exp(np.clip(lb - lf, -60, 60)))).reshape(sh, sw).astype(np.float32)
        take = cut & (p > best)
        out[take], best[take] = k, p[take]
        if k > 0:
            prob[k] = p
    claimed = best >= 0
    for k in kinds:  # strokes are certain
        out[seeds == k], claimed[seeds == k] = k, True
    if fill and len(kinds) >= 2:
        out = fill_gaps(out, claimed, cv2.cvtColor(small.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB), seeds)
    if (sh, sw) != (h, w):
        out = cv2.resize(out.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(np.int64)
        prob = {k: cv2.resize(p, (w, h), interpolation=cv2.INTER_LINEAR) for k, p in prob.items()}
    return Segmentation(out, prob, time.perf_counter() - t0)


def overlay_rgba(labels: np.ndarray, alpha: int = 150) -> np.ndarray:
    """Label map ``(H, W)`` → ``(H, W, 4) uint8`` RGBA in the label colours, transparent where 0, with each region's
    edge opaque so that the cut reads on any image."""
    lab = np.asarray(labels)
    rgba = np.zeros((*lab.shape, 4), np.uint8)
    rgba[..., :3] = PALETTE[np.where(lab > 0, (lab - 1) % (len(PALETTE) - 1) + 1, 0)]
    src = lab.astype(np.uint16 if lab.max(initial=0) > 255 else np.uint8)
    ring = np.ones((3, 3), np.uint8)
    edge = cv2.dilate(src, ring) != cv2.erode(src, ring)
    rgba[..., 3] = np.where(lab > 0, np.where(edge, 255, alpha), 0)
    return rgba


# ----------------------------------------------------------------------------------------------
# Session: the views (or the painting), their strokes and cuts
# ----------------------------------------------------------------------------------------------


@dataclass
class PaintItem:
    """One image on the page and where its label PNG goes."""

    name: str
    image_path: Path
    out_path: Path
    strokes: list[Stroke] = field(default_factory=list)
    result: Segmentation | None = None
    stale: bool = False  # strokes changed since ``result``


class PaintSession:
    """The images of one page, their strokes and cuts; thread-safe (the server handles requests in threads).

    ``mode`` is ``"scene"`` (every view of ``<scene>/images/``, masks to ``<scene>/masks/<stem>.png``) or
    ``"painting"`` (one painting, its label map to ``labels_out``).
    """

    def __init__(self, items: list[PaintItem], mode: str, title: str, *, iterations: int = 5, max_side: int = 1024,
                 fill: bool = True):
        if not items:
            raise InputError("nothing to paint on: no images")
        self.items, self.mode, self.title = items, mode, title
        self.iterations, self.max_side, self.fill = iterations, max_side, fill
        self._lock = threading.RLock()
        self._images: dict[int, np.ndarray] = {}
        self._png: dict[int, bytes] = {}

    @classmethod
    def for_scene(cls, scene: str | Path, **kw) -> PaintSession:
        """Every view in ``<scene>/images/``; Save writes ``<scene>/masks/<stem>.png``."""
        scene = Path(scene)
        if not scene.is_dir():
            raise InputError(f"scene folder {scene} does not exist; give the folder that holds images/ "
                             "(the path of data.scenes.<name> in params.yaml)")
        images = scene / "images"
        if not images.is_dir():
            raise InputError(f"{scene} has no images/ folder; put the scene's photos in {images}/ (the layout the "
                             f"pipeline reads) and give {scene} again, or use --painting PATH for a painting")
        files = sorted(p for p in images.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))
        if not files:
            raise InputError(f"{images} holds no images ({', '.join(IMAGE_SUFFIXES)})")
        stems: dict[str, str] = {}
        for p in files:
            if p.stem in stems:
                raise InputError(f"{images} has two views with the stem {p.stem!r} ({stems[p.stem]}, {p.name}): their "
                                 f"masks would share masks/{p.stem}.png; rename one")
            stems[p.stem] = p.name
        items = [PaintItem(p.name, p, scene / "masks" / f"{p.stem}.png") for p in files]
        return cls(items, "scene", scene.resolve().name, **kw)

    @classmethod
    def for_painting(cls, painting: str | Path, labels_out: str | Path | None = None, **kw) -> PaintSession:
        """One painting; Save writes its region label map to ``labels_out`` (default ``<stem>_labels.png`` beside it)."""
        painting = Path(painting)
        if not painting.is_file():
            raise InputError(f"painting {painting} does not exist")
        out = Path(labels_out) if labels_out else painting.with_name(f"{painting.stem}_labels.png")
        if out.suffix.lower() != ".png":
            raise InputError(f"--labels-out {out} must be a .png (label numbers need a lossless file)")
        if out.resolve() == painting.resolve():
            raise InputError("--labels-out must not be the painting itself")
        return cls([PaintItem(painting.name, painting, out)], "painting", painting.name, **kw)

    def _item(self, i: int) -> PaintItem:
        if not 0 <= i < len(self.items):
            raise InputError(f"no image {i}; this page has {len(self.items)}")
        return self.items[i]

    def image(self, i: int) -> np.ndarray:
        """``(H, W, 3) uint8`` RGB of image ``i``, as the pipeline reads it (no EXIF rotation)."""
        with self._lock:
            if i not in self._images:
                if len(self._images) >= 8:  # photo-sized scenes: keep a few views in memory
                    self._images.pop(next(iter(self._images)))
                self._images[i] = to_uint8(load_image(self._item(i).image_path))
            return self._images[i]

    def image_png(self, i: int) -> bytes:
        """Image ``i`` encoded for the page (PNG; the browser must not rotate it by EXIF as it would a JPEG)."""
        with self._lock:
            if i not in self._png:
                if len(self._png) >= 8:
                    self._png.pop(next(iter(self._png)))
                ok, buf = cv2.imencode(".png", cv2.cvtColor(self.image(i), cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1])
                if not ok:
                    raise InputError(f"could not encode {self._item(i).name} for the page")
                self._png[i] = buf.tobytes()
            return self._png[i]

    def size(self, i: int) -> tuple[int, int]:
        """``(H, W)`` of image ``i``."""
        return tuple(self.image(i).shape[:2])

    def set_strokes(self, i: int, strokes: list[Stroke]) -> None:
        with self._lock:
            item = self._item(i)
            item.strokes = list(strokes)
            item.stale = True
            if not strokes:
                item.result = None

    def segment(self, i: int, fill: bool | None = None) -> Segmentation:
        """Cut image ``i`` from its strokes (:func:`segment`) and keep the result; ``fill`` sets the session's."""
        with self._lock:
            item = self._item(i)
            if fill is not None:
                self.fill = bool(fill)
            if not any(s.label > 0 for s in item.strokes):
                raise InputError(f"{item.name} has no label strokes yet: pick a label and draw over a region")
            item.result = segment(self.image(i), item.strokes, iterations=self.iterations, max_side=self.max_side,
                                  fill=self.fill)
            item.stale = False
            log.info("%s: cut in %.2f s: %s", item.name, item.result.seconds, item.result.counts())
            return item.result

    def saved_labels(self, i: int) -> np.ndarray | None:
        """The label PNG already at image ``i``'s output path (``None`` if there is none or it does not read)."""
        p = self._item(i).out_path
        if not p.is_file():
            return None
        from abcgs.masks.content import read_label_files

        try:
            return read_label_files([p], [self.size(i)])[0][0]
        except InputError:
            return None

    def save(self) -> list[Path]:
        """Write the label PNG of every image with strokes (cutting those whose strokes changed), atomically.

        Returns the files written. Images without strokes are left alone (no file is written or removed).
        """
        with self._lock:
            todo = [i for i, it in enumerate(self.items) if any(s.label > 0 for s in it.strokes)]
            if not todo:
                raise InputError("nothing to save: no image has label strokes")
            for i in todo:
                if self.items[i].result is None or self.items[i].stale:
                    self.segment(i)
            written = []
            for i in todo:
                item = self.items[i]
                save_labels(item.out_path, item.result.labels)
                written.append(item.out_path)
            log.info("saved %d label map(s): %s", len(written), ", ".join(str(p) for p in written))
            return written

    def state(self) -> dict:
        """What the page shows: the images, their stroke counts and whether they are cut and saved."""
        with self._lock:
            used = [s.label for it in self.items for s in it.strokes]
            used += [int(it.result.labels.max()) for it in self.items if it.result is not None]
            return {
                "mode": self.mode, "title": self.title,
                "palette": [[int(c) for c in rgb] for rgb in PALETTE],
                "n_labels": max([2, *used]), "fill": self.fill,
                "items": [{
                    "index": i, "name": it.name, "strokes": len(it.strokes), "cut": it.result is not None,
                    "stale": it.stale, "saved": it.out_path.is_file(), "out": str(it.out_path),
                    "counts": {str(k): v for k, v in it.result.counts().items()} if it.result is not None else None,
                } for i, it in enumerate(self.items)],
            }


# ----------------------------------------------------------------------------------------------
# HTTP server: the page and a small JSON API, on 127.0.0.1 only
# ----------------------------------------------------------------------------------------------

_ROUTE = re.compile(r"^/api/(state|image|strokes|segment|labels|overlay|save)(?:/(\d+))?(?:\.png)?$")


def _png(arr: np.ndarray) -> bytes:
    if arr.ndim == 3 and arr.shape[2] == 4:
        arr = cv2.cvtColor(arr, cv2.COLOR_RGBA2BGRA)
    ok, buf = cv2.imencode(".png", arr)
    if not ok:
        raise InputError("could not encode a PNG")
    return buf.tobytes()


class _Handler(BaseHTTPRequestHandler):
    session: PaintSession  # set on the subclass :func:`make_server` builds
    server_version = "abcgs-paint"

    def log_message(self, fmt, *args):  # requests go to the debug log, not stderr
        log.debug("%s - %s", self.address_string(), fmt % args)

    def _send(self, status: int, body: bytes, ctype: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _json(self, data, status: int = 200) -> None:
        self._send(status, json.dumps(data).encode(), "application/json")

    def _body(self) -> dict:
        n = int(self.headers.get("Content-Length") or 0)
        if n > 64 << 20:
            raise InputError("request too large")
        raw = self.rfile.read(n) if n else b"{}"
        try:
            data = json.loads(raw or b"{}")
        except json.JSONDecodeError as exc:
            raise InputError(f"the request body is not JSON: {exc}") from exc
        if not isinstance(data, dict):
            raise InputError("the request body must be a JSON object")
        return data

    def _dispatch(self, method: str) -> None:
        path = self.path.split("?", 1)[0]
        try:
            if method == "GET" and path in ("/", "/index.html"):
                return self._send(200, PAGE.read_bytes(), "text/html; charset=utf-8")
            m = _ROUTE.match(path)
            if not m:
                return self._json({"error": f"no such page: {path}"}, HTTPStatus.NOT_FOUND)
            what, idx = m.group(1), int(m.group(2)) if m.group(2) else None
            s = self.session
            if what in ("image", "strokes", "segment", "labels", "overlay") and idx is None:
                raise InputError(f"/api/{what}/<index> needs an image index")
            if method == "GET" and what == "state":
                return self._json(s.state())
            if method == "GET" and what == "image":
                return self._send(200, s.image_png(idx), "image/png")
            if method == "GET" and what == "strokes":
                return self._json({"strokes": [st.to_json() for st in s._item(idx).strokes]})
            if method == "POST" and what == "strokes":
                s.set_strokes(idx, [Stroke.from_json(d) for d in self._body().get("strokes", [])])
                return self._json(s.state()["items"][idx])
            if method == "POST" and what == "segment":
                body = self._body()
                if "strokes" in body:
                    s.set_strokes(idx, [Stroke.from_json(d) for d in body["strokes"]])
                seg = s.segment(idx, body.get("fill"))
                return self._json({"counts": {str(k): v for k, v in seg.counts().items()},
                                   "seconds": round(seg.seconds, 3), "item": s.state()["items"][idx]})
            if method == "GET" and what in ("labels", "overlay"):
                item = s._item(idx)
                labels = item.result.labels if item.result is not None else s.saved_labels(idx)
                if labels is None:
                    return self._json({"error": f"{item.name} is not cut yet (press Segment)"}, HTTPStatus.NOT_FOUND)
                arr = labels.astype(np.uint8) if what == "labels" else overlay_rgba(labels)
                return self._send(200, _png(arr), "image/png")
            if method == "POST" and what == "save":
                body = self._body()
                if "fill" in body:
                    s.fill = bool(body["fill"])
                written = s.save()
                return self._json({"written": [str(p) for p in written], "state": s.state()})
            return self._json({"error": f"{method} {path} is not supported"}, HTTPStatus.METHOD_NOT_ALLOWED)
        except AbcgsError as exc:
            return self._json({"error": str(exc)}, HTTPStatus.BAD_REQUEST)
        except Exception as exc:  # the page shows the message; the server keeps running
            log.exception("request %s %s failed", method, path)
            return self._json({"error": f"{type(exc).__name__}: {exc}"}, HTTPStatus.INTERNAL_SERVER_ERROR)

    def do_GET(self):  # noqa: N802 (http.server's names)
        self._dispatch("GET")

    def do_POST(self):  # noqa: N802
        self._dispatch("POST")


def make_server(session: PaintSession, port: int = 0, host: str = "127.0.0.1") -> ThreadingHTTPServer:
    """An HTTP server for ``session`` on ``host:port`` (0 = any free port); call ``serve_forever()`` on it.

    ``server.server_port`` is the port it got. Only loopback addresses are allowed: the page can write files.
    """
    if host not in ("127.0.0.1", "localhost", "::1"):
        raise InputError(f"the paint server listens on the loopback address only, not {host}")
    handler = type("PaintHandler", (_Handler,), {"session": session})
    server = ThreadingHTTPServer((host, port), handler)
    server.daemon_threads = True
    return server


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m abcgs.masks.paint", description=__doc__.strip().splitlines()[0],
                                 epilog="Views: <scene>/images/*; masks: <scene>/masks/<stem>.png (0 = unassigned, 1, 2, …). "
                                        "Then `dvc repro` re-runs the masks stage and what follows.")
    ap.add_argument("scene", nargs="?", type=Path, help="scene folder (holds images/); not needed with --painting")
    ap.add_argument("--painting", type=Path, help="segment this painting into regions instead of a scene's views")
    ap.add_argument("--labels-out", type=Path, help="the painting's label PNG (default: <painting>_labels.png beside it)")
    ap.add_argument("--port", type=int, default=0, help="port on 127.0.0.1 (0: any free port)")
    ap.add_argument("--no-open", action="store_true", help="print the address; do not open a browser")
    ap.add_argument("--iterations", type=int, default=5, help="GrabCut iterations per label")
    ap.add_argument("--max-side", type=int, default=1024, help="cut larger images at this size (longest side)")
    ap.add_argument("--no-fill", action="store_true", help="leave gaps between the cuts unassigned (the page can switch)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        kw = {"iterations": args.iterations, "max_side": args.max_side, "fill": not args.no_fill}
        if args.painting is not None:
            if args.scene is not None:
                print(f"--painting given: showing {args.painting}; the scene folder {args.scene} is not used")
            session = PaintSession.for_painting(args.painting, args.labels_out, **kw)
        elif args.scene is not None:
            if args.labels_out is not None:
                raise InputError("--labels-out is for --painting; a scene's masks go to <scene>/masks/")
            session = PaintSession.for_scene(args.scene, **kw)
        else:
            raise InputError("give a scene folder (with images/) or --painting PATH")
        server = make_server(session, args.port)
    except (AbcgsError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    url = f"http://127.0.0.1:{server.server_port}/"
    what = (f"{len(session.items)} views; masks go to {session.items[0].out_path.parent}" if session.mode == "scene"
            else f"the painting; its labels go to {session.items[0].out_path}")
    print(f"paint: {url}  ({what}); Ctrl+C to stop")
    if not args.no_open:
        webbrowser.open(url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
