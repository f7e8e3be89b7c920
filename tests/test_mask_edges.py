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
