"""Lifting 2-D content label maps onto Gaussians (ABC-GS Eq. 2) and rendering them back.

For each Gaussian i and label j, ``w[i, j] = Σ_p α_i(p) T_i(p) M_j(p)`` summed over the pixels of every
masked view (its blending weight at the pixel times the one-hot mask; a pixel of value :data:`NO_VOTE` adds
nothing). Each Gaussian takes the label
whose weight wins, provided the winner holds at least ``min_weight`` of blending weight and a
``min_share`` of the Gaussian's total; otherwise it stays unassigned (0). Label 0 in the masks means
"unassigned" and takes part in the vote like any label, so Gaussians seen mostly in unassigned pixels
stay unassigned.

Rendering the one-hot labels of the Gaussians back gives view-consistent masks for every view,
including views that had no mask. (The authors' public code keeps per-view 2-D masks instead; this
3-D lifting is the paper's method.)
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch
from torch import Tensor

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.masks.params import UNDECIDED, LiftParams
from abcgs.render import accumulate_weights, rasterize
from abcgs.types import Backend

NO_VOTE = -1
"""Label-map value of a pixel that votes for nothing (not even 0 = unassigned): e.g. what a re-cut view left
undecided."""


LIFT_PIXELS = 1 << 20
"""Pixels of the largest view labels are lifted from and rendered into (about a megapixel): a larger view, a phone
photo of 12 Mpx or a 1080 × 1920 frame, is lifted at that size (:func:`lift_camera`), each of its pixels weighing
the photo pixels it covers, so that a Segment takes seconds at any photo size. Views of the pipeline's usual sizes
are lifted as they are."""


def lift_camera(camera: Camera, max_pixels: int | None = None) -> Camera:
    """``camera``, or the same view scaled down to at most ``max_pixels`` pixels (:data:`LIFT_PIXELS` by default,
    :meth:`Camera.scaled`)."""
    max_pixels = LIFT_PIXELS if max_pixels is None else max_pixels
    pixels = camera.width * camera.height
    if pixels <= max_pixels:
        return camera
    small = camera.scaled((max_pixels / pixels) ** 0.5)
    while small.width * small.height > max_pixels:  # rounding may add a row or a column
        small = camera.scaled(0.999 * small.width / camera.width)
    return small


def pixel_area(shape: tuple[int, ...], camera: Camera) -> float:
    """Pixels of a view of ``shape`` ``(H, W, ...)`` that one pixel of ``camera`` (the same view, scaled) covers."""
    return (shape[0] * shape[1]) / (camera.height * camera.width)


def area_weights(planes: np.ndarray, camera: Camera) -> np.ndarray:
    """Pixel weights ``(H, W, J) float32`` of a view scaled to ``camera``'s size ``(h, w, J)``: each pixel of
    ``camera`` holds the sum of the weights of the pixels it covers (OpenCV's area interpolation × the ratio of pixel
    counts), so that blending weights summed over a view keep their units, photo pixels, at either size."""
    planes = np.asarray(planes, np.float32)
    H, W = planes.shape[:2]
    if (H, W) == (camera.height, camera.width):
        return planes
    ratio = pixel_area(planes.shape, camera)
    out = np.empty((camera.height, camera.width, planes.shape[-1]), np.float32)
    for c in range(planes.shape[-1]):
        out[..., c] = cv2.resize(planes[..., c], (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    return out * ratio


@dataclass
class LiftResult:
    """Per-Gaussian labels ``(N,) int64`` (0 = unassigned), the vote ``weights (N, L+1)``, and ``decided (N,) bool``:
    the vote cleared both thresholds (or the label was propagated from 3-D neighbours). An undecided Gaussian has
    label 0 without anyone having chosen it: seen too little, or a split vote."""

    labels: Tensor
    weights: Tensor
    decided: Tensor

    def counts(self) -> dict[int, int]:
        vals, cnt = torch.unique(self.labels, return_counts=True)
        return {int(v): int(c) for v, c in zip(vals, cnt)}


def one_hot_labels(labels: np.ndarray | Tensor, n_labels: int, camera: Camera | None = None) -> Tensor:
    """``(H, W)`` int labels in 0..n_labels (or :data:`NO_VOTE`) → ``(H, W, n_labels + 1) float32`` one-hot (all
    zeros at :data:`NO_VOTE`); with ``camera`` of another size ``(h, w)``, ``(h, w, n_labels + 1)``: each label's
    pixels counted into the camera's pixels (:func:`area_weights`)."""
    lab = torch.as_tensor(np.asarray(labels), dtype=torch.long)
    if lab.min() < NO_VOTE or lab.max() > n_labels:
        raise InputError(f"label map has labels outside 0..{n_labels}: found {int(lab.min())}..{int(lab.max())}")
    if camera is not None and tuple(lab.shape) != (camera.height, camera.width):
        lab_np = lab.numpy()
        return torch.from_numpy(np.concatenate(
            [area_weights((lab_np == k).astype(np.float32)[..., None], camera) for k in range(n_labels + 1)], -1))
    votes = lab >= 0
    return torch.nn.functional.one_hot(lab.clamp_min(0), n_labels + 1).to(torch.float32) * votes[..., None]


def lift_labels(
    model: GaussianModel,
    cameras: list[Camera],
    label_maps: list[np.ndarray],
    n_labels: int,
    params: LiftParams | None = None,
    *,
    backend: Backend = "auto",
) -> LiftResult:
    """Vote per-Gaussian labels from label maps of some views.

    Args:
        model: the fitted scene. cameras: the masked views. label_maps: ``(H, W)`` int maps, one per camera,
        labels 0..n_labels at the camera's resolution.
    """
    params = params or LiftParams()
    if len(cameras) != len(label_maps):
        raise InputError(f"{len(cameras)} cameras but {len(label_maps)} label maps")
    if not cameras:
        raise InputError("no masked views to lift labels from; add label PNGs under <scene>/masks/")
    weights = torch.zeros(model.num_gaussians, n_labels + 1)  # on the host: one transfer per view, not per pixel
    for cam, lab in zip(cameras, label_maps):
        weights += view_weights(model, cam, lab, n_labels, backend=backend)
    return decide_labels(weights, params)


def view_weights(model: GaussianModel, camera: Camera, label_map: np.ndarray, n_labels: int, *,
                 backend: Backend = "auto") -> Tensor:
    """One view's votes ``(N, n_labels + 1)`` on the host: per Gaussian and label, its blending weight summed over
    the view's pixels of that label (:data:`NO_VOTE` pixels add nothing); a view larger than :data:`LIFT_PIXELS` is
    lifted at that size (:func:`lift_camera`)."""
    if tuple(label_map.shape) != (camera.height, camera.width):
        raise InputError(
            f"mask of view {camera.name} is {label_map.shape[1]}x{label_map.shape[0]}, the view is "
            f"{camera.width}x{camera.height}"
        )
    small = lift_camera(camera)
    return blend_votes(model, small, one_hot_labels(label_map, n_labels, small), backend=backend)


def blend_votes(model: GaussianModel, camera: Camera, pixels: Tensor, *, backend: Backend = "auto") -> Tensor:
    """Per Gaussian and channel, its blending weight in ``camera`` times the pixel weights ``pixels (H, W, J)``,
    summed over the view (:func:`abcgs.render.accumulate_weights`), on the host ``(N, J)``."""
    act = model.detach().activated()
    dev = model.device
    return accumulate_weights(act["means"], act["quats"], act["scales"], act["opacities"], camera.torch_viewmat(dev),
                              camera.torch_K(dev), pixels.to(dev), backend=backend).cpu()


def _depth_pass(model: GaussianModel, camera: Camera, backend: Backend):
    """``model`` rendered into ``camera`` for its depth alone: ``(alpha (H, W, 1), meta)`` (``meta.depth``: expected
    depth, world units; ``meta.means2d``, ``meta.depths``: each Gaussian's projected centre and camera depth)."""
    act = model.detach().activated()
    dev = model.device
    with torch.no_grad():
        _, alpha, meta = rasterize(act["means"], act["quats"], act["scales"], act["opacities"],
                                   torch.zeros(model.num_gaussians, 1, device=dev), camera.torch_viewmat(dev),
                                   camera.torch_K(dev), camera.width, camera.height, render_mode="RGB+ED",
                                   backend=backend)
    return alpha, meta


def rendered_depth(model: GaussianModel, camera: Camera, *, backend: Backend = "auto") -> np.ndarray:
    """The expected depth ``(h, w) float32`` (world units) that ``camera`` sees of ``model`` at its lifting size
    (:func:`lift_camera`), 0 where less than half of a pixel's alpha is rendered."""
    alpha, meta = _depth_pass(model, lift_camera(camera), backend)
    solid = alpha[..., 0] >= 0.5
    return torch.where(solid, meta.depth[..., 0], torch.zeros_like(alpha[..., 0])).numpy(force=True).astype(np.float32)


def occluded_gaussians(model: GaussianModel, camera: Camera, tolerance: float, *, backend: Backend = "auto") -> Tensor:
    """``(N,) bool``: the Gaussians whose centre lies behind the surface ``camera`` sees there, its camera depth
    beyond ``(1 + tolerance)`` × the view's expected depth at the pixel of its projected centre (where the view's
    alpha is at least 0.5). A label painted on a view belongs to its surface: a Gaussian hidden behind it (a wall
    behind a hood) still blends a little into its pixels, and would take that label from them. A view larger than
    :data:`LIFT_PIXELS` is rendered at that size (:func:`lift_camera`)."""
    camera = lift_camera(camera)
    alpha, meta = _depth_pass(model, camera, backend)
    uv = meta.means2d.detach().cpu().floor().long()
    z = meta.depths.detach().cpu()
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    u, v = uv[:, 0].clamp(0, camera.width - 1), uv[:, 1].clamp(0, camera.height - 1)
    surface = meta.depth[..., 0].detach().cpu()[v, u]
    solid = alpha[..., 0].detach().cpu()[v, u] >= 0.5
    return inside & solid & (z > surface * (1.0 + tolerance))


def decide_labels(weights: Tensor, params: LiftParams | None = None) -> LiftResult:
    """Summed votes ``(N, L + 1)`` → labels: the winner where it holds at least ``min_weight`` and a ``min_share`` of
    the Gaussian's total, else 0 (undecided)."""
    params = params or LiftParams()
    total = weights.sum(1)
    best_w, best = weights.max(1)
    ok = (best_w >= params.min_weight) & (best_w >= params.min_share * total.clamp_min(1e-12))
    labels = torch.where(ok, best, torch.zeros_like(best))
    return LiftResult(labels, weights, ok)


def propagate_labels(means: Tensor, labels: Tensor, unseen: Tensor, k: int = 8) -> Tensor:
    """Labels of the ``unseen`` Gaussians (``(N,)`` bool) from their ``k`` nearest *labelled* Gaussians (label > 0,
    world-space distance; majority vote, ties to the nearest); the others keep theirs. ``means (N, 3)``.

    Only Gaussians that no masked view saw are filled: one that was seen in unassigned (0) pixels stays 0, so
    what the user left unpainted stays unpainted.
    """
    from scipy.spatial import cKDTree

    labelled = labels > 0
    out = labels.clone()
    if not bool(unseen.any()) or not bool(labelled.any()):
        return out
    pts = means.detach().cpu().double().numpy()
    src = np.flatnonzero(labelled.numpy())
    kk = min(k, len(src))
    _, nn = cKDTree(pts[src]).query(pts[unseen.numpy()], k=kk)
    nn = np.asarray(nn).reshape(-1, kk)
    votes = labels.numpy()[src][nn]  # (M, kk), nearest first
    n_labels = int(labels.max())
    counts = np.stack([(votes == j).sum(1) for j in range(1, n_labels + 1)], 1)
    best = counts.max(1, keepdims=True)
    # ties: the label of the nearest neighbour among the tied ones
    tied = counts == best
    pick = np.array([next(v for v in row if tied[i, v - 1]) for i, row in enumerate(votes)])
    out[unseen] = torch.as_tensor(pick, dtype=out.dtype)
    return out


def propagate_unseen(model: GaussianModel, lifted: LiftResult, params: LiftParams, *,
                     undecided: bool = False) -> tuple[LiftResult, int]:
    """Labels for the Gaussians whose summed vote is below ``params.min_weight`` (no masked view saw them) and, with
    ``undecided``, also for those whose vote was split between labels (undecided, and "no label" (0) not the largest
    share: a vote for 0 is the user's and stays); the filled ones count as decided. ``params.propagate_along``:
    ``position``: :func:`propagate_labels` from the nearest labelled Gaussians; ``surface``:
    :func:`abcgs.masks.spread.spread_labels` from the decided ones along position and colour. Returns the new result
    and how many Gaussians changed label."""
    unseen = lifted.weights.sum(1) < params.min_weight
    if undecided and lifted.weights.shape[1] > 1:
        unseen |= ~lifted.decided & (lifted.weights[:, 0] < lifted.weights[:, 1:].max(1).values)
    if params.propagate_along == "surface":
        from abcgs.masks.spread import spread_labels, surface_features

        labels, _ = spread_labels(surface_features(model, params.propagate_colour_weight), lifted.labels,
                                  lifted.decided & ~unseen, unseen, model.opacities.detach().cpu(), params.propagate_k)
    else:
        labels = propagate_labels(model.means, lifted.labels, unseen, params.propagate_k)
    changed = labels != lifted.labels
    return LiftResult(labels, lifted.weights, lifted.decided | (unseen & (labels > 0))), int(changed.sum())


def label_colours(labels: Tensor, n_labels: int, decided: Tensor | None = None) -> Tensor:
    """Per-Gaussian labels ``(N,)`` 0..n_labels → the one-hot "colours" that render them ``(N, n_labels + 2)
    float32``: channel k for label k, and the last channel (``n_labels + 1``) for the Gaussians ``decided (N,) bool``
    marks False (with ``decided`` None, every Gaussian counts as decided and the last channel stays empty)."""
    cls = torch.as_tensor(labels).long()
    if decided is not None:
        cls = torch.where(torch.as_tensor(decided), cls, torch.full_like(cls, n_labels + 1))
    return torch.nn.functional.one_hot(cls, n_labels + 2).to(torch.float32)


def pick_labels(img: Tensor, alpha: Tensor, threshold: float, *, min_alpha: float = 1e-3, none: int = 0,
                undecided: int = UNDECIDED) -> Tensor:
    """Rendered :func:`label_colours` ``img (..., H, W, C)`` with its ``alpha (..., H, W, 1)`` → each pixel's channel
    of largest blending weight ``(..., H, W) int64``, where that weight is at least ``threshold`` of the pixel's alpha
    and the alpha exceeds ``min_alpha``; ``undecided`` where that channel is the last one (the undecided
    Gaussians'), ``none`` elsewhere."""
    a = alpha[..., 0]
    best_w, best = img.max(-1)
    ok = (best_w >= threshold * a) & (a > min_alpha)
    best = torch.where(best == img.shape[-1] - 1, torch.full_like(best, undecided), best)
    return torch.where(ok, best, torch.full_like(best, none))


def render_label_weights(model: GaussianModel, labels: Tensor, n_labels: int, camera: Camera, *,
                         decided: Tensor | None = None, backend: Backend = "auto") -> tuple[Tensor, Tensor]:
    """Per-Gaussian labels rendered into ``camera`` as weights: ``(H, W, n_labels + 2)`` (each label's blending weight
    at each pixel, and the undecided Gaussians' in the last channel, :func:`label_colours`) and the alpha ``(H, W, 1)``,
    on the host."""
    act = model.detach().activated()
    dev = model.device
    colours = label_colours(labels, n_labels, decided).to(dev)
    with torch.no_grad():
        img, alpha, _ = rasterize(
            act["means"], act["quats"], act["scales"], act["opacities"], colours, camera.torch_viewmat(dev),
            camera.torch_K(dev), camera.width, camera.height, backend=backend,
        )
    return img.cpu(), alpha.cpu()


def render_label_map(
    model: GaussianModel, labels: Tensor, n_labels: int, camera: Camera, *, decided: Tensor | None = None,
    threshold: float = 0.5, undecided: int = UNDECIDED, backend: Backend = "auto",
) -> np.ndarray:
    """Render per-Gaussian labels into ``camera``: ``(H, W) int64``.

    Each pixel takes the label with the largest accumulated blending weight, if that weight is at least
    ``threshold`` of the pixel's alpha (else 0, as are empty pixels). With ``decided`` ``(N,) bool``, the undecided
    Gaussians render as a label of their own, and pixels they win are ``undecided``
    (:data:`~abcgs.masks.params.UNDECIDED`).
    """
    img, alpha = render_label_weights(model, labels, n_labels, camera, decided=decided, backend=backend)
    return pick_labels(img, alpha, threshold, undecided=undecided).numpy().astype(np.int64)
