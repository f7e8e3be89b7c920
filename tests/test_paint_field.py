"""The masks page with the scene's fit (abcgs/masks/page/field_session.py through abcgs/masks/page/session.py): each Segment cuts
the view from its strokes and the labels already in 3-D, lifts every painted view and shows every view's labels in
the strip; without a fit, or with views of another size, the page says why and cuts one view at a time.

The fit is 200 steps of the tiny scene's Gaussians from its points, without densification (584 Gaussians, about
7 s), written once per module."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from test_paint import request, served  # noqa: F401  (served: the fixture)

from abcgs.errors import InputError
from abcgs.io.images import load_labels, load_stroke_map, stroke_map_path
from abcgs.masks.content import label_iou, read_label_files
from abcgs.masks.page.command import main
from abcgs.masks.page.field_session import THUMB_PHOTO
from abcgs.masks.page.session import PaintSession
from abcgs.masks.params import UNDECIDED
from abcgs.masks.strokes import rasterize_strokes
from abcgs.viz import LABEL_COLOURS
from eval.bench.paint_iou import simulated_strokes


def fit_tiny(colmap: Path, ply: Path, iterations: int = 200) -> Path:
    """A short fit of the tiny scene's layout ``colmap`` (no densification: its points' Gaussians, placed), to ``ply``."""
    from abcgs.fit.params import FitParams
    from abcgs.fit.training import fit
    from abcgs.gaussians.ply import write_ply
    from abcgs.sfm.model import read_scene

    params = FitParams(iterations=iterations, backend="cpu", test_every=0, threads=1, seed=0, densify=False)
    write_ply(ply, fit(read_scene(colmap), params, progress=False).model)
    return ply


@pytest.fixture(scope="module")
def fitted(tiny_colmap, tmp_path_factory) -> Path:
    return fit_tiny(tiny_colmap, tmp_path_factory.mktemp("fit") / "point_cloud.ply")


def fit_views(tiny_colmap: Path, folder: Path) -> Path:
    """A scene folder of the fit's own (undistorted) views."""
    shutil.copytree(tiny_colmap / "images", folder / "images")
    return folder


def truth(tiny_colmap: Path, view: int) -> np.ndarray:
    return load_labels(tiny_colmap / "masks" / f"{view:03d}.png")


def test_each_segment_labels_every_view_and_save_keeps_the_strokes(fitted, tiny_colmap, tmp_path) -> None:
    folder = fit_views(tiny_colmap, tmp_path / "scene")
    s = PaintSession.for_scene(folder)
    assert s.attach_fit(fitted, tiny_colmap), s.field_note
    fs = s.field
    assert s.state()["field"] == {"on": True, "note": f"3-D labels from {fitted}"}
    before = fs.listing([it.name for it in s.items])
    assert not before["labelled"] and len(before["views"]) == 16 and not any(v["painted"] for v in before["views"])
    assert np.array_equal(fs.thumbnail(3), fs.strip.photos[3])  # the photo alone before the first Segment

    s.set_strokes(0, simulated_strokes(truth(tiny_colmap, 0), 2, radius=3.0))
    first = s.segment(0)
    assert {1, 2, 3} <= set(np.unique(first.labels)) and fs.field.painted == [0]
    listing = fs.listing([it.name for it in s.items])
    assert listing["labelled"] and 0 < listing["seconds"] <= first.seconds + 1e-3
    assert sum(listing["counts"].values()) == fs.field.model.num_gaussians
    assert [v["index"] for v in listing["views"] if v["painted"]] == [0]
    doubts = [v["doubt"] for v in listing["views"]]
    assert doubts == sorted(doubts, reverse=True) and sorted(v["index"] for v in listing["views"]) == list(range(16))
    # every view, painted or not, shows the three labels where they are (measured: IoU 0.41–0.82 with this coarse fit)
    for view, lab in enumerate(fs.state.maps):
        small = cv2.resize(truth(tiny_colmap, view).astype(np.uint8), lab.shape[::-1], interpolation=cv2.INTER_NEAREST)
        iou = label_iou(np.where(lab == UNDECIDED, 0, lab), small, 3)
        assert min(iou.values()) > 0.35, (view, iou)

    # view 5 with strokes of label 1 only: the labels in 3-D seed its cut, so it has the other two as well
    only_one = [st for st in simulated_strokes(truth(tiny_colmap, 5), 2, radius=3.0) if st.label == 1]
    s.set_strokes(5, only_one)
    second = s.segment(5)
    assert {1, 2, 3} <= set(np.unique(second.labels)), second.counts()
    assert fs.field.painted == [0, 5]
    print(f"Segment, strip included: {first.seconds:.2f} s (view 000), {second.seconds:.2f} s (view 005)")

    written = s.save()
    assert written == [folder / "masks" / "000.png", folder / "masks" / "005.png"]
    maps, _ = read_label_files(written, [first.labels.shape] * 2)
    assert np.array_equal(np.maximum(maps[0], 0), np.where(first.claimed, first.labels, 0))  # the first view: its cut
    # a correction (correction: region) gives the field each stroke's colour region in the photo, its strokes
    # included: that is what is saved, for the stage
    strokes_5 = rasterize_strokes(s.items[5].strokes, first.labels.shape)
    assert second.claimed[strokes_5 >= 0].all() and second.claimed.sum() > (strokes_5 >= 0).sum()
    assert np.array_equal(second.labels[strokes_5 >= 0], strokes_5[strokes_5 >= 0])
    assert np.array_equal(maps[1], np.where(second.claimed, second.labels, -1))
    for i in (0, 5):  # the strokes, for the masks stage
        seeds = load_stroke_map(stroke_map_path(folder / "masks", f"{i:03d}"), first.labels.shape)
        assert np.array_equal(seeds, rasterize_strokes(s.items[i].strokes, first.labels.shape))

    s.set_strokes(5, [])  # Clear: view 5 leaves the labels in 3-D
    assert fs.field.painted == [0]
    assert [v["index"] for v in fs.listing([it.name for it in s.items])["views"] if v["painted"]] == [0]


def test_the_strip_thumbnail_is_the_photo_under_the_label_colours_and_white_where_undecided(fitted, tiny_colmap,
                                                                                            tmp_path) -> None:
    s = PaintSession.for_scene(fit_views(tiny_colmap, tmp_path / "scene"))
    assert s.attach_fit(fitted, tiny_colmap), s.field_note
    s.set_strokes(0, simulated_strokes(truth(tiny_colmap, 0), 2, radius=3.0))
    s.segment(0)
    fs = s.field
    lab = fs.state.maps[7]
    lab[:4] = UNDECIDED
    thumb = fs.thumbnail(7).astype(np.float32)
    photo = fs.strip.photos[7].astype(np.float32)
    assert (thumb[:4] == 255).all()
    for k in (1, 2, 3):
        at = lab == k
        assert at.sum() > 100, k
        colour = (thumb[at] - THUMB_PHOTO * photo[at]) / (1 - THUMB_PHOTO)
        assert np.abs(colour - np.array(LABEL_COLOURS[k], np.float32)).max() < 1.5, k  # the page's palette
    with pytest.raises(InputError, match="no view 16 in the strip; it has 16"):
        fs.thumbnail(16)


def test_without_a_fit_or_with_views_of_another_size_the_page_cuts_one_view_at_a_time(fitted, tiny_scene,
                                                                                       tiny_colmap, tmp_path) -> None:
    folder = fit_views(tiny_colmap, tmp_path / "scene")
    s = PaintSession.for_scene(folder)
    assert not s.attach_fit(tmp_path / "none.ply", tiny_colmap, make="`dvc repro fit@x`")
    assert s.field is None and s.field_note == f"one view at a time: no fit at {tmp_path / 'none.ply'}; " \
                                               "`dvc repro fit@x` makes it"
    assert s.state()["field"]["on"] is False
    s.set_strokes(0, simulated_strokes(truth(tiny_colmap, 0), 2, radius=3.0))
    assert {1, 2, 3} <= set(np.unique(s.segment(0).labels))  # GrabCut on the view alone

    photos = PaintSession.for_scene(tiny_scene)  # the photos, 160x120; the fit's undistorted views are 161x120
    assert not photos.attach_fit(fitted, tiny_colmap)
    assert photos.field_note == ("one view at a time: 000.png is 160x120 but the fit's view of it is 161x120 "
                                 "(undistorted): paint the views one at a time")
    other = tmp_path / "other" / "images"
    other.mkdir(parents=True)
    shutil.copy(tiny_colmap / "images" / "000.png", other / "elsewhere.png")
    none = PaintSession.for_scene(other.parent)
    assert not none.attach_fit(fitted, tiny_colmap) and "no view of the page is a camera of" in none.field_note


def _params_scene(tmp_path: Path, tiny_colmap: Path, masks: dict) -> Path:
    """params.yaml with the scene ``t`` (a folder of the fit's views) and its layout at out/t/colmap."""
    fit_views(tiny_colmap, tmp_path / "scene")
    (tmp_path / "out" / "t").mkdir(parents=True)
    os.symlink(tiny_colmap, tmp_path / "out" / "t" / "colmap")
    (tmp_path / "params.yaml").write_text(json.dumps({"data": {"scenes": {"t": {"path": "scene"}}}, "masks": masks}))
    return tmp_path / "params.yaml"


def test_the_scene_of_the_params_file_opens_its_fit_with_its_masks_params(fitted, tiny_colmap, tmp_path,
                                                                         capsys) -> None:
    params = _params_scene(tmp_path, tiny_colmap, {"field": {"k": 6}, "lift": {"min_share": 0.6}})
    s = PaintSession.for_params(params, "t")
    ply = tmp_path / "out" / "t" / "gs" / "point_cloud.ply"
    assert s.field is None and s.field_note == f"one view at a time: no fit at {ply}; `dvc repro fit@t` makes it"
    ply.parent.mkdir()
    shutil.copy(fitted, ply)
    s = PaintSession.for_params(params, "t")
    assert s.field is not None and s.field_note == f"3-D labels from {ply}"
    assert s.field.field.params.k == 6 and s.field.field.lift.min_share == 0.6
    assert PaintSession.for_params(params, "t", fit=False).field is None  # --one-view
    assert main([str(tmp_path / "scene"), "--fit", str(ply), "--no-open"]) == 2
    assert "--fit and --colmap go together" in capsys.readouterr().err
    assert main(["--scene", "t", "--params", str(params), "--fit", str(ply), "--colmap", str(tiny_colmap)]) == 2
    assert "--scene NAME finds its own fit" in capsys.readouterr().err


def test_the_cli_names_the_command_that_makes_the_fit(tiny_colmap, tmp_path) -> None:
    params = _params_scene(tmp_path, tiny_colmap, {})
    proc = subprocess.Popen([sys.executable, "-m", "abcgs.masks.page", "--scene", "t", "--params", str(params),
                             "--no-open"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            cwd=Path(__file__).resolve().parents[1])
    try:
        lines = [proc.stdout.readline() for _ in range(2)]
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    started = [ln for ln in lines if re.search(r"http://127\.0\.0\.1:\d+/\?token=", ln)]
    assert started and "one view at a time: no fit at" in started[0] and "`dvc repro fit@t` makes it" in started[0], \
        lines


def test_the_api_serves_the_strip_and_its_thumbnails(fitted, tiny_colmap, tmp_path, served) -> None:  # noqa: F811
    s = PaintSession.for_scene(fit_views(tiny_colmap, tmp_path / "scene"))
    assert s.attach_fit(fitted, tiny_colmap), s.field_note
    url = served(s)
    assert json.loads(request(url + "/api/state")[1])["field"]["on"] is True
    assert json.loads(request(url + "/api/strip")[1])["labelled"] is False
    strokes = [st.to_json() for st in simulated_strokes(truth(tiny_colmap, 0), 2, radius=3.0)]
    status, body, _ = request(url + "/api/segment/0", {"strokes": strokes, "revision": 1})
    assert status == 200, body
    listing = json.loads(request(url + "/api/strip")[1])
    assert listing["labelled"] and [v["name"] for v in listing["views"] if v["painted"]] == ["000.png"]
    assert set(listing["counts"]) == {"undecided", "stroke", "lifted", "graph"} and listing["seconds"] > 0
    status, png, ctype = request(url + "/api/strip/0.png")
    assert status == 200 and ctype == "image/png"
    thumb = cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    assert np.array_equal(thumb, s.field.thumbnail(0))
    status, body, _ = request(url + "/api/strip/16.png")
    assert status == 400 and "no view 16 in the strip" in json.loads(body)["error"]

    plain = PaintSession.for_scene(fit_views(tiny_colmap, tmp_path / "plain"))
    url = served(plain)
    status, body, _ = request(url + "/api/strip")
    assert status == 404 and json.loads(body)["error"] == plain.field_note == "one view at a time: no fit given"
    assert request(url + "/api/strip/0.png")[0] == 404


def test_a_region_correction_saves_each_strokes_colour_region_and_the_stage_reads_the_same(fitted, tiny_colmap,
                                                                                           tmp_path) -> None:
    """``correction: region``: a correction's evidence is its strokes' regions in the photo
    (:func:`abcgs.masks.regions.stroke_regions`), larger than the strokes, inside the reach; the page saves that map,
    which is what the ``masks`` stage reads back as the view's cut."""
    from abcgs.masks.lifting import NO_VOTE
    from abcgs.masks.params import FieldParams
    from abcgs.masks.regions import depth_steps, stroke_regions, view_evidence
    from abcgs.masks.strokes import Stroke

    folder = fit_views(tiny_colmap, tmp_path / "scene")
    s = PaintSession.for_scene(folder)
    assert s.attach_fit(fitted, tiny_colmap, FieldParams(correction="region", correction_reach=0.1))
    first = simulated_strokes(truth(tiny_colmap, 0), 2, radius=3.0)
    s.set_strokes(0, first)
    s.segment(0)  # the first Segment is a cut, whatever the correction
    inside = cv2.distanceTransform((truth(tiny_colmap, 5) == 1).astype(np.uint8), cv2.DIST_L2, 5)
    y, x = np.unravel_index(int(np.argmax(inside)), inside.shape)
    dot = [Stroke(1, np.array([[x + 0.5, y + 0.5]]), 2.0)]  # a dot in the middle of label 1
    s.set_strokes(5, dot)
    seg = s.segment(5)
    hw = seg.labels.shape
    seeds = rasterize_strokes(dot, hw)
    depth_5, depth_0 = (s.field.field.depth_of(s.field.camera_of[i]) for i in (5, 0))
    region = stroke_regions(s.image(5), seeds, int(round(0.1 * min(hw))), FieldParams().region_tolerance,
                            barrier=depth_steps(depth_5, FieldParams().region_depth_step, hw))
    assert np.array_equal(seg.claimed, region >= 0)
    assert (region == 1).sum() > 2 * (seeds == 1).sum()  # the region reaches past the dot
    truth_5 = truth(tiny_colmap, 5)
    assert ((truth_5 == 1)[region == 1]).mean() > 0.8  # and stays on the dot's part
    s.save()
    maps, _ = read_label_files([folder / "masks" / "005.png", folder / "masks" / "000.png"], [hw, hw])
    assert np.array_equal(maps[0], region)
    # the stage knows a correction's regions from a cut: the map is what the view's strokes make of its photo
    params = FieldParams(correction="region", correction_reach=0.1)
    front = rasterize_strokes(first, hw)
    cut, regions = view_evidence(maps[0], seeds, s.image(5), params, depth_5)
    assert cut is None and np.array_equal(regions, region)
    cut, regions = view_evidence(maps[1], front, s.image(0), params, depth_0)
    assert np.array_equal(cut, maps[1]) and (regions == NO_VOTE).all()  # the cut's own strokes correct nothing
    by_cut = params.model_copy(update={"correction": "cut"})
    assert view_evidence(maps[0], seeds, s.image(5), by_cut, depth_5)[1] is None
    cut, _ = view_evidence(np.where(region == 1, NO_VOTE, region), seeds, s.image(5), params, depth_5)
    assert cut is not None  # a map that is not the regions is a cut


def test_a_correction_on_a_view_once_cut_keeps_the_rest_of_its_cut(fitted, tiny_colmap, tmp_path) -> None:
    """A dot on the view the first Segment cut overrules the cut in its colour region and keeps the cut elsewhere
    (the cut of a whole view is not thrown away for one dot's region); the page still saves the cut, and the ``masks``
    stage, from the saved map, strokes and photo, sets the view as the page did."""
    from abcgs.masks.field import LabelField
    from abcgs.masks.lifting import NO_VOTE
    from abcgs.masks.params import FieldParams
    from abcgs.masks.regions import view_evidence
    from abcgs.masks.strokes import Stroke

    params = FieldParams(correction="region", correction_reach=0.1)
    folder = fit_views(tiny_colmap, tmp_path / "scene")
    s = PaintSession.for_scene(folder)
    assert s.attach_fit(fitted, tiny_colmap, params)
    first = simulated_strokes(truth(tiny_colmap, 0), 2, radius=3.0)
    s.set_strokes(0, first)
    s.segment(0)
    field = s.field.field
    cam = s.field.camera_of[0]
    cut = field.cut_of(cam).copy()
    decided = np.flatnonzero(cut.ravel() >= 0)
    y, x = np.unravel_index(decided[len(decided) // 2], cut.shape)
    other = 1 + int(cut[y, x]) % max(1, int(cut.max()))  # a label the cut does not give there
    dot = Stroke(other, np.array([[x + 0.5, y + 0.5]]), 2.0)
    s.set_strokes(0, [*first, dot])
    s.segment(0)
    assert np.array_equal(field.cut_of(cam), cut)  # the cut is kept, not re-cut and not dropped
    evidence = field.evidence_map(cam)
    hw = cut.shape
    seeds = rasterize_strokes([*first, dot], hw)
    assert field.depth_of(cam) is field.depth_of(cam)  # rendered once, kept
    by_cut = LabelField(field.model, field.cameras, params.model_copy(update={"correction": "cut"}))
    assert by_cut.depth_of(cam) is None  # no colour region to bound: no depth rendered
    _, regions = view_evidence(cut, seeds, s.image(0), params, field.depth_of(cam))
    assert (regions == other).any() and (regions[seeds < 0] != NO_VOTE).sum() > 0
    assert np.array_equal(evidence, np.where(regions >= 0, regions, cut))
    outside = regions == NO_VOTE
    assert outside.mean() > 0.5 and np.array_equal(evidence[outside], cut[outside])
    s.save()
    maps, _ = read_label_files([folder / "masks" / "000.png"], [hw])
    assert np.array_equal(maps[0], cut)  # what the page saves is the cut; the stage lays the same regions over it
    stage_cut, stage_regions = view_evidence(maps[0], load_stroke_map(stroke_map_path(folder / "masks", "000"), hw),
                                             s.image(0), params, field.depth_of(cam))
    assert np.array_equal(stage_cut, cut) and np.array_equal(stage_regions, regions)
