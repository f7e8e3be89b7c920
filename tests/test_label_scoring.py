"""The one label scoring of eval/ (:func:`eval.labels.score_labels`) gives, in each caller's convention, exactly what
the copies it replaced gave: ``eval.bench.strokes``'s case score and geometry bound, ``eval.bench.scripted_user``'s
step score, ``eval.bench.paint_iou``'s held-out score and ``eval.studies.mask_lifting``'s. The values below were
recorded from those copies on the example here (maps with undecided 255, references with ``NO_VOTE`` -1 and 0, a
label absent from one side, one absent from both, one that no view has, a reference that assigns nothing)."""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

from eval.labels import score_labels

NAN = float("nan")
RECORDED = {"strokes.score": {"per_view": {"a": {"iou": {"1": 0.24074074074074073,
                                                         "2": 0.0,
                                                         "3": 0.17142857142857143},
                                                 "unlabelled": 0.109375},
                                           "b": {"iou": {"1": 0.2247191011235955,
                                                         "2": 0.3090909090909091,
                                                         "3": 0.0},
                                                 "unlabelled": 0.07291666666666667},
                                           "c": {"iou": {}, "unlabelled": 0.3072916666666667}},
                              "worst_iou": {"1": 0.2247191011235955, "2": 0.0, "3": 0.0, "4": NAN},
                              "worst_unlabelled": 0.3072916666666667,
                              "goal_met": False},
            "strokes.geometry_bound": {"per_view": {"a": {"1": 0.24074074074074073,
                                                          "2": 0.0,
                                                          "3": 0.17142857142857143},
                                                    "b": {"1": 0.2247191011235955,
                                                          "2": 0.3090909090909091,
                                                          "3": 0.0},
                                                    "c": {}},
                                       "mean_iou": 0.1576632203973028,
                                       "worst_iou": {"1": 0.2247191011235955, "2": 0.0, "3": 0.0, "4": 1.0}},
            "scripted_user.score": {"iou": {"a": {"1": 0.24074074074074073, "2": 0.0, "3": 0.17142857142857143},
                                            "b": {"1": 0.2247191011235955, "2": 0.3090909090909091, "3": 0.0},
                                            "c": {}},
                                    "unlabelled": {"a": 0.109375,
                                                   "b": 0.07291666666666667,
                                                   "c": 0.3072916666666667},
                                    "view_mean": {"a": 0.13738977072310407, "b": 0.17793667007150152, "c": NAN},
                                    "worst_iou": 0.0,
                                    "mean_iou": 0.1576632203973028},
            "paint_iou._score": {"iou_per_label": {"1": {"mean": 0.24074074074074073,
                                                         "min": 0.24074074074074073,
                                                         "n_views": 1},
                                                   "2": {"mean": 0.0, "min": 0.0, "n_views": 1},
                                                   "3": {"mean": 0.17142857142857143,
                                                         "min": 0.17142857142857143,
                                                         "n_views": 1}},
                                 "pixel_agreement": NAN},
            "paint_iou._score_all": {"iou_per_label": {"1": {"mean": 0.2327299209321681,
                                                             "min": 0.2247191011235955,
                                                             "n_views": 2},
                                                       "2": {"mean": 0.15454545454545454, "min": 0.0, "n_views": 2},
                                                       "3": {"mean": 0.08571428571428572,
                                                             "min": 0.0,
                                                             "n_views": 2}},
                                     "pixel_agreement": 0.290064485311679},
            "mask_lifting": {"iou_per_label": {"1": {"mean": 0.24074074074074073,
                                                     "min": 0.24074074074074073,
                                                     "n_views": 1},
                                               "2": {"mean": 0.0, "min": 0.0, "n_views": 1},
                                               "3": {"mean": 0.17142857142857143,
                                                     "min": 0.17142857142857143,
                                                     "n_views": 1}},
                             "pixel_agreement": 0.24050632911392406}}
"""What each copy gave on :func:`example`, by the copy it was: ``paint_iou._score`` with view 1 (b) as the stroked
one, ``paint_iou._score_all`` with the truths of views 0 and 1 and view 2 skipped; ``mask_lifting`` with a and c held
out."""


def _pick(values, probs, shape, seed):
    """Pseudo-random picks from ``values`` with ``probs``: a fixed integer hash of each pixel's index (splitmix64),
    the same on every numpy."""
    x = np.arange(np.prod(shape), dtype=np.uint64) + np.uint64(seed * 0x9E3779B97F4A7C15 % 2**64)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    x = x ^ (x >> np.uint64(31))
    u = (x >> np.uint64(11)).astype(np.float64) / 2.0 ** 53
    pick = np.minimum(np.searchsorted(np.cumsum(probs), u, side="right"), len(values) - 1)
    return np.asarray(values, np.int64)[pick].reshape(shape)


def example() -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], int]:
    """Maps and references of views a, b, c (12x16), and n_labels 4: label 4 is in none of them."""
    shape = (12, 16)
    maps, refs = {}, {}
    for j, v in enumerate(("a", "b", "c")):
        refs[v] = _pick([-1, 0, 1, 2, 3], [0.1, 0.1, 0.3, 0.3, 0.2], shape, 2 * j + 1)
        maps[v] = _pick([0, 1, 2, 3, 255], [0.1, 0.3, 0.3, 0.2, 0.1], shape, 2 * j + 2)
    refs["b"][refs["b"] == 3] = 2  # label 3 absent from b's reference, present in b's map
    maps["a"][maps["a"] == 2] = 1  # label 2 absent from a's map, present in a's reference
    refs["c"][:] = np.where(refs["c"] > 0, 0, refs["c"])  # c's reference assigns nothing
    maps["c"][maps["c"] == 3] = 0  # ... and label 3 is absent from both sides in c
    return maps, refs, 4


def _same(got, want) -> bool:
    """Equal, float for float (nan equals nan), with dicts' keys in the same order."""
    if isinstance(want, dict):
        return isinstance(got, dict) and list(got) == list(want) and all(_same(got[k], want[k]) for k in want)
    if isinstance(want, float):
        return isinstance(got, float) and (got == want or (math.isnan(got) and math.isnan(want)))
    return type(got) is type(want) and got == want


def test_a_strokes_case_scores_as_before():
    from eval.bench.strokes import case_record

    maps, refs, n = example()
    got = case_record(score_labels(maps, refs, n), goal_iou=0.5)
    assert _same(got, RECORDED["strokes.score"])  # a label no view scores: nan


def test_the_geometry_bound_scores_as_before(monkeypatch):
    import eval.bench.strokes as strokes

    maps, refs, n = example()
    order = list(maps)
    monkeypatch.setattr(strokes, "lift_labels", lambda *a, **k: types.SimpleNamespace(labels=None))
    monkeypatch.setattr(strokes, "render_label_map", lambda model, labels, n_labels, cam: maps[order[cam]])
    got = strokes.geometry_bound(None, [0, 1, 2], {s: i for i, s in enumerate(order)}, refs, order, n)
    assert _same(got, RECORDED["strokes.geometry_bound"])  # a label no view scores: 1.0


@pytest.mark.filterwarnings("ignore:Mean of empty slice", "ignore:invalid value encountered")
def test_a_scripted_user_step_scores_as_before():
    maps, refs, n = example()
    got = score_labels(maps, refs, n).as_record()
    assert _same(got, RECORDED["scripted_user.score"])


def _heldout(s) -> dict:
    return {"iou_per_label": s.per_label_summary(), "pixel_agreement": s.mean_agreement(empty_views="count")}


def test_paint_iou_scores_as_before():
    """Every view but the stroked one (b), by index; a view whose truth assigns nothing (c) makes the agreement nan."""
    maps, refs, n = example()
    views, truth = list(maps.values()), dict(enumerate(refs.values()))
    got = _heldout(score_labels(views, {i: t for i, t in truth.items() if i != 1}, n))
    assert _same(got, RECORDED["paint_iou._score"])
    got = _heldout(score_labels(views, {0: truth[0], 1: truth[1]}, n))
    assert _same(got, RECORDED["paint_iou._score_all"])


def test_mask_lifting_scores_as_before():
    """The held-out views a and c; c, whose mask assigns nothing, is left out of the agreement (as the stage's
    held-out score leaves it out)."""
    maps, refs, n = example()
    views, truth = dict(enumerate(maps.values())), dict(enumerate(refs.values()))
    s = score_labels(views, {0: truth[0], 2: truth[2]}, n)
    got = {"iou_per_label": s.per_label_summary(), "pixel_agreement": s.mean_agreement(empty_views="skip")}
    assert _same(got, RECORDED["mask_lifting"])


def test_a_view_no_label_of_which_is_scored_and_no_assigned_reference():
    maps, refs, n = example()
    s = score_labels(maps, {"c": refs["c"]}, n)
    assert s.iou == {"c": {}} and math.isnan(s.agreement["c"]) and s.mean_agreement(empty_views="skip") is None
    assert s.worst_per_label(absent=1.0) == {"1": 1.0, "2": 1.0, "3": 1.0, "4": 1.0}
