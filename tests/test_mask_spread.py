"""Label spreading along the Gaussians' surfaces (abcgs/masks/spread.py, ``masks.lift.propagate_along: surface``)."""

from __future__ import annotations

import numpy as np
import torch

from abcgs.gaussians import GaussianModel
from abcgs.masks.lifting import LiftResult, propagate_unseen
from abcgs.masks.params import LiftParams
from abcgs.masks.spread import spread_labels, surface_features


def two_spheres(n: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two touching unit spheres of points (centres 2.05 apart on x): a pink one and a brown one. Returns the
    points ``(2n, 3)``, their colours and which sphere (0, 1) each belongs to."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(2 * n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    which = np.repeat([0, 1], n)
    pts = d + np.where(which[:, None] == 0, [-1.025, 0, 0], [1.025, 0, 0])
    cols = np.where(which[:, None] == 0, [0.9, 0.5, 0.7], [0.4, 0.25, 0.1])
    return pts, cols, which


def lifted_from_one_side(pts: np.ndarray, which: np.ndarray) -> LiftResult:
    """Only the Gaussians with z > 0.3 were seen (and decided) by the labelled view: sphere 0 → 1, sphere 1 → 2."""
    seen = torch.as_tensor(pts[:, 2] > 0.3)
    labels = torch.where(seen, torch.as_tensor(which + 1), torch.zeros(len(pts), dtype=torch.long))
    weights = torch.zeros(len(pts), 3)
    weights[seen, labels[seen]] = 1.0
    return LiftResult(labels, weights, seen.clone())


def test_the_far_side_of_each_object_takes_its_own_label() -> None:
    """The labelled view saw only the tops: spreading labels the bottoms, each by its own sphere, also where the
    spheres touch (there the colour keeps them apart)."""
    pts, cols, which = two_spheres()
    model = GaussianModel.from_points(pts, cols, init_opacity=0.5)
    lifted = lifted_from_one_side(pts, which)
    out, changed = propagate_unseen(model, lifted, LiftParams(propagate_along="surface", propagate_colour_weight=2.0))
    far = pts[:, 2] < -0.3
    assert changed == int((~lifted.decided).sum())
    assert (out.labels.numpy()[far] == which[far] + 1).mean() > 0.99
    touching = np.abs(pts[:, 0]) < 0.3
    assert (out.labels.numpy()[touching] == which[touching] + 1).all()
    assert out.decided.all()


def test_colour_keeps_a_label_on_its_surface_where_position_alone_crosses() -> None:
    """Seeds only on the far left of sphere 0 and the far right of sphere 1: by position alone the middle of sphere 0
    is as near to sphere 1's points as to its own; with colour it stays sphere 0's."""
    pts, cols, which = two_spheres(seed=1)
    seeds = torch.as_tensor(np.abs(pts[:, 0]) > 1.9)
    labels = torch.where(seeds, torch.as_tensor(which + 1), torch.zeros(len(pts), dtype=torch.long))
    with_colour, _ = spread_labels(surface_features(GaussianModel.from_points(pts, cols), 2.0), labels, seeds, ~seeds)
    right = (with_colour.numpy() == which + 1).mean()
    blind, _ = spread_labels(surface_features(GaussianModel.from_points(pts, cols), 0.0), labels, seeds, ~seeds)
    assert right > 0.99
    assert right > (blind.numpy() == which + 1).mean()


def test_an_undecided_gap_is_filled_from_its_labels_and_never_becomes_no_label() -> None:
    """Gaussians seen only in pixels the cut left undecided (no vote) are filled with the label round them; a
    decided 0 (the background brush) spreads as itself; Gaussians not in ``fill`` keep their label."""
    x = np.linspace(0.0, 3.0, 31)
    pts = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    labels = torch.zeros(31, dtype=torch.long)
    labels[:10] = 1  # 0.0 .. 0.9: label 1
    seeds = torch.zeros(31, dtype=torch.bool)
    seeds[:10] = True
    seeds[25:] = True  # 2.5 .. 3.0: decided "no label"
    fill = ~seeds
    fill[20] = False  # an undecided Gaussian outside the fill keeps its 0 and passes no label on
    feats = surface_features(GaussianModel.from_points(pts, np.full_like(pts, 0.5)), 1.0)
    out, rounds = spread_labels(feats, labels, seeds, fill, k=2)
    got = out.tolist()
    assert got[10:20] == [1] * 10  # the gap next to label 1 takes it
    assert got[20] == 0 and rounds >= 5
    assert got[21:25] == [0] * 4  # next to the background brush: "no label", from the brush
    no_seeds, rounds0 = spread_labels(feats, labels, torch.zeros(31, dtype=torch.bool), fill, k=2)
    assert no_seeds.tolist() == labels.tolist() and rounds0 == 0
