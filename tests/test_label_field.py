"""The labels of the masks page and stage (abcgs/masks/field.py), the strip of every view (abcgs/masks/page/strip.py) and
the strokes' file, on the wall-and-ball scene of tests/test_content_masks.py."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.io.images import load_stroke_map, save_labels, save_stroke_map, stroke_map_path
from abcgs.masks.content import label_iou, label_paths_in, make_content_masks
from abcgs.masks.field import LabelField, correction_seeds, render_field
from abcgs.masks.lifting import NO_VOTE, render_label_map
from abcgs.masks.page.strip import Strip
from abcgs.masks.params import UNDECIDED, MaskParams
from abcgs.masks.strokes import Stroke, rasterize_strokes
from tests.test_content_masks import cameras, wall_and_ball


def _truth_maps(model, truth, cams):
    return [render_label_map(model, truth, 2, c) for c in cams]


def test_one_painted_view_labels_every_view_and_keeps_its_own_cut() -> None:
    model, truth = wall_and_ball(1)
    cams = cameras(5)
    maps = _truth_maps(model, truth, cams)
    cut = maps[0].copy()
    cut[:, :10] = NO_VOTE  # a strip the cut left undecided votes for nothing
    field = LabelField(model, cams)
    field.set_view(0, cut)
    result = field.solve()
    assert result.counts()["lifted"] > 0 and result.counts()["graph"] > 0
    assert (result.labels[truth.numpy() == 1] == 1).mean() > 0.95
    ious = [label_iou(render_field(field, result, i, threshold=0.5), maps[i], 2)[1] for i in range(1, len(cams))]
    # measured 0.92 / 0.83 / 0.79 / 0.72, falling with the angle to view 0: the wall that the ball hides from view 0
    # touches the ball's far side and is split between the two labels
    assert min(ious) > 0.7 and ious[0] > 0.9
    own = render_field(field, result, 0)
    np.testing.assert_array_equal(own[:, 10:], cut[:, 10:])  # the painted view keeps its cut where it decided


def test_a_stroke_binds_the_gaussians_under_it_against_the_cuts() -> None:
    model, truth = wall_and_ball(2)
    cams = cameras(3)
    wrong = np.full((cams[0].height, cams[0].width), 2)  # a cut that calls everything wall
    field = LabelField(model, cams)
    field.set_view(0, wrong)
    before = field.solve()
    assert (before.labels[truth.numpy() == 1] == 1).mean() < 0.05
    ball_px = np.argwhere(_truth_maps(model, truth, cams[:1])[0] == 1).mean(0)
    strokes = rasterize_strokes([Stroke(1, np.array([ball_px[::-1] + 0.5]), 4.0)], (cams[0].height, cams[0].width))
    field.set_view(0, wrong, strokes)
    after = field.solve()
    stroked = after.source == 1
    assert stroked.sum() > 5 and (after.labels[stroked] == 1).all()
    assert (after.labels[truth.numpy() == 1] == 1).mean() > (before.labels[truth.numpy() == 1] == 1).mean()
    changed = after.changes_from(before)  # the stroke's Gaussians turned from wall to ball, and what followed them
    assert changed["stroke"] == int((stroked & (before.labels != 1)).sum()) > 5
    assert sum(changed.values()) == int((after.labels != before.labels).sum())
    assert sum(before.changes_from(before).values()) == 0


def test_changes_from_counts_what_a_segment_changed_by_the_step_that_decided_it() -> None:
    from abcgs.masks.field import FieldResult

    def result(labels, decided, source):
        labels = np.array(labels)
        return FieldResult(labels, np.array(decided, bool), np.zeros((labels.size, 3)), np.array(source, np.uint8),
                           2, 0.0)

    before = result([1, 1, 2, 2, 0, 2], [1, 1, 1, 1, 0, 1], [2, 3, 3, 2, 0, 3])
    after = result([1, 2, 2, 1, 2, 0], [1, 1, 1, 1, 1, 0], [1, 3, 3, 1, 2, 0])
    # kept; graph 1 -> 2; kept; 2 -> 1 by a stroke; undecided -> 2 by the cuts; 2 -> undecided
    assert after.changes_from(before) == {"undecided": 1, "stroke": 1, "lifted": 1, "graph": 1}
    relabelled = result([1, 1, 2, 2, 0, 2], [1, 1, 1, 1, 0, 1], [1, 1, 1, 1, 0, 1])
    assert sum(relabelled.changes_from(before).values()) == 0  # another step, the same labels: nothing changed
    with pytest.raises(ValueError, match="5 Gaussians now, 6 before"):
        result([1] * 5, [1] * 5, [1] * 5).changes_from(before)


def test_correction_seeds_free_the_touched_region_near_the_stroke_only() -> None:
    rendered = np.zeros((40, 60), np.int64)
    rendered[:, 30:] = 1
    strokes = np.full_like(rendered, -1)
    strokes[20, 35] = 0  # a stroke of 0 inside the region rendered as 1
    seeds = correction_seeds(rendered, strokes, erode_px=0, reach_px=5)
    assert seeds[20, 35] == 0
    assert (seeds[20, 31:41] != 1).all()  # within reach: left to the cut
    assert (seeds[:, 45:] == 1).all() and (seeds[:, :30] == 0).all()  # beyond reach and the other label: kept


def test_the_strip_shows_every_view_and_ranks_undecided_views_first() -> None:
    model, truth = wall_and_ball(3)
    cams = cameras(4)
    strip = Strip.record(model, cams, side=48)
    labels = truth.numpy()
    decided = np.ones_like(labels, dtype=bool)
    maps = strip.labels(labels, decided, 2)
    assert [m.shape for m in maps] == [(36, 48)] * 4
    small = render_label_map(model, truth, 2, cams[1].scaled(48 / 96))
    assert (maps[1] == small).mean() > 0.97  # the frozen map renders what the rasterizer does
    undecided = decided & ~((labels == 1) & (model.means[:, 0].numpy() > 0))  # half the ball undecided
    doubt = strip.doubt(strip.labels(labels, undecided, 2))
    assert all(d > 0 for d in doubt)
    assert (strip.labels(labels, undecided, 2)[0] == UNDECIDED).any()


def test_the_stage_reads_the_saved_strokes(tmp_path) -> None:
    model, truth = wall_and_ball(4)
    cams = cameras(3)
    wrong = np.full((cams[0].height, cams[0].width), 2)
    save_labels(tmp_path / "000.png", wrong)
    plain = make_content_masks(model, cams, label_paths_in(tmp_path, cams),
                               MaskParams(source="given"), show_progress=False)
    ball_px = np.argwhere(_truth_maps(model, truth, cams[:1])[0] == 1).mean(0)
    seeds = rasterize_strokes([Stroke(1, np.array([ball_px[::-1] + 0.5]), 4.0)], (cams[0].height, cams[0].width))
    save_stroke_map(stroke_map_path(tmp_path, "000"), seeds)
    np.testing.assert_array_equal(load_stroke_map(stroke_map_path(tmp_path, "000"), seeds.shape), seeds)
    stroked = make_content_masks(model, cams, label_paths_in(tmp_path, cams),
                                 MaskParams(source="given"), show_progress=False)
    ball = truth == 1
    assert (stroked.gaussian_labels[ball] == 1).float().mean() > (plain.gaussian_labels[ball] == 1).float().mean()
    save_stroke_map(stroke_map_path(tmp_path, "000"), np.full((5, 5), -1))
    with pytest.raises(InputError, match="5x5"):
        make_content_masks(model, cams, label_paths_in(tmp_path, cams), MaskParams(source="given"), show_progress=False)


def test_set_view_refuses_a_map_of_another_size() -> None:
    model, _ = wall_and_ball(5)
    cams = cameras(2)
    field = LabelField(model, cams)
    with pytest.raises(ValueError, match="is 5x4, the view 96x72"):
        field.set_view(1, np.zeros((4, 5), np.int64))


def test_reconstruct_carries_the_strokes_beside_the_cuts(tiny_scene, tmp_path) -> None:
    """The page's strokes of a view reach the layout the masks stage reads, undistorted like its cut."""
    import shutil

    from abcgs.io.images import load_labels
    from abcgs.sfm.params import ReconstructParams
    from abcgs.sources.photos import reconstruct_photos

    scene = tmp_path / "scene"
    shutil.copytree(tiny_scene / "images", scene / "images")
    (scene / "masks").mkdir()
    shutil.copy(tiny_scene / "masks" / "000.png", scene / "masks" / "000.png")
    h, w = load_labels(scene / "masks" / "000.png").shape
    seeds = rasterize_strokes([Stroke(2, np.array([[w / 2, h / 2]]), 6.0), Stroke(0, np.array([[10.0, 10.0]]), 3.0)],
                              (h, w))
    save_stroke_map(stroke_map_path(scene / "masks", "000"), seeds)
    reconstruct_photos(scene, tmp_path / "colmap", ReconstructParams())
    carried = load_stroke_map(stroke_map_path(tmp_path / "colmap" / "masks", "000"),
                              load_labels(tmp_path / "colmap" / "masks" / "000.png").shape)
    assert set(np.unique(carried)) == {-1, 0, 2}
    assert abs(int((carried == 2).sum()) - int((seeds == 2).sum())) < 0.3 * (seeds == 2).sum()


def test_the_colour_doubt_counts_pixels_nearer_another_labels_mean_colour() -> None:
    rng = np.random.default_rng(7)
    cie = rng.uniform(0, 100, (30 * 40, 3)).astype(np.float32)
    lab = rng.integers(0, 5, (30, 40))
    lab[:3] = UNDECIDED
    flat = lab.ravel()
    ids = [k for k in range(1, 5)]
    means = np.stack([cie[flat == k].astype(np.float64).mean(0) for k in ids])
    shown = (flat > 0) & (flat < UNDECIDED)
    nearest = np.array(ids)[np.linalg.norm(cie[shown, None, :] - means[None], axis=-1).argmin(1)]
    expected = float((nearest != flat[shown]).mean())
    assert 0.5 < expected < 0.9  # random colours: most pixels are nearer another label's mean
    assert np.isclose(Strip._colour_disagreement(cie, lab), expected, atol=1.0 / shown.sum())
    assert Strip._colour_disagreement(cie, np.full_like(lab, 3)) == 0.0  # one label: nothing to disagree with


def test_pick_labels_maps_the_undecided_channel_and_the_weak_pixels() -> None:
    """The last channel of :func:`label_colours` is the undecided Gaussians': its pixels take ``undecided``; a pixel
    whose best label holds under ``threshold`` of its alpha, or with no alpha, takes ``none``."""
    import torch

    from abcgs.masks.lifting import label_colours, pick_labels

    assert label_colours(torch.tensor([0, 2, 1]), 2, torch.tensor([True, True, False])).argmax(-1).tolist() == [0, 2, 3]
    # pixels: label 1 strong, undecided strong, label 2 weak (0.3 of alpha 0.9), empty
    img = torch.tensor([[[0.0, 0.8, 0.1, 0.0], [0.0, 0.1, 0.0, 0.7], [0.3, 0.3, 0.3, 0.0], [0.0, 0.0, 0.0, 0.0]]])
    alpha = torch.tensor([[[0.9], [0.8], [0.9], [0.0]]])
    assert pick_labels(img, alpha, 0.5).tolist() == [[1, UNDECIDED, 0, 0]]
    assert pick_labels(img, alpha, 0.5, none=-1, undecided=-2).tolist() == [[1, -2, -1, -1]]
    assert pick_labels(img, alpha, 0.0, none=-1, undecided=0).tolist() == [[1, 0, 0, -1]]


def _ball_stroke(model, truth, cam, label: int = 1, radius: float = 4.0) -> np.ndarray:
    ball_px = np.argwhere(render_label_map(model, truth, 2, cam) == 1).mean(0)
    return rasterize_strokes([Stroke(label, np.array([ball_px[::-1] + 0.5]), radius)], (cam.height, cam.width))


@pytest.mark.parametrize("evidence", ["soft", "hard"])
def test_no_cut_flips_a_gaussian_that_a_stroke_on_another_view_bound(evidence: str) -> None:
    model, truth = wall_and_ball(6)
    cams = cameras(5)
    maps = _truth_maps(model, truth, cams)
    field = LabelField(model, cams, MaskParams().field.model_copy(update={"cut_evidence": evidence}))
    field.set_view(0, maps[0], _ball_stroke(model, truth, cams[0]))
    bound = field.solve().source == 1
    assert bound.sum() > 5
    wrong = np.full((cams[4].height, cams[4].width), 2)  # a far view's cut that calls the ball wall, with a stroke
    strokes = np.full(wrong.shape, -1)
    strokes[5:10, 5:10] = 2
    field.set_view(4, wrong, strokes)
    after = field.solve()
    assert (after.labels[bound] == 1).all() and (after.source[bound] == 1).all()


def test_a_cut_far_from_its_strokes_weighs_less_than_one_near_them() -> None:
    """View 0's cut is right and painted all over; view 4's cut calls the ball wall, its one stroke in a corner of the
    wall. As soft evidence, view 4's cut where it has no stroke near counts for little and the ball stays a ball;
    as a hard vote (the earlier rule) it outvotes view 0 on the Gaussians both see. Occlusion is off: the back of the
    ball, hidden from view 0, would otherwise hear view 4 alone."""
    model, truth = wall_and_ball(7)
    cams = cameras(5)
    maps = _truth_maps(model, truth, cams)
    h, w = maps[0].shape
    everywhere = np.full((h, w), -1)
    everywhere[::6, ::6] = maps[0][::6, ::6]  # dots all over view 0: its cut is sure everywhere
    wrong = np.full((h, w), 2)
    corner = np.full((h, w), -1)
    corner[2:5, 2:5] = 2
    ball = truth.numpy() == 1
    kept = {}
    for evidence in ("soft", "hard"):
        field = LabelField(model, cams, MaskParams().field.model_copy(update={"cut_evidence": evidence,
                                                                                 "stroke_weight": 1e9, "occlusion": 0.0}))
        field.set_view(0, maps[0], everywhere)
        field.set_view(4, wrong, corner)
        kept[evidence] = float((field.solve().labels[ball] == 1).mean())
    assert kept["soft"] > 0.9 and kept["hard"] < kept["soft"] - 0.2, kept


def test_cut_confidence_falls_with_the_distance_to_the_views_strokes() -> None:
    from abcgs.masks.field import cut_confidence

    strokes = np.full((50, 100), -1)
    strokes[25, 10] = 1
    conf = cut_confidence(strokes.shape, strokes, reach=0.2)  # r = 10 px
    assert conf[25, 10] == 1.0 and conf[25, 20] == pytest.approx(np.exp(-1.0), abs=0.02)
    assert conf[25, 90] < 1e-6 and np.all(np.diff(conf[25, 10:]) <= 0)
    np.testing.assert_array_equal(cut_confidence(strokes.shape, None, reach=0.2), 1.0)  # a map given as it is


def test_the_strip_blends_again_only_the_views_a_change_reaches() -> None:
    model, truth = wall_and_ball(8)
    cams = cameras(4)
    strip = Strip.record(model, cams, side=48)
    labels = truth.numpy().copy()
    decided = np.ones_like(labels, dtype=bool)
    before = strip.labels(labels, decided, 2)
    changed = np.zeros_like(decided)
    seen_by_0 = np.zeros_like(decided)
    seen_by_0[strip.views[0].ids.numpy()] = True
    unseen = set(strip.views[3].ids.numpy().tolist()) - set(strip.views[0].ids.numpy().tolist())
    flip = np.array(sorted(unseen)[:50])  # Gaussians view 3 sees and view 0 does not
    labels[flip], changed[flip] = 1, True
    after = strip.labels(labels, decided, 2, previous=before, changed=changed)
    full = strip.labels(labels, decided, 2)
    for a, f in zip(after, full):
        np.testing.assert_array_equal(a, f)
    assert after[0] is before[0] and after[3] is not before[3]


def test_a_dot_binds_the_gaussians_it_lies_on_not_a_large_splat_across_it() -> None:
    """A faint splat as large as the view lies over the ball; a dot on the ball blends into it too (more than
    stroke_weight), but holds a few thousandths of its weight in the view: with stroke_share it is not bound, without
    it takes the dot's label."""
    model, truth = wall_and_ball(9)
    big = GaussianModel(means=torch.tensor([[0.0, 0.0, 2.0]]), quats=torch.tensor([[1.0, 0, 0, 0]]),
                        log_scales=torch.full((1, 3), 2.0).log(), opacity_logits=torch.tensor([-1.5]),
                        sh0=model.sh0[:1].detach().clone(), shN=torch.zeros(1, 0, 3))
    both = GaussianModel(**{k: torch.cat([getattr(model, k).detach(), getattr(big, k).detach()])
                            for k in ("means", "quats", "log_scales", "opacity_logits", "sh0", "shN")})
    n = model.num_gaussians
    cams = cameras(3)
    dot = _ball_stroke(model, truth, cams[0])
    bound = {}
    default = MaskParams().field.stroke_share
    for share in (0.0, 0.03, default):
        field = LabelField(both, cams, MaskParams().field.model_copy(update={"stroke_share": share}))
        field.set_view(0, None, dot)
        result = field.solve()
        bound[share] = result.source == 1
        assert bound[share][:n][truth.numpy() == 1].sum() > 5  # the ball under the dot is bound either way
    assert bound[0.0][n] and not bound[0.03][n] and not bound[default][n]
    assert bound[default].sum() < bound[0.03].sum()  # the default binds only the splats mostly under the dot


def test_what_a_painted_view_hides_casts_no_vote_with_occlusion() -> None:
    """The ball hides part of the wall from view 0: those wall Gaussians blend a little into the ball's pixels of a
    right cut. With ``occlusion`` they take no evidence from it; without, some are lifted as ball."""
    from abcgs.masks.lifting import occluded_gaussians

    model, truth = wall_and_ball(10)
    cams = cameras(3)
    hidden = occluded_gaussians(model, cams[0], 0.1).numpy()
    wall, ball = truth.numpy() == 2, truth.numpy() == 1
    z = model.means.detach().numpy()[:, 2]
    assert hidden[wall].sum() > 50 and not hidden[ball & (z < 3.0)].any()  # the ball's front is what view 0 sees
    assert not hidden[wall & (np.abs(model.means.detach().numpy()[:, 0]) > 2.0)].any()  # wall beside the ball
    assert (z[hidden & wall] > 4.9).all()
    maps = _truth_maps(model, truth, cams)
    lifted_as_ball = {}
    for occlusion in (0.0, 0.1):
        field = LabelField(model, cams, MaskParams().field.model_copy(update={"occlusion": occlusion}))
        field.set_view(0, maps[0])
        result = field.solve()
        lifted_as_ball[occlusion] = int(((result.source == 2) & (result.labels == 1) & wall & hidden).sum())
    assert lifted_as_ball[0.0] > 0 and lifted_as_ball[0.1] == 0, lifted_as_ball


def test_specks_take_the_label_around_them_and_large_regions_stay() -> None:
    from abcgs.masks.edges import drop_specks

    labels = np.ones((40, 60), np.int64)
    labels[:, 30:] = 2
    labels[5:8, 5:8] = 3  # a 9-pixel speck of label 3 inside label 1
    labels[20:22, 40:42] = 0  # a 4-pixel hole in label 2
    labels[30:40, 0:10] = 4  # a 100-pixel region: kept
    out = drop_specks(labels, 50)
    assert (out[5:8, 5:8] == 1).all() and (out[20:22, 40:42] == 2).all() and (out[30:40, 0:10] == 4).all()
    assert set(np.unique(out)) == {1, 2, 4} and (out[labels != out] != 3).all()
    np.testing.assert_array_equal(drop_specks(labels, 1), labels)
    np.testing.assert_array_equal(drop_specks(np.full((5, 5), 7), 100), np.full((5, 5), 7))  # all small: kept


def test_a_view_larger_than_the_lift_size_is_lifted_and_rendered_at_it(monkeypatch) -> None:
    """A view of more than LIFT_PIXELS pixels (a phone photo) is lifted from and rendered into the same view scaled
    to that many: its votes keep their units (photo pixels), its labels their size, and both agree with the view's
    own size."""
    import abcgs.masks.lifting as lifting

    model, truth = wall_and_ball(1)
    cams = [c.scaled(3.0) for c in cameras(3)]
    maps = _truth_maps(model, truth, cams)
    photo = (np.stack([maps[1] == 1, maps[1] == 2, maps[1] == 0], -1) * 200 + 30).astype(np.uint8)
    dots = rasterize_strokes([Stroke(1, np.argwhere(maps[0] == 1).mean(0)[None, ::-1] + 0.5, 3.0)], maps[0].shape)
    runs = {}
    for name, pixels in (("own size", lifting.LIFT_PIXELS), ("lifted", cams[0].width * cams[0].height // 9)):
        monkeypatch.setattr(lifting, "LIFT_PIXELS", pixels)
        # every Gaussian's stroke weight kept (stroke_share 0): the units are compared, not which splats bind
        field = LabelField(model, cams, MaskParams().field.model_copy(update={"stroke_share": 0.0}))
        field.set_view(0, maps[0], dots)
        result = field.solve()
        runs[name] = (field._views[0], result, render_field(field, result, 1, threshold=0.5),
                      render_field(field, result, 1, photo=photo))
    small = lifting.lift_camera(cams[0], cams[0].width * cams[0].height // 9)
    assert small.width * small.height <= cams[0].width * cams[0].height // 9
    (own, r_own, map_own, ref_own), (lifted, r_lifted, map_lifted, ref_lifted) = runs["own size"], runs["lifted"]
    # the summed weight of the view is the same in photo pixels at either size (measured 0.6 % apart)
    assert abs(float(lifted.seen.sum()) / float(own.seen.sum()) - 1) < 0.02
    assert abs(float(lifted.stroke_votes.sum()) / float(own.stroke_votes.sum()) - 1) < 0.1  # measured 2.4 %
    both = r_own.decided & r_lifted.decided
    assert (r_own.labels[both] == r_lifted.labels[both]).mean() > 0.98  # measured 0.995
    # the labels rendered, and refined against the photo, at the view's size (measured 0.993 and 1.0)
    assert map_lifted.shape == ref_lifted.shape == maps[1].shape
    assert (map_lifted == map_own).mean() > 0.97 and (ref_lifted == ref_own).mean() > 0.97


def test_a_region_that_covers_a_splat_in_part_leaves_it_to_the_other_views() -> None:
    """View 0's cut is right. A correction on view 4 claims the wall in a disc that also covers the ball's rim (a
    region that bled across the border). With ``cut_share`` 0.5, a ball Gaussian with under half of its blending
    weight in view 4 on the disc takes no vote from it and keeps the label view 0's cut gave it; without, the disc
    turns some of them into wall. Occlusion is off: it holds some of those rim Gaussians too."""
    from abcgs.masks.lifting import blend_votes

    model, truth = wall_and_ball(8)
    cams = cameras(5)
    maps = _truth_maps(model, truth, cams)
    ball_px = np.argwhere(maps[4] == 1)
    cy, cx = ball_px[:, 0].mean(), ball_px[:, 1].min()  # the ball's left rim in view 4
    yy, xx = np.mgrid[: maps[4].shape[0], : maps[4].shape[1]]
    disc = (yy - cy) ** 2 + (xx - cx) ** 2 <= 12.0**2
    region = np.where(disc, 2, NO_VOTE)
    strokes = np.where((yy - cy) ** 2 + (xx - (cx - 8)) ** 2 <= 2.0**2, 2, -1)
    w = blend_votes(model, cams[4], torch.from_numpy(np.stack([disc, np.ones_like(disc)], -1).astype(np.float32)))
    front = LabelField(model, cams, MaskParams().field.model_copy(update={"occlusion": 0.0}))
    front.set_view(0, maps[0])
    lifted = front.solve().source == 2  # decided by view 0's cut
    partly = ((w[:, 0] > 0) & (w[:, 0] < 0.5 * w[:, 1])).numpy() & (truth.numpy() == 1) & lifted
    assert partly.sum() > 10
    wall_balls = {}
    for share in (0.0, 0.5):
        field = LabelField(model, cams, MaskParams().field.model_copy(update={"cut_share": share, "occlusion": 0.0}))
        field.set_view(0, maps[0])
        alone = field.solve().labels.copy()
        field.set_view(4, region, strokes)
        after = field.solve()
        assert (alone[partly] == 1).mean() > 0.9
        wall_balls[share] = int((after.labels[partly] == 2).sum())
        if share > 0:
            np.testing.assert_array_equal(after.labels[partly], alone[partly])
    assert wall_balls[0.0] > 0 and wall_balls[0.5] == 0, wall_balls


def test_a_label_map_from_elsewhere_is_a_views_evidence_and_the_strip_follows() -> None:
    """``FieldSession.set_evidence``: a view's evidence given as a label map (a benchmark's ideal part mask) is lifted
    as a cut is, and the labels and the strip are solved again; a wrong map moves the ball the other way."""
    from abcgs.masks.page.field_session import FieldSession

    model, truth = wall_and_ball(9)
    cams = cameras(4)
    maps = _truth_maps(model, truth, cams)
    session = FieldSession(LabelField(model, cams), Strip.record(model, cams, side=48), {i: i for i in range(4)})
    ball = truth.numpy() == 1
    session.set_evidence(0, maps[0], None)
    assert (session.result.labels[ball] == 1).mean() > 0.9 and session.state is not None
    right = session.state.maps[2].copy()
    session.set_evidence(0, np.full_like(maps[0], 2), None)  # everything wall
    assert (session.result.labels[ball] == 1).mean() < 0.1
    assert (session.state.maps[2] != right).any()


def test_a_painted_views_cut_spreads_over_the_part_of_the_photo_it_lies_in() -> None:
    """A painted view's cut decides a patch of label 1 inside a square of the photo of its own colour, which the wall
    (label 2) renders into. Refined with the cut put in (:func:`~abcgs.masks.field.with_cut`), the rest of the square
    takes the cut's label along the photo; refined from the Gaussians alone it stays wall, and so does the wall round
    the square, beyond its edges."""
    import cv2

    model, truth = wall_and_ball(10)
    cam = cameras(3)[0]
    truth_map = _truth_maps(model, truth, [cam])[0]
    field = LabelField(model, [cam])
    field.set_view(0, truth_map)
    result = field.solve()  # the labels in 3-D: the wall is wall
    h, w = truth_map.shape
    ys, xs = np.nonzero(truth_map == 2)
    y0, x0 = int(ys.min()) + 2, int(xs.min()) + 2  # a square in the wall's top-left corner
    square = np.zeros((h, w), bool)
    square[y0 : y0 + 16, x0 : x0 + 16] = True
    assert (truth_map[square] == 2).all()
    photo = np.full((h, w, 3), (60, 160, 80), np.uint8)
    photo[square] = (200, 40, 40)
    cut = np.full((h, w), NO_VOTE, np.int64)
    cut[y0 + 2 : y0 + 14, x0 + 2 : x0 + 14] = 1  # 144 of the square's 256 pixels
    field.set_view(0, cut)  # what the user painted there; the labels in 3-D stay the ones solved above
    shown = render_field(field, result, 0, photo=photo)
    alone = render_field(field, result, 0, photo=photo, cut_where_painted=False)
    ring = square & (cut < 0)
    assert (shown[ring] == 1).mean() > 0.9 and (alone[ring] == 2).mean() > 0.9
    around = cv2.dilate(square.astype(np.uint8), np.ones((13, 13), np.uint8)).astype(bool) & ~square & (truth_map == 2)
    assert around.sum() > 100 and (shown[around] == 2).mean() > 0.95


def test_a_corrections_region_weighs_less_than_the_cut_it_disagrees_with() -> None:
    """View 0's cut is right. A correction on view 4 is a wall stroke beside the ball whose colour region bled over
    the ball's left half. Marked as its strokes' regions, the region beyond the stroke weighs ``region_weight`` of a
    cut's evidence: at 0.2 fewer of the ball's Gaussians that view 0's cut decided turn into wall than at 1, where
    the region weighs as a cut does (the same as the map given as view 4's cut)."""
    model, truth = wall_and_ball(8)
    cams = cameras(5)
    maps = _truth_maps(model, truth, cams)
    ball_px = np.argwhere(maps[4] == 1)
    cy, cx = ball_px[:, 0].mean(), ball_px[:, 1].min()
    yy, xx = np.mgrid[: maps[4].shape[0], : maps[4].shape[1]]
    region = np.where((yy - cy) ** 2 + (xx - cx) ** 2 <= 16.0**2, 2, NO_VOTE)
    strokes = np.where((yy - cy) ** 2 + (xx - (cx - 10)) ** 2 <= 2.0**2, 2, -1)
    ball = truth.numpy() == 1
    turned = {}
    for weight, regions in ((1.0, False), (1.0, True), (0.2, True)):
        field = LabelField(model, cams, MaskParams().field.model_copy(update={"occlusion": 0.0, "region_weight": weight}))
        field.set_view(0, maps[0])
        alone = field.solve().labels.copy()
        field.set_view(4, None if regions else region, strokes, regions=region if regions else None)
        after = field.solve().labels
        assert (alone[ball] == 1).mean() > 0.9
        turned[weight, regions] = int((ball & (alone == 1) & (after == 2)).sum())
    assert turned[1.0, True] == turned[1.0, False] > 0, turned
    assert turned[0.2, True] < turned[1.0, True], turned
