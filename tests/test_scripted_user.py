"""The scripted user of eval/bench/scripted_user.py: where its next stroke goes and how a step is scored (the miku
run itself needs ../shared/data and minutes; docs/MASKS.md has its record)."""

from __future__ import annotations

import numpy as np

from eval.bench.scripted_user import next_stroke, score


def test_the_next_stroke_is_a_dot_inside_the_largest_wrong_region_with_the_reference_label() -> None:
    truth = np.zeros((60, 80), np.int64)
    truth[:, :40], truth[:, 40:] = 1, 2
    pred = truth.copy()
    pred[10:20, 5:15] = 2  # a small wrong patch of label 1
    pred[20:50, 45:75] = 1  # a large wrong patch of label 2, centred at (x 60, y 35)
    s = next_stroke(pred, truth, radius=8.0)
    assert s is not None and s.label == 2
    x, y = s.points[0]
    assert abs(x - 60) <= 1 and abs(y - 35) <= 1
    assert 1.0 <= s.radius <= 8.0
    assert next_stroke(truth, truth, radius=8.0) is None
    thin = truth.copy()
    thin[:, 40] = 1  # a wrong region one pixel wide: the dot shrinks to stay inside
    assert next_stroke(thin, truth, radius=8.0).radius == 1.0


def test_a_step_scores_every_pair_and_the_unlabelled_share() -> None:
    truth = np.zeros((10, 10), np.int64)
    truth[:, :5], truth[:, 5:] = 1, 2
    pred = truth.copy()
    pred[:, 9] = 0  # unlabelled
    s = score({"a": pred, "b": truth}, {"a": truth, "b": truth}, 2)
    assert s["unlabelled"] == {"a": 0.1, "b": 0.0}
    assert s["iou"]["b"] == {"1": 1.0, "2": 1.0}
    assert np.isclose(s["iou"]["a"]["2"], 0.8) and s["worst_iou"] == s["iou"]["a"]["2"]
    assert np.isclose(s["mean_iou"], (1 + 0.8 + 1 + 1) / 4)
