"""Labels in each view sharper than the Gaussians: a view's labels rendered from the Gaussians, refined against the
edges of its photo.

The labels rendered from the Gaussians follow the fitted geometry, whose borders are as soft as the splats'
footprints, and a pixel where undecided Gaussians win has no label. :func:`refine_to_photo` filters each label's
rendered weight with an edge-aware filter whose guide is the view's photo: the weights spread inside a region of one
colour and not across the photo's edges, so each pixel takes the label whose filtered weight is largest, a label's
border moves onto the photo's edge nearest to it, and a pixel of undecided Gaussians takes the label around it on
its side of the edges. Two filters (``masks.field.edge_filter``), both OpenCV contrib's ``ximgproc``:

- ``domain`` (the default): the domain transform's normalized convolution (Gastal and Oliveira, SIGGRAPH 2011). A
  label's weight spreads over a spatial σ_s of ``radius`` × the view's shorter side, measured along the photo: a
  step of colour whose RGB differences sum to ``colour`` (σ_r, 8-bit levels) counts as σ_s of distance. So a label
  reaches across a surface of one colour and stops at a change of colour several times σ_r. A blob that a few
  wrong splats paint over part of a region of another colour is outweighed by the region around it, and a region
  the Gaussians paint in part is filled to its edges.
- ``guided``: the guided filter (He, Sun and Tang, TPAMI 2013) of radius ``radius`` × the shorter side and
  regularisation ``eps``: a local linear model of the photo, which moves a border by about its radius.

A stray splat or two leaves specks of a label in a view, a few pixels that a painting would paint as its own;
:func:`drop_specks` gives each connected region smaller than a share of the view the label of its surroundings, as
SAM's mask post-processing removes small islands and holes (``remove_small_regions``).
"""

from __future__ import annotations

import cv2
import numpy as np

from abcgs.masks.params import EdgeFilter

FILTER_CHANNELS = 4
"""Channels OpenCV's guided filter takes at a time."""


def guided_filter(photo: np.ndarray, planes: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """``planes`` ``(H, W, C) float32`` filtered with ``photo`` ``(H, W, 3) uint8`` as the guide (RGB in 0..1),
    ``radius`` in pixels, regularisation ``eps``; ``(H, W, C) float32``."""
    guide = photo.astype(np.float32) / 255.0
    out = np.empty(planes.shape, np.float32)
    for c0 in range(0, planes.shape[-1], FILTER_CHANNELS):
        part = np.ascontiguousarray(planes[..., c0:c0 + FILTER_CHANNELS], np.float32)
        out[..., c0:c0 + FILTER_CHANNELS] = cv2.ximgproc.guidedFilter(guide, part, radius, eps).reshape(part.shape)
    return out


def domain_filter(photo: np.ndarray, planes: np.ndarray, sigma_space: float, sigma_colour: float) -> np.ndarray:
    """``planes`` ``(H, W, C) float32`` filtered by the domain transform's normalized convolution with ``photo``
    ``(H, W, 3) uint8`` as the guide: spatial σ ``sigma_space`` in pixels, colour σ ``sigma_colour`` in 8-bit levels
    (three iterations, OpenCV's default); ``(H, W, C) float32``."""
    dt = cv2.ximgproc.createDTFilter(photo, float(sigma_space), float(sigma_colour), cv2.ximgproc.DTF_NC, 3)
    out = np.empty(planes.shape, np.float32)
    for c in range(planes.shape[-1]):
        out[..., c] = dt.filter(np.ascontiguousarray(planes[..., c], np.float32))
    return out


def refine_to_photo(weights: np.ndarray, alpha: np.ndarray, photo: np.ndarray, *, method: EdgeFilter, radius: float,
                    colour: float, eps: float, min_alpha: float = 1e-3) -> np.ndarray:
    """A view's labels ``(H, W) int64`` from its rendered label weights refined against its photo (module docstring).
    The settings are ``masks.field``'s (:func:`abcgs.masks.field.refine_labels` passes them).

    Args:
        weights: ``(H, W, L + 2)``: labels 0..L and the undecided Gaussians' weight last
            (:func:`abcgs.masks.lifting.render_label_weights`). alpha: ``(H, W, 1)``.
        photo: ``(H, W, 3) uint8``.
        radius: how far a label spreads along the photo, as a share of the view's shorter side: the domain
            transform's spatial σ, the guided filter's radius.
        eps: ``guided``: the filter's regularisation (guide in 0..1): edges of a contrast above about √eps hold.
        min_alpha: pixels of less alpha (nothing rendered) are 0.
        method: ``domain`` or ``guided`` (module docstring).
        colour: ``domain``: the colour σ_r, in 8-bit levels: a step of colour whose RGB differences sum to it
            counts as ``radius`` of distance.

    Returns:
        each pixel's label of largest filtered weight, 0 where nothing is rendered or no label reaches.
    """
    h, w = weights.shape[:2]
    if photo.shape[:2] != (h, w):
        raise ValueError(f"the photo is {photo.shape[1]}x{photo.shape[0]}, the labels {w}x{h}")
    labels = np.asarray(weights, np.float32)[..., :-1]  # the undecided Gaussians take the labels around them
    if method == "domain":
        filtered = domain_filter(photo, labels, max(1.0, radius * min(h, w)), colour)
    else:
        filtered = guided_filter(photo, labels, max(1, int(round(radius * min(h, w)))), eps)
    best = filtered.argmax(-1)
    ok = (filtered.max(-1) > 1e-3) & (np.asarray(alpha)[..., 0] > min_alpha)
    return np.where(ok, best, 0).astype(np.int64)


def drop_specks(labels: np.ndarray, min_pixels: int) -> np.ndarray:
    """``labels`` ``(H, W) int`` with every 8-connected region of one value smaller than ``min_pixels`` given the
    value of the nearest pixel outside all such regions (Euclidean distance transform); unchanged where
    ``min_pixels`` < 2 or every region is small."""
    from scipy.ndimage import distance_transform_edt

    labels = np.asarray(labels)
    if min_pixels < 2:
        return labels.copy()
    small = np.zeros(labels.shape, bool)
    for v in np.unique(labels):
        n, comp, stats, _ = cv2.connectedComponentsWithStats((labels == v).astype(np.uint8), connectivity=8)
        tiny = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] < min_pixels)
        tiny = tiny[tiny > 0]
        if len(tiny):
            small |= np.isin(comp, tiny)
    if not small.any() or small.all():
        return labels.copy()
    _, (iy, ix) = distance_transform_edt(small, return_indices=True)
    return np.where(small, labels[iy, ix], labels)
