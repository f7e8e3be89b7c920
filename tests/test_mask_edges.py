"""A view's rendered labels refined against its photo (abcgs/masks/edges.py, abcgs.masks.field.refine_labels): the
domain transform moves a border onto the photo's edge, fills what the Gaussians left undecided, outweighs a blob
painted over a region of one colour, keeps a region of its own colour, and does the same at any photo size."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from abcgs.masks.edges import refine_to_photo
from abcgs.masks.field import refine_labels
from abcgs.masks.params import FieldParams

H, W = 60, 90
_FIELD = FieldParams()


def _refine(w: np.ndarray, a: np.ndarray, photo: np.ndarray, radius: float, method: str = "domain") -> np.ndarray:
    """:func:`refine_to_photo` with ``masks.field``'s default colour σ and regularisation."""
    return refine_to_photo(w, a, photo, method=method, radius=radius, colour=_FIELD.edge_colour, eps=_FIELD.edge_eps)


def _weights(labels: np.ndarray, n_labels: int, undecided: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One-hot rendered weights ``(H, W, n_labels + 2)`` of a label map (the undecided channel last) and full alpha."""
    w = np.zeros((*labels.shape, n_labels + 2), np.float32)
    np.put_along_axis(w, labels[..., None], 1.0, -1)
    if undecided is not None:
        w[undecided] = 0.0
        w[undecided, -1] = 1.0
    return w, np.ones((*labels.shape, 1), np.float32)


def _two_tone(h: int = H, w: int = W, edge: float = 0.5) -> np.ndarray:
    """A photo, dark grey left of ``edge`` × width and light yellow right of it, with a little noise (σ 1 level)."""
    rng = np.random.default_rng(0)
    photo = np.empty((h, w, 3), np.float32)
    photo[:, : int(edge * w)] = (60, 60, 70)
    photo[:, int(edge * w):] = (230, 210, 90)
    return np.clip(photo + rng.normal(0, 1, photo.shape), 0, 255).astype(np.uint8)


def test_a_border_a_few_pixels_off_moves_onto_the_photos_edge() -> None:
    photo = _two_tone()
    rendered = np.where(np.arange(W)[None, :] < 42, 1, 2).repeat(H, 0)  # the photo's edge is at 45
    rendered[:, 49:52] = 1  # and a 3-px line of label 1 on the other side
    w, a = _weights(rendered, 2)
    out = _refine(w, a, photo, 0.25)
    assert (out[:, :45] == 1).all() and (out[:, 45:] == 2).all()


def test_the_domain_transform_outweighs_a_blob_that_the_guided_filter_keeps() -> None:
    photo = _two_tone()
    rendered = np.where(np.arange(W)[None, :] < 45, 1, 2).repeat(H, 0)
    rendered[20:32, 12:24] = 2  # 12 × 12 px of the bright side's label on the dark side
    w, a = _weights(rendered, 2)
    domain = _refine(w, a, photo, 0.25)
    guided = _refine(w, a, photo, 0.01, "guided")
    assert (domain[:, :45] == 1).all() and (domain[:, 45:] == 2).all()
    assert (guided[22:30, 14:22] == 2).all()  # a radius of a pixel keeps what is wider than it


def test_undecided_pixels_take_the_label_on_their_side_of_the_edge() -> None:
    photo = _two_tone()
    rendered = np.where(np.arange(W)[None, :] < 45, 1, 2).repeat(H, 0)
    undecided = np.zeros((H, W), bool)
    undecided[20:40, 35:55] = True  # a hole across the edge
    w, a = _weights(rendered, 2, undecided)
    out = _refine(w, a, photo, 0.25)
    assert (out[20:40, 35:45] == 1).all() and (out[20:40, 45:55] == 2).all()


def test_a_blob_over_one_colour_goes_and_a_region_of_its_own_colour_stays() -> None:
    photo = np.full((H, W, 3), (200, 120, 160), np.uint8)
    photo[10:30, 55:80] = (30, 160, 60)  # a green patch on a pink wall
    rendered = np.ones((H, W), np.int64)
    rendered[35:50, 10:30] = 2  # a blob of label 2 that the photo does not show (300 px, 5.6 % of the view)
    rendered[10:30, 55:80] = 3  # the green patch, labelled as such
    rendered[10:30, 50:55] = 3  # with a 5-px fringe over the wall
    w, a = _weights(rendered, 3)
    out = refine_labels(w, a, photo, FieldParams(min_region=0.0))
    assert (out[35:50, 10:30] == 1).all(), "the blob over one colour is outweighed by the region around it"
    assert (out[10:30, 55:80] == 3).all() and (out[10:30, 50:55] == 1).all()


def test_the_refined_labels_are_the_same_at_twice_the_photo_size() -> None:
    rng = np.random.default_rng(1)
    photo = _two_tone()
    photo[35:55, 10:30] = (40, 90, 200)  # a blue square on the dark side
    rendered = np.where(np.arange(W)[None, :] < 40, 1, 2).repeat(H, 0)
    rendered[33:52, 12:33] = 3  # the square, rendered a little off
    rendered[rng.random((H, W)) < 0.05] = 2  # and stray pixels
    w, a = _weights(rendered, 3)
    p = FieldParams(min_region=0.0)
    small = refine_labels(w, a, photo, p)
    big_w = cv2.resize(w, (2 * W, 2 * H), interpolation=cv2.INTER_NEAREST)
    big_photo = cv2.resize(photo, (2 * W, 2 * H), interpolation=cv2.INTER_NEAREST)
    big = refine_labels(big_w, np.ones((2 * H, 2 * W, 1), np.float32), big_photo, p)
    agree = (cv2.resize(small, (2 * W, 2 * H), interpolation=cv2.INTER_NEAREST) == big).mean()
    assert agree > 0.98, agree
    assert (small[36:54, 11:29] == 3).all()


def test_refine_refuses_a_photo_of_another_size() -> None:
    w, a = _weights(np.ones((H, W), np.int64), 1)
    with pytest.raises(ValueError, match="the photo is 10x10"):
        _refine(w, a, np.zeros((10, 10, 3), np.uint8), 0.25)


def test_the_guided_filters_coefficients_match_the_papers_equations_in_float64() -> None:
    """guided_coefficients against He et al.'s Eqs. 14-15 written out in float64 with SciPy's box filter (OpenCV's
    own guidedFilter differs from both by up to 0.0025 inside the image, so it is not the reference)."""
    from scipy.ndimage import uniform_filter

    from abcgs.masks.edges import guided_coefficients

    rng = np.random.default_rng(0)
    photo = cv2.resize(rng.integers(0, 255, (30, 40, 3), dtype=np.uint8), (200, 150), interpolation=cv2.INTER_CUBIC)
    planes = cv2.GaussianBlur((rng.random((150, 200, 3)) > 0.5).astype(np.float32), (0, 0), 3)
    r, eps = 4, 1e-3

    def box(x):
        return uniform_filter(x, size=(2 * r + 1, 2 * r + 1) + (1,) * (x.ndim - 2), mode="reflect")

    guide, p = photo.astype(np.float64) / 255, planes.astype(np.float64)
    mean_i, mean_p = box(guide), box(p)
    sigma = box(guide[..., :, None] * guide[..., None, :]) - mean_i[..., :, None] * mean_i[..., None, :] + eps * np.eye(3)
    cov = box(guide[..., :, None] * p[..., None, :]) - mean_i[..., :, None] * mean_p[..., None, :]
    a = np.linalg.solve(sigma, cov).transpose(0, 1, 3, 2)
    b = mean_p - np.einsum("hwci,hwi->hwc", a, mean_i)
    expected = np.einsum("hwci,hwi->hwc", box(a), guide) + box(b)
    A, B = guided_coefficients(photo.astype(np.float32) / 255, planes, r, eps)
    got = np.einsum("cihw,hwi->hwc", A, photo.astype(np.float32) / 255) + B.transpose(1, 2, 0)
    np.testing.assert_allclose(got, expected, atol=1e-5)


def test_upsampled_labels_follow_the_photos_edge_and_computing_only_the_band_changes_nothing() -> None:
    """Labels at a working size brought to the photo's size: the slanted border lands on the photo's edge (nearest
    scaling leaves it in steps), pixels far from any border keep the working pixel's label, and the result equals
    the fast guided filter applied at every pixel."""
    from abcgs.masks.edges import UPSAMPLE_EPS, UPSAMPLE_RADIUS, _bilinear, guided_coefficients, upsample_labels

    h, w = 300, 480
    yy, xx = np.mgrid[:h, :w]
    truth = np.where(yy > 0.4 * xx + 40, 2, np.where(xx > 0.8 * w, 1, 3))
    rng = np.random.default_rng(1)
    colours = np.uint8([[0, 0, 0], [200, 60, 40], [40, 90, 200], [60, 160, 60]])
    photo = np.clip(colours[truth] + rng.normal(0, 2, (h, w, 3)), 0, 255).astype(np.uint8)
    small = cv2.resize(truth.astype(np.uint8), (96, 60), interpolation=cv2.INTER_NEAREST).astype(np.int64)
    claimed = np.ones(small.shape, bool)
    claimed[:4, :4] = False  # a corner the cut left to nobody
    out, keep = upsample_labels(small, claimed, photo)
    nearest = cv2.resize(small.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
    assert out.shape == keep.shape == (h, w) and not keep[:10, :10].any() and (out[:10, :10] == 0).all()
    assert (out != truth)[keep].sum() < 0.2 * (nearest != truth)[keep].sum()
    # the same filter at every pixel
    values = np.array([1, 2, 3, 0])
    index = np.where(claimed, small - 1, 3)
    planes = (index[..., None] == np.arange(4)).astype(np.float32)
    guide = cv2.resize(photo, (96, 60), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    a, b = guided_coefficients(guide, planes, UPSAMPLE_RADIUS, UPSAMPLE_EPS)
    ys, xs = (v.ravel() for v in np.mgrid[:h, :w])
    coef = _bilinear(np.concatenate([a.reshape(12, 60, 96), b]), ys, xs, (h / 60, w / 96))
    q = coef[:, 12:] + sum(coef[:, i:12:3] * (photo[ys, xs, i:i + 1] / 255.0) for i in range(3))
    np.testing.assert_array_equal(out.ravel(), values[q.argmax(-1)])


def test_upsampling_a_map_of_the_photos_size_keeps_it() -> None:
    from abcgs.masks.edges import upsample_labels

    labels = np.arange(12).reshape(3, 4) % 3
    claimed = labels > 0
    out, keep = upsample_labels(labels, claimed, np.zeros((3, 4, 3), np.uint8))
    np.testing.assert_array_equal(out, np.where(claimed, labels, 0))
    np.testing.assert_array_equal(keep, claimed)
