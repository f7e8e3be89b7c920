"""The scripted user of eval/bench/scripted_user.py: where its next stroke goes and how a step is scored
(:func:`eval.labels.score_labels`, as a step records it; the miku run itself needs ../shared/data and minutes;
docs/MASKS.md has its record)."""

from __future__ import annotations

import numpy as np
import pytest

from abcgs.masks.strokes import rasterize_strokes
from eval.bench.marks import largest_wrong_region, line_inside, next_stroke
from eval.labels import score_labels


def test_the_next_stroke_is_a_dot_inside_the_largest_wrong_region_with_the_reference_label() -> None:
    truth = np.zeros((60, 80), np.int64)
    truth[:, :40], truth[:, 40:] = 1, 2
    pred = truth.copy()
    pred[10:20, 5:15] = 2  # a small wrong patch of label 1
    pred[20:50, 45:75] = 1  # a large wrong patch of label 2, centred at (x 60, y 35)
    k, region = largest_wrong_region(pred, truth)
    assert k == 2 and region.sum() == 30 * 30 and region[20:50, 45:75].all()
    s = next_stroke(pred, truth, radius=8.0)
    assert s is not None and s.label == 2
    x, y = s.points[0]
    assert abs(x - 60) <= 1 and abs(y - 35) <= 1
    assert 1.0 <= s.radius <= 8.0
    assert next_stroke(truth, truth, radius=8.0) is None
    thin = truth.copy()
    thin[:, 40] = 1  # a wrong region one pixel wide: the dot shrinks to stay inside
    assert next_stroke(thin, truth, radius=8.0).radius == 1.0


def test_a_scripted_stroke_crosses_the_wrong_region_along_its_long_axis_and_stays_inside() -> None:
    region = np.zeros((60, 120), bool)
    region[25:36, 10:110] = True  # a bar 100 px long, 11 px high, centred at (x 60, y 30)
    s = line_inside(3, region, radius=4.0, length=60.0)
    assert s.label == 3 and s.points.shape == (2, 2) and 1.0 <= s.radius <= 4.0
    (x0, y0), (x1, y1) = s.points
    assert abs(y0 - y1) < 1.0 and 59 <= abs(x1 - x0) <= 60  # horizontal, as long as allowed
    dot = next_stroke(np.where(region, 1, 3), np.where(region, 3, 0), radius=4.0).points[0]
    assert min(x0, x1) <= dot[0] <= max(x0, x1) and abs(dot[1] - y0) <= 1  # through the dot's pixel
    painted = rasterize_strokes([s], region.shape) >= 0
    assert painted.sum() > 200 and not (painted & ~region).any()  # the brush never leaves the region
    short = line_inside(3, region, radius=4.0, length=400.0)  # longer than the bar: stops at its ends
    painted = rasterize_strokes([short], region.shape) >= 0
    assert not (painted & ~region).any() and abs(short.points[1, 0] - short.points[0, 0]) >= 85
    tall = region.T.copy()  # the same bar upright: the stroke turns with it
    (x0, y0), (x1, y1) = line_inside(3, tall, radius=4.0, length=60.0).points
    assert abs(x0 - x1) < 1.0 and abs(y1 - y0) >= 50


def test_a_step_scores_every_pair_and_the_unlabelled_share() -> None:
    truth = np.zeros((10, 10), np.int64)
    truth[:, :5], truth[:, 5:] = 1, 2
    pred = truth.copy()
    pred[:, 9] = 0  # unlabelled
    s = score_labels({"a": pred, "b": truth}, {"a": truth, "b": truth}, 2).as_record()
    assert s["unlabelled"] == {"a": 0.1, "b": 0.0}
    assert s["iou"]["b"] == {"1": 1.0, "2": 1.0}
    assert np.isclose(s["iou"]["a"]["2"], 0.8) and s["worst_iou"] == s["iou"]["a"]["2"]
    assert np.isclose(s["mean_iou"], (1 + 0.8 + 1 + 1) / 4)


def test_the_regression_check_finds_the_worst_drop_of_the_mean_and_of_a_view() -> None:
    from eval.bench.scripted_user import regression, verdict

    def step(n, a, b):
        return {"strokes": n, "mean_iou": (a + b) / 2, "view_mean": {"a": a, "b": b},
                "iou": {"a": {"1": a}, "b": {"1": b}}, "unlabelled": {"a": 0.0, "b": 0.01}}

    steps = [step(15, 0.6, 0.6), step(16, 0.7, 0.55), step(17, 0.7, 0.62), step(18, 0.69, 0.59)]
    for k, st in enumerate(steps[1:]):
        st["delta"] = {"changed": {"undecided": 0, "stroke": 3, "lifted": k, "graph": 10 * k}}
    drops = regression(steps)
    assert drops["view"]["view"] == "b" and drops["view"]["strokes"] == 16
    assert drops["view"]["changed"]["graph"] == 0 and drops["mean"]["changed"]["graph"] == 20  # strokes 16 and 18
    assert abs(drops["view"]["drop"] - 0.05) < 1e-9
    assert abs(drops["mean"]["drop"] - 0.02) < 1e-9 and drops["mean"]["strokes"] == 18
    assert drops["view"]["fell"] == {"1": {"before": 0.6, "after": 0.55}}
    bound = {"per_view": {"a": {"1": 0.9}, "b": {"1": 0.9}}}
    assert regression(steps, bound)["view"]["fell"]["1"]["bound"] == 0.9
    v = verdict(steps, bound)
    assert not v["mean_drop"] and not v["view_drop"] and v["unlabelled"] and not v["mean_iou"]
    assert v["pairs_below"] == {"b/1": 0.59}  # below min(0.60, 0.9 - 0.05); a's 0.69 is not
    low_bound = {"per_view": {"a": {"1": 0.9}, "b": {"1": 0.62}}}
    assert verdict(steps, low_bound)["pairs"]  # against a bound of 0.62, 0.59 is within 0.05
    ok = verdict([step(15, 0.8, 0.8), step(16, 0.8, 0.795)], bound)
    assert ok["mean_drop"] and ok["view_drop"] and ok["mean_iou"] and ok["pairs"]


def test_the_attribution_finds_gaussians_the_references_disagree_on() -> None:
    """The test view's cut is its reference (ball and wall); the other views' references call the ball wall. The ball's
    Gaussians, decided by the cut, are then wrong in those views, carry the test view's reference label, and all
    references lifted together give that label to few of them; with references that agree, nothing is wrong."""
    from types import SimpleNamespace

    from abcgs.masks.field import LabelField
    from abcgs.masks.lifting import render_label_map
    from eval.bench.scripted_user import attribute
    from tests.test_content_masks import cameras, wall_and_ball

    model, truth = wall_and_ball(1)
    cams = cameras(3)
    maps = [render_label_map(model, truth, 2, c) for c in cams]
    field = LabelField(model, cams)
    field.set_view(0, maps[0])
    session = SimpleNamespace(field=field, result=field.solve())
    by_stem = {f"v{i}": i for i in range(3)}
    agree = attribute(SimpleNamespace(session=session, refs={f"v{i}": m for i, m in enumerate(maps)}, by_stem=by_stem),
                      2, "v0")
    wall = [np.where(m == 1, 2, m) for m in maps[1:]]
    disagree = attribute(SimpleNamespace(session=session, refs={"v0": maps[0], "v1": wall[0], "v2": wall[1]},
                                         by_stem=by_stem), 2, "v0")
    g = disagree["wrong_gaussians"]
    assert g["wrong"]["lifted"] > 20 and g["wrong"]["lifted"] > 5 * agree["wrong_gaussians"]["wrong"]["lifted"]
    assert g["wrong"]["test_ref"] > 0.9 and g["wrong"]["test_ref_is_all"] < 0.2
    assert g["right"]["test_ref_is_all"] > 0.9 and disagree["wrong_pixels"]["lifted"] > 0.5
    assert g["wrong"]["hidden_in_test_view"] < 0.1 and g["wrong"]["test_view_weight"] > 0  # measured 2.7 %


def test_several_fits_need_a_settings_file(tmp_path, capsys) -> None:
    """A record without ``--settings`` is one run: two ``--work`` folders are refused before any fit is read."""
    from eval.bench.scripted_user import main

    with pytest.raises(SystemExit) as err:
        main(["--work", str(tmp_path / "a"), str(tmp_path / "b")])
    assert err.value.code == 2 and "one --work without --settings" in capsys.readouterr().err


def test_the_pair_target_goes_to_the_pair_furthest_below_its_goal_and_the_view_target_to_the_worst_view() -> None:
    """View a is worst by its mean, but its face (label 2) is under a bound too low to ask anything of it; view b's
    label 2 spills over label 1 and is 0.1 under its goal. ``view`` marks a's largest wrong region; ``pair`` marks the
    spill on b with b's reference label there (1), and, once no pair is below its goal, falls back to ``view``."""
    from eval.bench.marks import next_region

    ref_a = np.zeros((40, 40), np.int64)
    ref_a[:, :20], ref_a[:, 20:] = 1, 2
    pred_a = np.ones_like(ref_a)  # a's label 2 missed: a wrong region of 800 px
    ref_b = ref_a.copy()
    pred_b = ref_b.copy()
    pred_b[10:20, 10:20] = 2  # b's label 2 spills over label 1: 100 px
    maps, refs = {"a": pred_a, "b": pred_b}, {"a": ref_a, "b": ref_b}
    iou = {"a": {"1": 0.5, "2": 0.0}, "b": {"1": 0.7, "2": 0.5}}
    bound = {"per_view": {"a": {"1": 0.6, "2": 0.03}, "b": {"1": 0.9, "2": 0.9}}}
    view, (label, region) = next_region(maps, refs, iou, "view")
    assert view == "a" and label == 2 and region.sum() == 800
    view, (label, region) = next_region(maps, refs, iou, "pair", bound)
    assert view == "b" and label == 1 and region.sum() == 100 and region[10:20, 10:20].all()
    met = {"a": {"1": 0.7, "2": 0.0}, "b": {"1": 0.7, "2": 0.7}}
    assert next_region(maps, refs, met, "pair", bound)[0] == "a"
    assert next_region(refs, refs, iou, "view") is None
    with pytest.raises(ValueError, match="bound"):
        next_region(maps, refs, iou, "pair")


def test_the_gain_target_goes_to_the_wrong_region_that_is_the_largest_share_of_its_pairs_union() -> None:
    """View a misses 200 px of a large label 1 (union 1200 px: a sixth); view b misses 60 px of a small label 2
    (union 100 px: three fifths). ``view`` goes to the worse view by its mean, a; ``gain`` to the smaller region
    that costs more IoU, on b; with nothing wrong, nowhere."""
    from eval.bench.marks import next_region

    ref_a = np.full((40, 40), 3, np.int64)
    ref_a[:30, :40] = 1  # label 1: 1200 px
    pred_a = ref_a.copy()
    pred_a[:5, :40] = 3  # 200 px of label 1 missed
    ref_b = np.full((40, 40), 3, np.int64)
    ref_b[:10, :10] = 2  # label 2: 100 px
    pred_b = ref_b.copy()
    pred_b[:6, :10] = 3  # 60 px of it missed
    maps, refs = {"a": pred_a, "b": pred_b}, {"a": ref_a, "b": ref_b}
    iou = {"a": {"1": 0.83, "3": 0.6}, "b": {"2": 0.4, "3": 0.98}}
    view, (label, region) = next_region(maps, refs, {"a": {"1": 0.1, "3": 0.1}, "b": iou["b"]}, "view")
    assert view == "a" and label == 1 and region.sum() == 200
    view, (label, region) = next_region(maps, refs, iou, "gain")
    assert view == "b" and label == 2 and region.sum() == 60 and region[:6, :10].all()
    assert next_region(refs, refs, iou, "gain") is None
