"""Content masks: the user's label PNGs for any subset of views, or automatic ones, lifted onto Gaussians.

The user's path (``masks.source: given``, or ``auto`` when ``<scene>/masks/`` has files): label PNGs named
like the views they label, for one view or several. A PNG may hold label numbers (single channel: 0 =
unassigned, 1, 2, …, and 255 = undecided: no vote) or colours painted in any paint program (black = unassigned; each other colour is a
label, numbered in the order of the colours' RGB values across all the mask files; colours covering less
than :data:`MIN_COLOUR_SHARE` of a file, such as a soft brush's edge blends, count as unassigned). Eq. 2
lifts them to every view. With ``masks.holdout_every: k`` every k-th given mask is kept out of the lifting
and only scored: the per-label IoU of the lifted masks against the user's on those views is the honest
measure of how well one view's labels carry to the others; ``masks.lift_views: ['000']`` lifts from the named
views only and scores all the other given masks.

Automatic masks need no downloaded network (SAM-class checkpoints cannot be fetched on the project's
machines; PyPI packages that wrap them ship no weights):

- ``clustering``: k-means (OpenCV) on CIELAB colour + rendered depth of a reference view — view-consistent
  after lifting, but clusters of colour, not objects;
- ``grabcut``: OpenCV's GrabCut (iterated graph cuts over colour GMMs, Rother et al. 2004) on the reference
  view's render, seeded by a box (``masks.grabcut.box``, fractions of the view; default the central region,
  where an object-centred capture keeps its object) and by depth (the nearest pixels inside the box are
  probable object, the farthest probable background): label 1 = the object, 2 = the rest.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from abcgs.camera_paths import capture_layout
from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel, render
from abcgs.io.images import MAX_LABEL, decode_image, load_image, load_labels, to_uint8
from abcgs.masks.lifting import NO_VOTE, LiftResult, lift_labels, propagate_unseen, render_label_map
from abcgs.masks.params import UNDECIDED, AutoMaskParams, GrabCutParams, MaskParams
from abcgs.masks.refine import Refinement, refine_labels
from abcgs.types import Backend

log = logging.getLogger(__name__)


MIN_COLOUR_SHARE = 0.005
"""In a colour label PNG, colours covering less than this share of the file's pixels are unassigned (0)."""


@dataclass
class ContentMasks:
    """Lifted labels and the re-rendered per-view label maps."""

    gaussian_labels: torch.Tensor  # (N,) int64
    n_labels: int
    view_labels: list[np.ndarray]  # per camera (H, W) int64
    source: str
    input_views: list[str]
    agreement: float | None  # pixel agreement of re-rendered vs given masks on the masked views
    heldout_views: list[str] = field(default_factory=list)
    heldout_iou: dict[int, float] = field(default_factory=dict)  # per label, lifted vs given on held-out views
    heldout_agreement: float | None = None  # pixel agreement on the held-out views' labelled pixels
    palette: dict[int, tuple[int, int, int]] = field(default_factory=dict)  # colour label PNGs: label → RGB
    propagated: int = 0  # Gaussians no masked view saw, labelled from their 3-D neighbours
    refinement: Refinement | None = None  # the cross-view re-cut (masks.refine), when it ran
    unlabelled_pixels: dict[str, float] = field(default_factory=dict)  # per view (image stem): share of pixels at 0
    unlabelled_gaussians: float = 0.0  # share of the Gaussians with label 0
    warnings: list[str] = field(default_factory=list)  # one line per view above masks.warn_unlabelled
    warned_views: list[str] = field(default_factory=list)  # those views' stems, worst first
    gaussian_decided: torch.Tensor | None = None  # (N,) bool: the label was voted or propagated, not left by default


def views_above(shares: dict[str, float], threshold: float) -> list[str]:
    """The views (keys of ``shares``) whose share of unlabelled pixels is above ``threshold``, worst first."""
    return [k for v, k in sorted(((v, k) for k, v in shares.items() if v > threshold), reverse=True)]


def unlabelled_warnings(shares: dict[str, float], threshold: float) -> list[str]:
    """One line per view of :func:`views_above`."""
    return [f"view {k}: {shares[k]:.0%} of pixels unlabelled — add strokes on this view"
            for k in views_above(shares, threshold)]


def read_label_files(paths: list[Path], sizes: list[tuple[int, int]]) -> tuple[list[np.ndarray], dict]:
    """Label PNGs → ``(H, W) int64`` maps and the colour palette used (empty for numbered PNGs).

    Numbered (single-channel or grey) files are read as they are, except the value
    :data:`~abcgs.masks.params.UNDECIDED` (255: a pixel the page's cut left undecided), which becomes
    :data:`~abcgs.masks.lifting.NO_VOTE`: it votes for no label, not even 0. If any file holds colours, every file's
    colours are numbered together (see the module docstring) so one colour is one label in every view.
    ``sizes`` are the views' ``(H, W)``; a size mismatch is an :class:`InputError`.
    """
    raws = []
    for p, hw in zip(paths, sizes):
        img = decode_image(p, "label map")
        if tuple(img.shape[:2]) != tuple(hw):
            raise InputError(f"label map {p} is {img.shape[1]}x{img.shape[0]} but its view is {hw[1]}x{hw[0]}; "
                             "masks must have the same size as the view they label")
        if img.ndim == 3 and img.shape[2] == 4:
            img = img[..., :3]
        raws.append(img)
    coloured = [r.ndim == 3 and not (np.all(r[..., 0] == r[..., 1]) and np.all(r[..., 1] == r[..., 2])) for r in raws]
    if not any(coloured):  # numbered: UNDECIDED (what the page's cut left open) votes for nothing
        return [np.where(m == UNDECIDED, NO_VOTE, m) for m in (load_labels(p, expect_hw=hw) for p, hw in zip(paths, sizes))], {}
    keep: set[tuple[int, int, int]] = set()
    for r in raws:
        rgb = (r if r.ndim == 3 else np.repeat(r[..., None], 3, -1))[..., ::-1].reshape(-1, 3)  # BGR → RGB
        cols, counts = np.unique(rgb, axis=0, return_counts=True)
        keep |= {tuple(int(v) for v in c) for c, n in zip(cols, counts) if n >= MIN_COLOUR_SHARE * len(rgb) and c.any()}
    if len(keep) > MAX_LABEL:
        raise InputError(f"the colour label PNGs hold {len(keep)} colours, more than the {MAX_LABEL} labels abcgs "
                         "lifts; paint each label in one flat colour")
    palette = {i + 1: c for i, c in enumerate(sorted(keep))}
    lut = {c: i for i, c in palette.items()}
    maps = []
    for r in raws:
        rgb = (r if r.ndim == 3 else np.repeat(r[..., None], 3, -1))[..., ::-1]
        code = (rgb[..., 0].astype(np.int64) << 16) | (rgb[..., 1].astype(np.int64) << 8) | rgb[..., 2]
        out = np.zeros(code.shape, np.int64)
        for c, i in lut.items():
            out[code == ((c[0] << 16) | (c[1] << 8) | c[2])] = i
        maps.append(out)
    return maps, palette


def label_paths_in(masks_dir: Path | None, cameras: Sequence[Camera]) -> list[Path | None]:
    """Each view's label PNG in ``masks_dir`` (``<stem>.png``, the stem of the view's image), or ``None``: the
    per-view label maps of a folder, as a scene record names them (:attr:`abcgs.types.CalibratedScene.label_paths`).
    A PNG that matches no view is named in a warning."""
    if masks_dir is None or not masks_dir.is_dir():
        return [None] * len(cameras)
    by_stem = {Path(c.name).stem: i for i, c in enumerate(cameras)}
    paths: list[Path | None] = [None] * len(cameras)
    for p in sorted(masks_dir.glob("*.png")):
        i = by_stem.get(p.stem)
        if i is None:
            log.warning("mask %s matches no registered view; ignored", p.name)
            continue
        paths[i] = p
    return paths


def read_given_masks(label_paths: Sequence[Path | None] | None, cameras: Sequence[Camera]
                     ) -> tuple[dict[int, np.ndarray], dict]:
    """The views' label maps (``label_paths[i]``: view ``i``'s, or ``None``) read at their views' sizes →
    ``{camera index: (H, W) int64 labels}``, and the colour palette of colour label PNGs (see
    :func:`read_label_files`)."""
    found = [(i, p) for i, p in enumerate(label_paths or ()) if p is not None]
    if not found:
        return {}, {}
    maps, palette = read_label_files([p for _, p in found], [(cameras[i].height, cameras[i].width) for i, _ in found])
    return {i: m for (i, _), m in zip(found, maps)}, palette


def cluster_view(model: GaussianModel, camera: Camera, params: AutoMaskParams, backend: Backend = "auto") -> np.ndarray:
    """k-means labels 1..n of one rendered view from Lab colour + depth ``(H, W) int64``."""
    with torch.no_grad():
        img, alpha, meta = render(model, camera, backend=backend, render_mode="RGB+ED")
    rgb = img.clamp(0, 1).numpy(force=True).astype(np.float32)
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB) / np.array([100.0, 127.0, 127.0], np.float32)
    depth = meta.depth[..., 0].numpy(force=True)
    valid = alpha[..., 0].numpy(force=True) > 0.5
    if valid.sum() < params.n_labels:
        raise InputError(f"view {camera.name} renders almost empty; cannot cluster it into {params.n_labels} labels")
    d = (depth - depth[valid].mean()) / (depth[valid].std() + 1e-6)
    feats = np.concatenate([lab, params.depth_weight * d[..., None]], -1).reshape(-1, 4).astype(np.float32)
    cv2.setRNGSeed(params.seed)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    _, lbl, _ = cv2.kmeans(feats[valid.reshape(-1)], params.n_labels, None, crit, 3, cv2.KMEANS_PP_CENTERS)
    out = np.zeros(depth.shape, np.int64)
    out[valid] = lbl[:, 0] + 1
    # clean-up: a median filter removes speckle without moving boundaries much
    return cv2.medianBlur(out.astype(np.uint8), 5).astype(np.int64)


def grabcut_view(model: GaussianModel, camera: Camera, params: GrabCutParams, backend: Backend = "auto") -> np.ndarray:
    """Object (1) vs rest (2) of one rendered view by GrabCut seeded with a box and depth ``(H, W) int64``
    (0 where nothing is rendered)."""
    with torch.no_grad():
        img, alpha, meta = render(model, camera, backend=backend, render_mode="RGB+ED")
    rgb = (img.clamp(0, 1).numpy(force=True) * 255 + 0.5).astype(np.uint8)
    depth = meta.depth[..., 0].numpy(force=True)
    valid = alpha[..., 0].numpy(force=True) > 0.5
    h, w = depth.shape
    x0, y0, x1, y1 = params.box
    bx0, by0 = int(round(x0 * w)), int(round(y0 * h))
    bx1, by1 = max(bx0 + 1, int(round(x1 * w))), max(by0 + 1, int(round(y1 * h)))
    mask = np.full((h, w), cv2.GC_BGD, np.uint8)
    mask[by0:by1, bx0:bx1] = cv2.GC_PR_FGD
    inside = np.zeros((h, w), bool)
    inside[by0:by1, bx0:bx1] = True
    inside &= valid
    if inside.sum() < 16:
        raise InputError(f"grabcut: the box {params.box} covers almost nothing rendered in view {camera.name}")
    if params.depth_seed:
        # inverse depth, clipped to its 2nd–98th percentiles in the box: a few far floaters must not set the scale
        disp = 1.0 / np.maximum(depth, 1e-6)
        lo, hi = (float(v) for v in np.percentile(disp[inside], [2, 98]))
        if hi > lo:
            d8 = (255.0 - np.clip((disp - lo) / (hi - lo) * 255.0, 0, 255)).astype(np.uint8)  # 0 = nearest
            thr, _ = cv2.threshold(d8[inside], 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
            near = inside & (d8 <= thr)
            mask[inside & ~near] = cv2.GC_PR_BGD
            core = cv2.erode(near.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
            mask[core] = cv2.GC_FGD
    mask[~valid] = cv2.GC_BGD
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)
    cv2.grabCut(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), mask, None, bgd, fgd, params.iterations, cv2.GC_INIT_WITH_MASK)
    obj = (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)
    out = np.where(obj, 1, 2).astype(np.int64)
    out[~valid] = 0
    if not (out == 1).any():
        raise InputError(f"grabcut found no object in view {camera.name}; move masks.grabcut.box onto it")
    return out


def recut_outputs(model: GaussianModel, cameras: list[Camera], images: list[Path] | None, lifted, n_labels: int,
                  rendered: list[np.ndarray], *, skip: set[int], params: MaskParams, only: set[int] | None = None,
                  show_progress: bool = False) -> list[np.ndarray]:
    """``masks.refine.output: recut``: each view not in ``skip`` (and in ``only``, when given) cut once more on its
    photo and rendered depth, seeded by ``lifted``'s decided labels (:func:`abcgs.masks.refine.cut_view`); where the
    cut decides nothing the view keeps its ``rendered`` label. The others keep ``rendered``."""
    from abcgs.masks.refine import cut_view
    from abcgs.progress import progress

    out = list(rendered)
    todo = [i for i in range(len(cameras)) if i not in skip and (only is None or i in only)]
    for i in progress(todo, "masks: cut the output views", enabled=show_progress):
        cut, _, _ = cut_view(model, lifted, n_labels, cameras[i], None if images is None else images[i], params.refine,
                             backend=params.backend)
        out[i] = np.where(cut >= 0, cut, rendered[i]).astype(np.int64)
    return out


def label_iou(pred: np.ndarray, truth: np.ndarray, n_labels: int) -> dict[int, float]:
    """Per label 1..n: IoU of ``pred`` and ``truth`` over pixels where ``truth`` is assigned (> 0); labels absent
    from both are left out."""
    keep = truth > 0
    out = {}
    for k in range(1, n_labels + 1):
        a, b = (pred == k) & keep, truth == k
        union = int((a | b).sum())
        if union:
            out[k] = float((a & b).sum() / union)
    return out


def _given_views(given: dict[int, np.ndarray], cameras: list[Camera], lift_views: list[str], holdout_every: int
                 ) -> tuple[list[int], list[int]]:
    """Which views with a given mask are lifted and which are held out and scored: the views ``lift_views`` names
    (file stems) when set, else all but every ``holdout_every``-th (< 2: none held out).

    Returns:
        the lifted and the held-out view indices, ascending.

    Raises:
        InputError: ``lift_views`` names a view without a given mask.
    """
    idx = sorted(given)
    heldout: list[int] = []
    if lift_views:
        stems = {Path(cameras[i].name).stem: i for i in idx}
        missing = [v for v in lift_views if v not in stems]
        if missing:
            raise InputError(f"masks.lift_views names view(s) {missing} without a label map "
                             f"(masks found for: {', '.join(sorted(stems)) or 'none'})")
        chosen = sorted(stems[v] for v in lift_views)
        heldout = [i for i in idx if i not in chosen]
        idx = chosen
    elif holdout_every >= 2 and len(idx) >= 2:
        heldout = idx[holdout_every - 1 :: holdout_every]
        idx = [i for i in idx if i not in heldout]
    return idx, heldout


def _reference_masks(model: GaussianModel, cameras: list[Camera], given: dict[int, np.ndarray],
                     params: MaskParams) -> tuple[str, list[int], list[np.ndarray], list[int]]:
    """The label maps to lift, by ``params.source``: the given masks (when any, for ``auto`` and ``given``), else one
    reference view cut by GrabCut or by colour clustering.

    Returns:
        the source's name (``given``, ``grabcut``, ``clustering``), the lifted views' indices, their label maps
        ``(H, W) int64`` and the held-out views' indices.

    Raises:
        InputError: a reference view out of range, or ``lift_views`` naming a view without a mask.
    """
    if given and params.source in ("auto", "given"):
        idx, heldout = _given_views(given, cameras, params.lift_views, params.holdout_every)
        return "given", idx, [given[i] for i in idx], heldout
    if params.source == "grabcut":
        i = params.grabcut.reference_view
        if i >= len(cameras):
            raise InputError(f"masks.grabcut.reference_view {i} is out of range (scene has {len(cameras)} views)")
        return "grabcut", [i], [grabcut_view(model, cameras[i], params.grabcut, params.backend)], []
    i = params.clustering.reference_view
    if i >= len(cameras):
        raise InputError(f"masks.clustering.reference_view {i} is out of range (scene has {len(cameras)} views)")
    return "clustering", [i], [cluster_view(model, cameras[i], params.clustering, params.backend)], []


def _lift_and_refine(model: GaussianModel, cameras: list[Camera], images: list[Path] | None, idx: list[int],
                     maps: list[np.ndarray], n_labels: int, params: MaskParams,
                     show_progress: bool) -> tuple[LiftResult, int, Refinement | None]:
    """Per-Gaussian labels from the label maps ``maps`` (``(H, W) int64`` each) of the views ``idx``: lifted (Eq. 2),
    spread to the Gaussians no masked view sees where the capture calls for it (``LiftParams.propagate``), and, with
    ``masks.refine``, re-cut in every other view and lifted again.

    Returns:
        the lifted labels, how many Gaussians took a neighbour's label, and the refinement (None when off).
    """
    lifted = lift_labels(model, [cameras[i] for i in idx], maps, n_labels, params.lift, backend=params.backend)
    # Gaussians no masked view sees take their 3-D neighbours' label (object-centred captures, LiftParams.propagate)
    propagate = params.lift.propagate == "always" or (
        params.lift.propagate == "auto" and len(idx) < len(cameras) and len(cameras) > 1
        and capture_layout(cameras).kind == "orbit"
    )
    propagated = 0
    if propagate:
        lifted, propagated = propagate_unseen(model, lifted, params.lift)
        log.info("propagated labels to %d Gaussians no masked view sees", propagated)
    refinement = None
    if params.refine.enabled and len(idx) < len(cameras):
        # every view but the lifted ones (the user's masks stay as painted; held-out views are re-cut and scored)
        refinement = refine_labels(model, cameras, images, dict(zip(idx, maps)), lifted, n_labels, params.lift,
                                   params.refine, backend=params.backend, show_progress=show_progress,
                                   propagate=propagate)
        lifted = refinement.lifted
        if propagate:  # what no view sees at all (and, with propagate_split, the split votes)
            lifted, propagated = propagate_unseen(model, lifted, params.lift,
                                                  undecided=params.lift.propagate_split)
    return lifted, propagated, refinement


def _field_labels(model: GaussianModel, cameras: list[Camera], label_paths: Sequence[Path | None] | None,
                  idx: list[int], maps: list[np.ndarray], params: MaskParams, show_progress: bool,
                  images: list[Path] | None = None) -> tuple[LiftResult, int, list[np.ndarray]]:
    """Per-Gaussian labels from the label maps ``maps`` of the views ``idx`` and their saved strokes
    (``strokes/<stem>.png`` beside the view's label map ``label_paths[i]``, when there are any) by :class:`abcgs.masks.field.LabelField`, as the masks
    page computes them (the strokes' corrections on the view's photo laid over the map,
    :func:`~abcgs.masks.regions.view_evidence`), and every view's labels (refined against the view's photo in ``images`` where given; a
    painted view keeps its map where it decided).

    Returns:
        the labels (``weights`` empty), how many Gaussians the 3-D step decided, and the label map of every view.
    """
    from abcgs.io.images import load_stroke_map, stroke_map_path
    from abcgs.masks.field import LabelField, render_field
    from abcgs.masks.regions import view_evidence
    from abcgs.progress import progress

    field_ = LabelField(model, cameras, params.field, params.lift, params.backend)
    for i, m in zip(idx, maps):
        cam = cameras[i]
        given = label_paths[i] if label_paths is not None else None
        path = stroke_map_path(given.parent, Path(cam.name).stem) if given is not None else None
        strokes = load_stroke_map(path, (cam.height, cam.width)) if path is not None and path.is_file() else None
        cut, regions = (m, None) if images is None or strokes is None else view_evidence(
            m, strokes, to_uint8(load_image(images[i])), params.field, field_.depth_of(i))
        field_.set_view(i, cut, strokes, regions=regions)
    result = field_.solve()
    views = [render_field(field_, result, i, photo=None if images is None else to_uint8(load_image(images[i])))
             for i in progress(range(len(cameras)), "masks: render every view's labels", enabled=show_progress)]
    lifted = LiftResult(torch.as_tensor(result.labels), torch.empty(0), torch.as_tensor(result.decided))
    return lifted, result.counts()["graph"], views


def heldout_scores(views: list[np.ndarray] | dict[int, np.ndarray], truths: dict[int, np.ndarray],
                   n_labels: int) -> tuple[dict[int, list[float]], list[float]]:
    """Scores of lifted label maps against held-out masks.

    Args:
        views: the label maps rendered from the lifted labels, ``(H, W) int64`` each, by view index.
        truths: view index → the held-out given mask ``(H, W) int64`` (0 = unassigned).
        n_labels: labels 1..n_labels are scored.

    Returns:
        per label, its IoU in each held-out view (:func:`label_iou`; a label absent from both maps is left out), and
        per held-out view with a label, the share of its labelled pixels the view's map agrees with.
    """
    ho_iou: dict[int, list[float]] = {}
    ho_agree = []
    for i, truth in truths.items():
        for k, v in label_iou(views[i], truth, n_labels).items():
            ho_iou.setdefault(k, []).append(v)
        if (truth > 0).any():
            ho_agree.append(float((views[i] == truth)[truth > 0].mean()))
    return ho_iou, ho_agree


def make_content_masks(
    model: GaussianModel,
    cameras: list[Camera],
    label_paths: Sequence[Path | None] | None,
    params: MaskParams,
    images: list[Path] | None = None,
    *,
    show_progress: bool = True,
) -> ContentMasks:
    """Given or automatic masks → per-Gaussian labels (Eq. 2; cross-view refinement with ``masks.refine``) →
    re-rendered masks for every view.

    ``label_paths``: each view's given label map or ``None`` (the scene record's
    :attr:`~abcgs.types.CalibratedScene.label_paths`; :func:`label_paths_in` for a folder of them), a view's strokes
    in ``strokes/`` beside its map. ``images``: the views' photos, which the refinement cuts (None: the scene's renders
    stand in for them).
    """
    given, palette = read_given_masks(label_paths, cameras)
    if params.source == "given" and not given:
        raise InputError("masks.source is 'given' but no view has a label map (masks/<stem>.png in the scene folder, "
                         "carried by the reconstruct stage)")
    source, idx, maps, heldout = _reference_masks(model, cameras, given, params)
    n_labels = int(max([m.max() for m in maps] + [given[i].max() for i in heldout]))
    if n_labels == 0:
        raise InputError("the content masks contain no label > 0 (0 means unassigned); nothing to lift")
    if params.refine.enabled:
        lifted, propagated, refinement = _lift_and_refine(model, cameras, images, idx, maps, n_labels, params,
                                                          show_progress)
        views = [render_label_map(model, lifted.labels, n_labels, c, threshold=params.lift.render_threshold,
                                  backend=params.backend) for c in cameras]
    else:
        lifted, propagated, views = _field_labels(model, cameras, label_paths if source == "given" else None, idx,
                                                  maps, params, show_progress, images)
        refinement = None
    if params.refine.enabled and params.refine.output == "recut":
        views = recut_outputs(model, cameras, images, lifted, n_labels, views, skip=set(idx), params=params,
                              show_progress=show_progress)
    agree = [float((views[i] == m)[m > 0].mean()) for i, m in zip(idx, maps) if (m > 0).any()]
    ho_iou, ho_agree = heldout_scores(views, {i: given[i] for i in heldout}, n_labels)
    counts = lifted.counts()
    log.info("lifted %s masks of %d view(s) onto %d Gaussians: %s", source, len(idx), len(lifted.labels), counts)
    unlabelled = {Path(c.name).stem: float((v == 0).mean()) for c, v in zip(cameras, views)}
    warnings = unlabelled_warnings(unlabelled, params.warn_unlabelled)
    for w in warnings:
        log.warning("masks: %s", w)
    if heldout:
        log.info("held-out views %d: per-label IoU %s", len(heldout),
                 {k: round(float(np.mean(v)), 3) for k, v in sorted(ho_iou.items())})
    return ContentMasks(lifted.labels, n_labels, views, source, [cameras[i].name for i in idx],
                        float(np.mean(agree)) if agree else None, [cameras[i].name for i in heldout],
                        {k: float(np.mean(v)) for k, v in sorted(ho_iou.items())},
                        float(np.mean(ho_agree)) if ho_agree else None, palette, propagated, refinement,
                        unlabelled, float((lifted.labels == 0).float().mean()), warnings,
                        views_above(unlabelled, params.warn_unlabelled), lifted.decided)
