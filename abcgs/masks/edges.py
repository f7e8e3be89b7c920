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
"""Channels OpenCV's guided and box filters take at a time."""

UPSAMPLE_EPS = 1e-3
"""Regularisation ε of the guided filter that brings labels at a working size back to the photo's size (guide RGB in
0..1): a label's border follows a colour edge of more than about √ε ≈ 0.03 of contrast."""

UPSAMPLE_RADIUS = 2
"""That filter's radius, in working pixels."""

REMAP_COLUMNS = 4096
"""Columns of the maps pixels are sampled through (OpenCV's ``remap``)."""


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


def box_mean(x: np.ndarray, radius: int) -> np.ndarray:
    """The mean of the plane ``x`` ``(H, W) float32`` over each pixel's ``(2 radius + 1)²`` window (borders
    reflected, as OpenCV's guided filter does)."""
    return cv2.boxFilter(x, -1, (2 * radius + 1, 2 * radius + 1), borderType=cv2.BORDER_REFLECT)


def _inverse3(m: np.ndarray) -> np.ndarray:
    """The inverses of symmetric ``(M, 3, 3)`` matrices by their adjugates (the guided filter's regularised
    covariances, positive definite)."""
    a, b, c = m[:, 0, 0], m[:, 0, 1], m[:, 0, 2]
    e, f, i = m[:, 1, 1], m[:, 1, 2], m[:, 2, 2]
    adj = np.stack([e * i - f * f, c * f - b * i, b * f - c * e,
                    c * f - b * i, a * i - c * c, b * c - a * f,
                    b * f - c * e, b * c - a * f, a * e - b * b], -1).reshape(-1, 3, 3)
    det = a * adj[:, 0, 0] + b * adj[:, 1, 0] + c * adj[:, 2, 0]
    return adj / det[:, None, None]


def guided_coefficients(guide: np.ndarray, planes: np.ndarray, radius: int, eps: float,
                        active: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The guided filter's local linear model (He, Sun and Tang, TPAMI 2013, Eqs. 14-15, colour guide), averaged over
    each window: ``A (C, 3, H, W)`` and ``B (C, H, W)`` such that plane c of the filter's output is
    ``Σ_i A[c, i] guide[..., i] + B[c]``. ``guide`` ``(H, W, 3) float32`` (RGB in 0..1), ``planes`` ``(H, W, C)
    float32``. With ``active`` ``(H, W) bool``, the model is solved there only: elsewhere every plane must be
    constant over the pixel's window, where the model is that constant."""
    h, w, c = planes.shape
    at = np.flatnonzero(np.ones((h, w), bool) if active is None else active)
    guide_planes = [np.ascontiguousarray(guide[..., i], np.float32) for i in range(3)]
    mean_i = [box_mean(g, radius) for g in guide_planes]
    mean_at = [m.ravel()[at] for m in mean_i]
    sigma = np.empty((len(at), 3, 3), np.float32)
    for i in range(3):
        for j in range(i, 3):
            v = box_mean(guide_planes[i] * guide_planes[j], radius).ravel()[at] - mean_at[i] * mean_at[j]
            sigma[:, i, j] = sigma[:, j, i] = v + (eps if i == j else 0.0)
    inverse = _inverse3(sigma)
    A = np.empty((c, 3, h, w), np.float32)
    B = np.empty((c, h, w), np.float32)
    for k in range(c):
        p = np.ascontiguousarray(planes[..., k], np.float32)
        mean_p = box_mean(p, radius)
        cov = np.stack([box_mean(g * p, radius).ravel()[at] - m * mean_p.ravel()[at]
                        for g, m in zip(guide_planes, mean_at)], -1)
        a = np.zeros((3, h * w), np.float32)
        a[:, at] = np.einsum("mij,mj->im", inverse, cov)
        a = a.reshape(3, h, w)
        B[k] = box_mean(mean_p - a[0] * mean_i[0] - a[1] * mean_i[1] - a[2] * mean_i[2], radius)
        for i in range(3):
            A[k, i] = box_mean(a[i], radius)
    return A, B


def _bilinear(planes: np.ndarray, ys: np.ndarray, xs: np.ndarray, scale: tuple[float, float]) -> np.ndarray:
    """``planes`` ``(C, h, w) float32`` sampled bilinearly at the pixel centres ``(ys, xs)`` ``(M,)`` of an image
    ``scale`` = (H / h, W / w) times as large (pixel-centre convention, edges replicated): ``(M, C)``."""
    m, cols = len(xs), REMAP_COLUMNS
    rows = max(1, -(-m // cols))  # OpenCV's remap takes maps of fewer than 32767 rows and columns: fold them
    map_x = np.zeros(rows * cols, np.float32)
    map_y = np.zeros(rows * cols, np.float32)
    map_x[:m] = (xs + 0.5) / scale[1] - 0.5
    map_y[:m] = (ys + 0.5) / scale[0] - 0.5
    map_x, map_y = map_x.reshape(rows, cols), map_y.reshape(rows, cols)
    out = np.empty((m, len(planes)), np.float32)
    for c, plane in enumerate(planes):
        got = cv2.remap(plane, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        out[:, c] = got.ravel()[:m]
    return out


def upsample_labels(labels: np.ndarray, claimed: np.ndarray, photo: np.ndarray, eps: float = UPSAMPLE_EPS,
                    radius: int = UPSAMPLE_RADIUS) -> tuple[np.ndarray, np.ndarray]:
    """Labels at a working size (``labels (h, w) int``, ``claimed (h, w) bool``) brought to the size of ``photo``
    ``(H, W, 3) uint8`` along the photo's edges, by the fast guided filter (He and Sun, arXiv:1505.00996): each
    value's indicator (and the unclaimed one) is guided-filtered at the working size with the photo scaled down as
    the guide (``radius`` working pixels, regularisation ``eps``, guide in 0..1), the filter's linear coefficients
    are scaled up bilinearly and applied to the full-size photo, and each pixel takes the largest. Only pixels
    within reach of a change of value are computed: elsewhere the coefficients are those of a constant and the
    value is the working pixel's. Returns ``(H, W) int64`` and ``(H, W) bool``; the labels as they are when the
    sizes agree."""
    H, W = photo.shape[:2]
    h, w = labels.shape
    labels = np.asarray(labels, np.int64)
    if (h, w) == (H, W):
        return np.where(claimed, labels, 0), np.asarray(claimed, bool).copy()
    values = np.asarray([int(v) for v in np.unique(labels[claimed])] + [0], np.int64)
    index = np.where(claimed, np.searchsorted(values[:-1], labels), len(values) - 1)
    planes = (index[..., None] == np.arange(len(values))).astype(np.float32)
    small = cv2.resize(photo, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    small_index = index.astype(np.uint16)

    def near_a_change(reach: int) -> np.ndarray:
        window = np.ones((2 * reach + 1,) * 2, np.uint8)
        return cv2.dilate(small_index, window) != cv2.erode(small_index, window)

    a, b = guided_coefficients(small, planes, radius, eps, active=near_a_change(radius))
    # where the windows of 2 radius + 1 (and the bilinear step) hold one value, the filter returns that value
    changes = near_a_change(2 * radius + 2)
    full = cv2.resize(small_index, (W, H), interpolation=cv2.INTER_NEAREST)
    band = cv2.resize(changes.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST).astype(bool)
    ys, xs = np.nonzero(band)
    scale = (H / h, W / w)
    c = len(values)
    coef = _bilinear(np.concatenate([a.reshape(3 * c, h, w), b]), ys, xs, scale)
    guide = photo[ys, xs].astype(np.float32) / 255.0
    q = coef[:, 3 * c:]
    for i in range(3):
        q += coef[:, i:3 * c:3] * guide[:, i:i + 1]
    full[ys, xs] = q.argmax(-1)
    keep = full < len(values) - 1
    return np.where(keep, values[full], 0), keep


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
