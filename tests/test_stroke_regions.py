"""A stroke's region in its photo (abcgs/masks/regions.py): the correction evidence of ``masks.field.correction:
region``, a colour flood fill from each stroke bounded by the photo's edges and by a disc of ``reach``."""

from __future__ import annotations

import numpy as np
import pytest

from abcgs.masks.lifting import NO_VOTE
from abcgs.masks.regions import stroke_regions

H, W = 60, 90


def two_colour_photo() -> np.ndarray:
    """Left of x = 40 red, right blue, with a little noise."""
    rng = np.random.default_rng(0)
    photo = np.zeros((H, W, 3), np.float64)
    photo[:, :40] = (200, 40, 40)
    photo[:, 40:] = (40, 40, 200)
    return np.clip(photo + rng.normal(0, 3, photo.shape), 0, 255).astype(np.uint8)


def dot(y: int, x: int, label: int, r: int = 1) -> np.ndarray:
    seeds = np.full((H, W), -1, np.int64)
    seeds[y - r:y + r + 1, x - r:x + r + 1] = label
    return seeds


def test_a_dot_takes_its_colour_region_up_to_the_photo_edge_and_within_its_reach():
    out = stroke_regions(two_colour_photo(), dot(30, 20, 3), reach_px=30, tolerance=12.0)
    region = out == 3
    assert region[:, :40].mean() > 0.7  # most of the red half lies within 30 px of the dot
    assert not region[:, 40:].any()  # the edge holds
    assert (out[~region] == NO_VOTE).all()
    ys, xs = np.nonzero(region)
    assert np.hypot(ys - 30, xs - 20).max() <= 30 + np.sqrt(2) + 1e-6  # and the disc (from the 3 × 3 dot)


def test_two_strokes_of_one_colour_share_it_by_colour_and_reach_and_the_background_brush_counts():
    seeds = dot(30, 10, 1)
    seeds[28:33, 60:63] = 0  # the background brush on the blue half
    out = stroke_regions(two_colour_photo(), seeds, reach_px=25, tolerance=12.0)
    assert (out[:, :40][out[:, :40] != NO_VOTE] == 1).all()
    assert (out[:, 40:][out[:, 40:] != NO_VOTE] == 0).all() and (out[:, 40:] == 0).mean() > 0.4


def test_no_reach_or_tolerance_leaves_the_strokes_alone():
    seeds = dot(30, 20, 2)
    for reach, tol in ((0, 12.0), (20, 0.0)):
        out = stroke_regions(two_colour_photo(), seeds, reach_px=reach, tolerance=tol)
        assert ((out == 2) == (seeds == 2)).all() and (out[seeds < 0] == NO_VOTE).all()


def test_a_stroke_across_the_edge_keeps_its_pixels_and_takes_both_sides_only_near_its_colour():
    seeds = np.full((H, W), -1, np.int64)
    seeds[30, 30:50] = 4  # mostly red (10 px), half blue: the mean colour lies between
    out = stroke_regions(two_colour_photo(), seeds, reach_px=10, tolerance=12.0)
    assert (out[seeds == 4] == 4).all()
    assert (out == 4).sum() == (seeds == 4).sum()  # neither side is near the mean colour: the stroke alone


def test_a_photo_of_another_size_is_refused():
    with pytest.raises(ValueError, match="the photo is 90x59, the strokes 90x60"):
        stroke_regions(two_colour_photo()[:-1], dot(30, 20, 1), reach_px=5, tolerance=10.0)


def test_a_click_is_a_round_mark_and_its_region_reaches_further_than_a_strokes():
    """A dot is a click (:func:`abcgs.masks.regions.is_click`), a line of the same brush is not; with ``click`` the
    dot's region takes the click's reach, the line's the stroke's."""
    from abcgs.masks.regions import is_click

    yy, xx = np.mgrid[:H, :W]
    disc = (yy - 30) ** 2 + (xx - 15) ** 2 <= 9
    line = (np.abs(yy - 30) <= 2) & (xx >= 5) & (xx <= 35)
    assert is_click(disc) and not is_click(line) and not is_click(np.zeros((H, W), bool))
    for mark, label in ((disc, 1), (line, 2)):
        seeds = np.where(mark, label, -1)
        out = stroke_regions(two_colour_photo(), seeds, reach_px=5, tolerance=12.0, click=(20, 12.0))
        ys, xs = np.nonzero(out == label)
        farthest = np.hypot(ys[:, None] - np.argwhere(mark)[:, 0], xs[:, None] - np.argwhere(mark)[:, 1]).min(1).max()
        if label == 1:
            assert 15 < farthest <= 20 + 1e-6  # the click's reach
        else:
            assert farthest <= 5 + 1e-6  # the stroke's
        assert not (out[:, 40:] == label).any()  # the photo's edge holds for both


def test_a_region_of_one_colour_stops_at_a_step_of_the_views_depth():
    """A grey object before a grey wall: colour alone floods both; the rendered depth's step (the object at 2 world
    units, the wall at 5) stops the region at the object's outline, and a smooth slope or a hole in the render
    (nothing rendered: no depth to go by) does not."""
    from abcgs.masks.regions import depth_steps

    photo = np.full((H, W, 3), 128, np.uint8)
    depth = np.full((H, W), 5.0, np.float32)
    depth[15:45, 20:60] = 2.0 + np.linspace(0.0, 0.02, 40)[None, :]  # a slope of 1 % across the object
    depth[28:32, 30:34] = 0.0  # a hole in the render inside it
    steps = depth_steps(depth, 0.02)
    assert steps[14:16, 20:60].all() and steps[15:45, 59:61].all()  # the outline, on both sides of the step
    assert not steps[18:42, 23:28].any() and not steps[26:34, 28:36].any()  # the slope and round the hole
    seeds = dot(20, 40, 2)
    free = stroke_regions(photo, seeds, reach_px=80, tolerance=12.0)
    assert (free == 2).all()  # one colour: the whole photo
    bound = stroke_regions(photo, seeds, reach_px=80, tolerance=12.0, barrier=steps)
    region = bound == 2
    assert region[17:43, 22:58].all()  # the object, its hole included
    assert not region[:13].any() and not region[:, 62:].any()  # not the wall
    half = depth_steps(depth[::2, ::2], 0.02, (H, W))  # a depth rendered at half the photo's size
    assert half.shape == (H, W) and half[14:16, 24:56].any() and not half[20:40, 26:54].any()
    with pytest.raises(ValueError, match="barrier"):
        stroke_regions(photo, seeds, reach_px=10, tolerance=12.0, barrier=steps[:, :-1])
