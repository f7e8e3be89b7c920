"""Cross-view refinement of lifted content labels: every view without a given mask is cut again, on its own colours
and the fitted scene's depth, seeded by the lifted labels rendered into it; then the labels are lifted from all views.

Lifting the masks of a few views (Eq. 2) labels only the Gaussians those views see, and carries their masks' errors
into 3-D: a stroke-guided cut that leaked from an object onto the wall behind it leaves wall Gaussians with the
object's label, seen as a tail of the object in every other view. Refinement lets every view vote with its own
evidence, as segmenters that prompt one view from another do (here with GrabCut rather than a learned model):

1. **Seeds.** The Gaussians whose vote is decided (:attr:`LiftResult.decided`) are rendered into view v with their
   labels. Each label's region, and the region of decided 0 (what the user marked with the background brush: a
   background seed; a gap the page's cut left undecided votes for nothing and seeds nothing), is eroded by ``masks.refine.seed_erode`` × the view's shorter side: that certain core is the seed. Edges, pixels of
   undecided Gaussians and empty pixels are left to the cut.
2. **Cut.** :func:`abcgs.masks.grabcut.segment` on the view's photo and its rendered depth (GrabCut per label on two
   colour components and inverse depth; ``masks.refine.depth_weight``). A seed is certain; GrabCut decides the rest,
   so a tail that has the wall's depth and colours goes to the wall. Pixels no cut claims vote for nothing
   (:data:`abcgs.masks.lifting.NO_VOTE`): "undecided" must not outvote a label as "unassigned" would.
3. **Lift again** from every view: the given masks as they are, the cuts for the others.

The views with given masks are never re-cut: what the user painted stays the user's.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel, render
from abcgs.io.images import load_image
from abcgs.masks.grabcut import segment
from abcgs.masks.lifting import (
    NO_VOTE,
    LiftResult,
    decide_labels,
    label_colours,
    lift_labels,
    pick_labels,
    propagate_unseen,
    view_weights,
)
from abcgs.masks.params import LiftParams, RefineParams
from abcgs.progress import progress
from abcgs.render import rasterize
from abcgs.types import Backend

log = logging.getLogger(__name__)

NO_SEED = -1
"""Seed-map value of a pixel left to the cut (:func:`abcgs.masks.grabcut.rasterize_strokes`'s "no stroke")."""


@dataclass
class Refinement:
    """What :func:`refine_labels` did.

    Attributes:
        lifted: the labels lifted from every view.
        views: per re-cut view (name): ``{"seeded": share of its pixels that were seeds, "changed": share of the
            pixels both the first lift's render and the cut decided whose label the cut changed, "undecided": share of
            its pixels that vote for nothing}``.
        seconds: time spent.
    """

    lifted: LiftResult
    views: dict[str, dict[str, float]] = field(default_factory=dict)
    seconds: float = 0.0


def eroded_cores(region: np.ndarray, erode_px: int, *, keep_small: bool = False) -> np.ndarray:
    """``region (H, W) bool`` eroded by a ``(2·erode_px + 1)²`` square; pixels outside the view count as inside, so a
    region that meets the border keeps its core there. With ``keep_small`` each connected part is eroded by at most
    half its thickness (its largest chessboard distance to its edge), so a part thinner than the erosion keeps its
    middle instead of vanishing; parts 2 px thick or less still vanish."""
    if erode_px <= 0:
        return region.copy()
    padded = cv2.copyMakeBorder(region.astype(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=1)
    dist = cv2.distanceTransform(padded, cv2.DIST_C, 3)[1:-1, 1:-1]  # chessboard distance to the nearest outside pixel
    if not keep_small:
        return dist > erode_px
    n, comp = cv2.connectedComponents(region.astype(np.uint8), connectivity=8)
    thickest = np.zeros(n, np.float32)
    np.maximum.at(thickest, comp.ravel(), dist.ravel())
    limit = np.minimum(float(erode_px), np.maximum(1.0, np.floor(thickest / 2.0)))
    return region & (dist > limit[comp])


def render_seeds(
    model: GaussianModel, lifted: LiftResult, n_labels: int, camera: Camera, erode_px: int, *, backend: Backend = "auto",
    keep_small: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The decided labels rendered into ``camera`` and their eroded cores (:func:`eroded_cores`; ``keep_small``:
    regions thinner than the erosion keep their middle).

    A pixel takes the label (0..n_labels) whose decided Gaussians hold at least half of its alpha; undecided
    Gaussians render as a label of their own that never seeds.

    Returns:
        ``seeds (H, W) int64`` (:data:`NO_SEED`, or 0..n_labels: the label's region eroded by ``erode_px``),
        ``rendered (H, W) int64`` (the label before erosion, :data:`NO_SEED` where no label holds half the alpha),
        ``depth (H, W) float32`` (expected depth, world units; 0 where nothing is rendered).
    """
    act = model.detach().activated()
    colours = label_colours(lifted.labels, n_labels, lifted.decided).to(model.device)
    with torch.no_grad():
        img, alpha, meta = rasterize(
            act["means"], act["quats"], act["scales"], act["opacities"], colours, camera.torch_viewmat(model.device),
            camera.torch_K(model.device), camera.width, camera.height, render_mode="RGB+ED", backend=backend,
        )
    rendered = pick_labels(img, alpha, 0.5, min_alpha=0.5, none=NO_SEED, undecided=NO_SEED).numpy(force=True).astype(np.int64)
    a = alpha[..., 0]
    depth = torch.where(a > 1e-3, meta.depth[..., 0], torch.zeros_like(a)).numpy(force=True).astype(np.float32)
    seeds = np.full(rendered.shape, NO_SEED, np.int64)
    for v in range(n_labels + 1):
        seeds[eroded_cores(rendered == v, erode_px, keep_small=keep_small)] = v
    return seeds, rendered, depth


def cut_view(
    model: GaussianModel,
    lifted: LiftResult,
    n_labels: int,
    camera: Camera,
    image: Path | str | np.ndarray | None,
    params: RefineParams,
    *,
    backend: Backend = "auto",
) -> tuple[np.ndarray, np.ndarray, float]:
    """One view cut on its photo and rendered depth, seeded by the decided labels' eroded cores (module docstring,
    steps 1–2).

    Args:
        image: the view's photo (path or ``(H, W, 3)`` array at the camera's size); None: the scene's render.

    Returns:
        ``cut (H, W) int64`` (0..n_labels, :data:`~abcgs.masks.lifting.NO_VOTE` where no cut claimed the pixel; as
        rendered where no label reaches the view), ``rendered (H, W) int64`` (:func:`render_seeds`) and the share of
        the view's pixels that were seeds.
    """
    erode_px = int(round(params.seed_erode * min(camera.height, camera.width)))
    seeds, rendered, depth = render_seeds(model, lifted, n_labels, camera, erode_px, backend=backend,
                                          keep_small=params.small_regions == "core")
    seeded = float((seeds >= 0).mean())
    if not (seeds > 0).any():  # no label reaches this view: nothing to seed a cut with; it votes as rendered
        return np.where(rendered >= 0, rendered, NO_VOTE), rendered, seeded
    if image is None:
        with torch.no_grad():
            rgb = render(model, camera, backend=backend)[0].clamp(0, 1).numpy(force=True)
    else:
        rgb = load_image(image) if isinstance(image, (str, Path)) else np.asarray(image)
    if rgb.shape[:2] != (camera.height, camera.width):
        raise InputError(f"the photo of view {camera.name} is {rgb.shape[1]}x{rgb.shape[0]} but its camera is "
                         f"{camera.width}x{camera.height}; give the undistorted images the cameras belong to")
    seg = segment(rgb, seeds, iterations=params.iterations, depth=depth, depth_weight=params.depth_weight)
    return np.where(seg.claimed, seg.labels, NO_VOTE), rendered, seeded


def nearest_first(cameras: list[Camera], given: list[int], todo: list[int]) -> list[int]:
    """``todo`` ordered by the angle between each camera's viewing direction and the nearest of the ``given``
    cameras', smallest first (ties by index): on a capture round an object, the views next to a labelled one come
    first and the far side last."""
    def forward(c: Camera) -> np.ndarray:
        r = np.asarray(c.torch_viewmat("cpu"), np.float64)[:3, :3]
        return r[2] / np.linalg.norm(r[2])  # the camera's +z axis in world coordinates

    if not given:
        return list(todo)
    ref = np.stack([forward(cameras[g]) for g in given])
    angle = {i: float(np.arccos(np.clip(ref @ forward(cameras[i]), -1.0, 1.0)).min()) for i in todo}
    return sorted(todo, key=lambda i: (angle[i], i))


def refine_labels(
    model: GaussianModel,
    cameras: list[Camera],
    images: list[Path] | list[np.ndarray] | None,
    given: dict[int, np.ndarray],
    lifted: LiftResult,
    n_labels: int,
    lift_params: LiftParams,
    params: RefineParams,
    *,
    backend: Backend = "auto",
    show_progress: bool = True,
    propagate: bool = False,
) -> Refinement:
    """Re-cut every camera not in ``given`` from the lifted labels, then lift from all cameras (module docstring).

    Args:
        model: the fitted scene. cameras: all views. images: their photos (paths or ``(H, W, 3)`` arrays) at the
            cameras' sizes; None: the scene's own renders stand in for them.
        given: camera index → the label map lifted as it is (the user's masks); every other camera is re-cut.
        lifted: the first lift (from ``given``, or from an automatic mask). n_labels: labels 1..n_labels.
        lift_params: thresholds of the final lift. params: ``masks.refine``.
        propagate: with ``params.order: nearest_first``, fill the Gaussians no view so far decides from their 3-D
            neighbours (:func:`~abcgs.masks.lifting.propagate_unseen`) before each cut.

    Returns:
        :class:`Refinement`.
    """
    t0 = time.perf_counter()
    views: dict[str, dict[str, float]] = {}
    todo = [i for i in range(len(cameras)) if i not in given]
    recut: dict[int, np.ndarray] = {}
    weights = None
    if params.order == "nearest_first":
        todo = nearest_first(cameras, sorted(given), todo)
        weights = lifted.weights.clone()
    for i in progress(todo, "masks: re-cut views", enabled=show_progress):
        cam = cameras[i]
        cut, rendered, seeded = cut_view(model, lifted, n_labels, cam, None if images is None else images[i], params,
                                         backend=backend)
        recut[i] = cut
        if weights is not None:  # the next view is seeded by the given masks and every cut so far
            weights += view_weights(model, cam, cut, n_labels, backend=backend)
            lifted = decide_labels(weights, lift_params)
            if propagate:
                lifted = propagate_unseen(model, lifted, lift_params)[0]
        both = (cut >= 0) & (rendered >= 0)
        views[cam.name] = {"seeded": seeded,
                           "changed": float((cut != rendered)[both].mean()) if both.any() else 0.0,
                           "undecided": float((cut < 0).mean())}
    if weights is not None:  # the given masks' votes and every cut's: the lift from all views
        relifted = decide_labels(weights, lift_params)
    else:
        maps = [given[i] if i in given else recut[i] for i in range(len(cameras))]
        relifted = lift_labels(model, cameras, maps, n_labels, lift_params, backend=backend)
    seconds = time.perf_counter() - t0
    log.info("refined: %d views re-cut on colour%s in %.1f s; labels per Gaussian %s", len(todo),
             " and depth" if params.depth_weight > 0 else "", seconds, relifted.counts())
    return Refinement(relifted, views, seconds)
