"""GrabCut from strokes (Rother et al. 2004, seeded by a user's scribbles), on colour and optionally depth.

Pure functions over arrays, used by the masks page (:mod:`abcgs.masks.page`) and by the ``masks`` stage's
cross-view refinement (:mod:`abcgs.masks.refine`).

For each label k (and the background brush, when used), GrabCut runs once, k against the rest: k's strokes are
certain foreground (``GC_FGD``), every other stroke certain background (``GC_BGD``), unstroked pixels probable
background (``GC_PR_BGD``; GrabCut then moves them). The parts of k's cut that no k-stroke touches are dropped (a
stroke marks the region it lies in). Where cuts overlap, the one with the higher GrabCut foreground probability (the
posterior of its colour models) wins. Gaps no cut claims take, per connected gap, the label around it whose strokes
are nearest in colour, when it clearly is (``fill``, :data:`FILL_MAJORITY`; off, gaps stay 0 and unclaimed: saved as
:data:`UNDECIDED`). Pixels the background wins are 0.

**Depth.** Given the view's rendered depth, GrabCut runs on :func:`grabcut_features` instead of RGB: the two
principal components of the view's colours and its inverse depth, as the three 8-bit channels OpenCV's GrabCut takes.
Its colour models then model colour and depth jointly, and its edge term (contrast between neighbours) sees depth
edges, so a label stops where its surface does even when the colours on both sides match.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from abcgs.errors import InputError
from abcgs.io.images import to_uint8
from abcgs.masks.edges import upsample_labels
from abcgs.masks.strokes import BACKGROUND, Segmentation, Stroke, rasterize_strokes
from abcgs.runtime import available_cores

FILL_MAJORITY = 0.7
"""A gap between several cuts takes the label nearest in colour for at least this share of its pixels, or stays 0.
On the tiny scene's textured views a plain majority gives large gaps of wall to an object (box IoU 0.96 → 0.63 from
strokes that differed by 26 pixels); at 0.7 such gaps stay unassigned."""

FILL_MARGIN = 0.5
"""Margin (:attr:`Segmentation.margin`) of a pixel the gap fill decided: by the colour of the strokes nearest, which
no cut's models claimed."""

GMM_COMPONENTS = 5
"""Gaussians per colour model in OpenCV's GrabCut (its model array is ``1 × 13·GMM_COMPONENTS``)."""


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


def _grabcut_one(feats: np.ndarray, seeds: np.ndarray, k: int, iterations: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """GrabCut of seed value ``k`` against the rest on ``feats`` (:func:`grabcut_features`): ``(cut (H, W) bool, fg
    model, bg model)``."""
    mask = np.full(seeds.shape, cv2.GC_PR_BGD, np.uint8)
    mask[seeds >= 0] = cv2.GC_BGD
    mask[seeds == k] = cv2.GC_FGD
    if not (mask != cv2.GC_FGD).any():
        raise InputError(f"the strokes of {'the background' if k == BACKGROUND else f'label {k}'} cover the whole "
                         "view; leave some of it unpainted")
    bgd, fgd = np.zeros((1, 13 * GMM_COMPONENTS), np.float64), np.zeros((1, 13 * GMM_COMPONENTS), np.float64)
    cv2.setRNGSeed(0)
    try:
        cv2.grabCut(feats, mask, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    except cv2.error as exc:
        raise InputError(f"GrabCut could not cut label {k}: {exc.err}") from exc
    return (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD), fgd, bgd


def _colour_distances(lab: np.ndarray, seeds: np.ndarray, where: np.ndarray, centres: int = 24) -> dict[int, np.ndarray]:
    """Per seed value (label or background), the squared distance of each pixel in ``where`` to the nearest colour of
    its strokes.

    A value's stroke colours are summarised by up to ``centres`` k-means centres.

    Args:
        lab: ``(H, W, C) float32`` CIELAB, optionally with further channels (:func:`fill_features`). seeds: ``(H, W)``
            as :func:`rasterize_strokes` returns. where: ``(H, W) bool``, the pixels asked about.

    Returns:
        ``{value: (M,) float32}``, in the order of ``lab[where]``.
    """
    flat = lab.reshape(-1, lab.shape[-1])
    asked = flat[where.reshape(-1)]
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.5)
    out = {}
    for v in (int(v) for v in np.unique(seeds) if v >= 0):
        samples = np.ascontiguousarray(flat[seeds.reshape(-1) == v], np.float32)
        if len(samples) > centres:
            cv2.setRNGSeed(0)
            _, _, samples = cv2.kmeans(samples, centres, None, crit, 1, cv2.KMEANS_PP_CENTERS)
        d = np.full(asked.shape[0], np.inf, np.float32)
        for c in samples:
            d = np.minimum(d, ((asked - c) ** 2).sum(-1))
        out[v] = d
    return out


def fill_gaps(
    labels: np.ndarray, claimed: np.ndarray, lab: np.ndarray, seeds: np.ndarray, majority: float = FILL_MAJORITY
) -> tuple[np.ndarray, np.ndarray]:
    """Give each connected gap (where ``claimed`` is False) one of the values around it: the one whose strokes'
    colours are nearest for most of the gap's pixels. A gap that borders several values is filled only when that
    value wins at least ``majority`` of its pixels; else it is left as it was.

    Args:
        labels: ``(H, W) int`` values of the claimed pixels (0 may be a claimed value: the background).
        claimed: ``(H, W) bool``. lab: ``(H, W, C) float32`` CIELAB of the view (:func:`fill_features`). seeds: its
            stroke raster.

    Returns:
        the labels ``(H, W) int64`` and the claimed pixels after the fill ``(H, W) bool``.
    """
    out = labels.astype(np.int64).copy()
    claimed_after = claimed.copy()
    n, comp = cv2.connectedComponents((~claimed).astype(np.uint8), connectivity=4)
    if n <= 1:
        return out, claimed_after
    gaps = comp > 0
    dist = _colour_distances(lab, seeds, gaps)
    in_gaps = comp[gaps]
    ring = np.ones((3, 3), np.uint8)
    for c in range(1, n):
        gap = comp == c
        rim = cv2.dilate(gap.astype(np.uint8), ring).astype(bool) & claimed
        around = [int(v) for v in np.unique(out[rim]) if int(v) in dist] or sorted(dist)
        mine = in_gaps == c
        votes = np.bincount(np.stack([dist[v][mine] for v in around]).argmin(0), minlength=len(around))
        if len(around) == 1 or votes.max() >= majority * votes.sum():
            out[gap] = around[int(np.argmax(votes))]
            claimed_after[gap] = True
    return out, claimed_after


WORK_PIXELS = 1 << 18
"""Pixels of the working size the cuts run at (about a quarter megapixel): a 12 Mpx phone photo is cut at 591 × 443, a
1080 × 1920 frame at 384 × 682, so that one Segment takes seconds at any photo size; the labels are brought back to
the photo's size along its edges (:func:`abcgs.masks.edges.upsample_labels`)."""


def working_size(hw: tuple[int, int], max_side: int, max_pixels: int = WORK_PIXELS) -> tuple[int, int]:
    """The ``(h, w)`` a view of size ``hw`` is cut at: scaled down (never up) until its longest side is at most
    ``max_side`` and it has at most ``max_pixels`` pixels."""
    h, w = hw
    scale = min(1.0, max_side / max(h, w), (max_pixels / (h * w)) ** 0.5)
    if scale == 1.0:
        return h, w
    return max(1, int(h * scale)), max(1, int(w * scale))  # rounded down: never more than max_pixels


DEPTH_PERCENTILES = (1.0, 99.0)
"""Inverse depth is normalised between these percentiles of the view's rendered pixels (a few floaters must not set
the scale)."""


def inverse_depth(depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth ``(H, W)`` (world units; 0, negative or non-finite = nothing rendered) → inverse depth normalised to
    ``[0, 1]`` over :data:`DEPTH_PERCENTILES` of the rendered pixels (1 = nearest; empty pixels 0), and the
    ``(H, W) bool`` mask of rendered pixels."""
    d = np.asarray(depth, np.float64)
    valid = np.isfinite(d) & (d > 0)
    out = np.zeros(d.shape, np.float32)
    if valid.sum() < 2:
        return out, valid
    disp = 1.0 / d[valid]
    lo, hi = np.percentile(disp, DEPTH_PERCENTILES)
    out[valid] = np.clip((disp - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    return out, valid


def grabcut_features(rgb: np.ndarray, depth: np.ndarray | None, depth_weight: float = 1.0) -> np.ndarray:
    """The 8-bit, 3-channel image GrabCut cuts: the view in BGR, or, with ``depth``, colour and depth together.

    With depth: the two principal components of the view's colours (one common scale: ±3 standard deviations of the
    first span 0..255) and the normalised inverse depth (:func:`inverse_depth`, 0..255). ``depth_weight`` w sets the
    depth channel's range against the colour channels': colour is scaled by min(1, 1/w) and depth by min(1, w), so
    both stay in 8 bits. The third colour component is dropped; on photos it holds a few percent of the colour
    variance.

    Args:
        rgb: ``(H, W, 3) uint8``. depth: ``(H, W)`` rendered depth (world units, 0 where empty) or None.

    Returns:
        ``(H, W, 3) uint8``.
    """
    if depth is None or depth_weight <= 0:
        return np.ascontiguousarray(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if depth.shape != rgb.shape[:2]:
        raise InputError(f"the depth map is {depth.shape[1]}x{depth.shape[0]} but the image is "
                         f"{rgb.shape[1]}x{rgb.shape[0]}")
    x = rgb.reshape(-1, 3).astype(np.float64)
    centred = x - x.mean(0)
    var, vec = np.linalg.eigh(np.cov(centred.T) + np.eye(3) * 1e-9)
    pcs = centred @ vec[:, ::-1][:, :2]  # the two largest components
    colour_scale = 255.0 / (6.0 * np.sqrt(max(var[-1], 1e-9))) * min(1.0, 1.0 / depth_weight)
    disp, _ = inverse_depth(depth)
    feats = np.concatenate([pcs * colour_scale + 127.5, disp.reshape(-1, 1) * 255.0 * min(1.0, depth_weight)], 1)
    return np.clip(np.round(feats), 0, 255).astype(np.uint8).reshape(rgb.shape)


def fill_features(rgb: np.ndarray, depth: np.ndarray | None, depth_weight: float = 1.0) -> np.ndarray:
    """What :func:`fill_gaps` compares: CIELAB ``(H, W, 3) float32``, with depth a fourth channel, the normalised
    inverse depth × 100 × ``depth_weight`` (the range of CIELAB's L)."""
    lab = cv2.cvtColor(rgb.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB)
    if depth is None or depth_weight <= 0:
        return lab
    disp, _ = inverse_depth(depth)
    return np.concatenate([lab, (disp * 100.0 * depth_weight)[..., None]], -1).astype(np.float32)


def _working_inputs(
    rgb: np.ndarray, strokes: list[Stroke] | np.ndarray, depth: np.ndarray | None, max_side: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The view, its seed map and its depth at the size the cuts run at (:func:`working_size`).

    Args:
        rgb: ``(H, W, 3) uint8``. strokes: as :func:`segment` takes them. depth: ``(H, W)`` world units, or None.
        max_side: the longest side of the working size, pixels.

    Returns:
        ``(h, w, 3) uint8`` view (INTER_AREA), ``(h, w) int64`` seed map (-1 = none, 0 = background, k = label k;
        nearest) and ``(h, w) float32`` depth (nearest) or None.

    Raises:
        InputError: a depth map or seed map of another size than the view.
    """
    h, w = rgb.shape[:2]
    sh, sw = working_size((h, w), max_side)
    small = rgb if (sh, sw) == (h, w) else cv2.resize(rgb, (sw, sh), interpolation=cv2.INTER_AREA)
    if depth is not None:
        depth = np.asarray(depth, np.float32)
        if depth.shape != (h, w):
            raise InputError(f"the depth map is {depth.shape[1]}x{depth.shape[0]} but the image is {w}x{h}")
        if (sh, sw) != (h, w):
            depth = cv2.resize(depth, (sw, sh), interpolation=cv2.INTER_NEAREST)
    if isinstance(strokes, np.ndarray):
        if strokes.shape != (h, w):
            raise InputError(f"the seed map is {strokes.shape[1]}x{strokes.shape[0]} but the image is {w}x{h}")
        seeds = strokes.astype(np.int64)
        if (sh, sw) != (h, w):
            seeds = cv2.resize(seeds.astype(np.int16), (sw, sh), interpolation=cv2.INTER_NEAREST).astype(np.int64)
    else:
        seeds = rasterize_strokes(strokes, (sh, sw), scale=sw / w)
    return small, seeds, depth


def _cut_every_kind(
    feats: np.ndarray, seeds: np.ndarray, kinds: list[int], iterations: int, keep_touching: bool
) -> tuple[np.ndarray, np.ndarray, dict[int, np.ndarray]]:
    """One GrabCut per seed value in ``kinds`` (labels and the background brush), merged: where cuts overlap, the one
    with the higher foreground probability wins; stroked pixels keep their stroke's value.

    Args:
        feats: ``(h, w, 3) uint8`` (:func:`grabcut_features`). seeds: ``(h, w) int64`` seed map. kinds: the seed
            values present (>= 0), ascending. iterations: GrabCut iterations per value. keep_touching: drop the parts
            of a cut that none of its value's strokes touch.

    Returns:
        labels ``(h, w) int64`` (0 where nothing or the background won), claimed ``(h, w) bool``, per label
        k > 0, its foreground probability ``(h, w) float32``, and the margin ``(h, w) float32``
        (:attr:`Segmentation.margin`, before any gap fill).
    """
    sh, sw = seeds.shape
    pixels = feats.reshape(-1, 3).astype(np.float64)

    def cut_one(k: int) -> tuple[np.ndarray, np.ndarray]:
        cut, fgd, bgd = _grabcut_one(feats, seeds, k, iterations)
        if keep_touching:
            _, comp = cv2.connectedComponents(cut.astype(np.uint8), connectivity=8)
            touched = np.unique(comp[(seeds == k) & cut])
            cut = np.isin(comp, touched[touched > 0])
        lf, lb = gmm_log_density(fgd, pixels), gmm_log_density(bgd, pixels)
        return cut, (1.0 / (1.0 + np.exp(np.clip(lb - lf, -60, 60)))).reshape(sh, sw).astype(np.float32)

    # OpenCV and NumPy release the GIL, and each thread seeds its own OpenCV RNG: the cuts run side by side and
    # are merged in the order of ``kinds``, as one after the other would be.
    with ThreadPoolExecutor(max_workers=max(1, min(len(kinds), available_cores()))) as pool:
        cuts = list(pool.map(cut_one, kinds))
    out = np.zeros((sh, sw), np.int64)
    best = np.full((sh, sw), -1.0, np.float32)
    prob: dict[int, np.ndarray] = {}
    for k, (cut, p) in zip(kinds, cuts):
        take = cut & (p > best)
        out[take], best[take] = k, p[take]
        if k > 0:
            prob[k] = p
    claimed = best >= 0
    margin = np.where(claimed, np.abs(2.0 * best - 1.0), 0.0).astype(np.float32)
    for k in kinds:  # strokes are certain
        out[seeds == k], claimed[seeds == k], margin[seeds == k] = k, True, 1.0
    return out, claimed, prob, margin


def segment(
    image: np.ndarray,
    strokes: list[Stroke] | np.ndarray,
    *,
    iterations: int = 5,
    max_side: int = 1024,
    keep_touching: bool = True,
    fill: bool = True,
    depth: np.ndarray | None = None,
    depth_weight: float = 1.0,
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
        max_side: views larger than this are cut at this size (longest side); views of more than
            :data:`WORK_PIXELS` pixels are cut at that many. The labels are brought back to the image's size along its
            edges (:func:`abcgs.masks.edges.upsample_labels`), which keeps one cut to seconds at any photo size.
        keep_touching: drop the parts of a label's cut that none of its strokes touch.
        fill: give gaps between the cuts a label from around them (off: they stay 0 and unclaimed, undecided).
        depth: ``(H, W)`` rendered depth of the view (world units, 0 where nothing is rendered): GrabCut and the gap
            fill then use colour and depth together (:func:`grabcut_features`). None: colour only.
        depth_weight: the depth channel's weight against colour (0: colour only).

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
    small, seeds, depth = _working_inputs(rgb, strokes, depth, max_side)
    sh, sw = seeds.shape
    kinds = sorted(int(v) for v in np.unique(seeds) if v >= 0)
    if not any(k > 0 for k in kinds):
        raise InputError("no label strokes: draw over at least one region with a label (1, 2, …) before segmenting")
    feats = grabcut_features(small, depth, depth_weight)
    out, claimed, prob, margin = _cut_every_kind(feats, seeds, kinds, iterations, keep_touching)
    if fill and len(kinds) >= 2:
        before = claimed
        out, claimed = fill_gaps(out, claimed, fill_features(small, depth, depth_weight), seeds)
        margin[claimed & ~before] = FILL_MARGIN
    if (sh, sw) != (h, w):
        out, claimed = upsample_labels(out, claimed, rgb)
        full_seeds = strokes if isinstance(strokes, np.ndarray) else rasterize_strokes(strokes, (h, w))
        stroked = full_seeds >= 0  # strokes stay where they were painted, at the photo's size
        out[stroked], claimed[stroked] = full_seeds[stroked], True
        prob = {k: cv2.resize(p, (w, h), interpolation=cv2.INTER_LINEAR) for k, p in prob.items()}
        margin = np.where(stroked, 1.0, np.where(claimed, cv2.resize(margin, (w, h)), 0.0)).astype(np.float32)
    return Segmentation(out, claimed, prob, margin, time.perf_counter() - t0)
