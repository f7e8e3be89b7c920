"""A scene that is only a splat: cameras made around it, its renders as the photos, and the whole library path
(import check, colour match, stylization, give-back) on them. The SH-band options of stylization."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from abcgs.errors import InputError
from abcgs.features.matching import build_groups
from abcgs.features.params import TransferSpec
from abcgs.features.vgg import VGG16Features, random_state_dict
from abcgs.fit.params import FitParams
from abcgs.gaussians import FITTED_ROW, GaussianModel, fitted_rows, render
from abcgs.gaussians.ply import read_ply, write_ply
from abcgs.io.images import save_image
from abcgs.layout import ColorMatchDir
from abcgs.sources.bare_splat import read_splat_source
from abcgs.splats.cameras import cameras_around
from abcgs.splats.exporting import give_back
from abcgs.splats.formats.splat import write_splat_file
from abcgs.splats.importing import import_and_save
from abcgs.splats.params import SplatViewsParams
from abcgs.splats.registry import read_splat
from abcgs.stylize.colormatch import color_match_and_refit
from abcgs.stylize.experiment import read_colormatch
from abcgs.stylize.loop import stylize
from abcgs.stylize.params import ColorMatchParams, StylizeOptim, StylizeParams
from abcgs.stylize.sh_bands import with_higher_sh
from abcgs.view.outputs import _on_stylized_rows

sys.path.insert(0, str(Path(__file__).parent))
from test_splats import make_model  # noqa: E402


def _projected_inside(model: GaussianModel, cams) -> float:
    """Share of (camera, Gaussian) pairs whose centre projects in front of the camera and inside the image."""
    x = np.c_[model.means.numpy(), np.ones(model.num_gaussians)]
    hits = []
    for c in cams:
        p = (c.viewmat @ x.T)[:3]
        uv = (c.K @ p)[:2] / np.maximum(p[2], 1e-9)
        hits.append((p[2] > 0) & (uv[0] >= 0) & (uv[0] < c.width) & (uv[1] >= 0) & (uv[1] < c.height))
    return float(np.mean(hits))


def test_auto_views_orbit_a_compact_splat_and_face_a_layered_one():
    blob = make_model(2000, 0)
    cams, kind = cameras_around(blob, SplatViewsParams(count=12, width=64, height=48))
    assert kind == "orbit" and len(cams) == 12 and cams[0].meta["views_kind"] == "orbit"
    assert _projected_inside(blob, cams) > 0.97
    # a forward-facing capture's splat: trained from z = -3, each Gaussian a few pixels wide there, so the far ones
    # (up to z = 6) are larger; views come from -z, facing +z
    g = torch.Generator().manual_seed(1)
    n = 3000
    means = torch.rand(n, 3, generator=g) * torch.tensor([4.0, 3.0, 6.0]) - torch.tensor([2.0, 1.5, 0.0])
    log_scales = torch.log(0.004 * (means[:, 2:3] + 3.0)).repeat(1, 3)
    facing = GaussianModel(means, blob.quats[:1].repeat(n, 1), log_scales, torch.full((n,), 2.0),
                           torch.zeros(n, 1, 3), torch.zeros(n, 0, 3))
    cams, kind = cameras_around(facing, SplatViewsParams(count=8, width=64, height=48))
    assert kind == "forward"
    assert all(c.center[2] < -1.0 for c in cams)  # the small-Gaussian side
    assert all(c.viewmat[2, 2] > 0.9 for c in cams)  # looking along +z
    assert _projected_inside(facing, cams) > 0.9
    # the same positions with sizes that do not grow: nothing says which side it was seen from, so an orbit
    assert cameras_around(GaussianModel(means, facing.quats, torch.full((n, 3), -4.0), facing.opacity_logits,
                                        facing.sh0, facing.shN),
                          SplatViewsParams(count=8, width=64, height=48))[1] == "orbit"


@pytest.mark.parametrize("refine_every", [0, 5])
def test_a_bare_splat_runs_through_import_stylization_and_give_back(refine_every, tmp_path):
    """A bare ``.splat`` through import, the colour match's re-fit (densifying with ``refine_every`` 5), stylization
    and give-back: the returned file holds every stylized Gaussian, in the source's format."""
    model = make_model(2500, 0, seed=3)
    src = tmp_path / "scene.splat"
    write_splat_file(src, model)
    source = read_splat_source(src, tmp_path / "images", SplatViewsParams(count=8, width=64, height=48))
    assert source.format == "splat" and len(source.views) == 8 and all(v.image_path.is_file() for v in source.views)
    assert source.points.shape[1] == 3 and len(source.points) > 100
    scene = source
    record = import_and_save(scene, src, "auto", FitParams(test_every=4), tmp_path / "gs")
    assert record["imported"]["check"]["psnr"] > 40.0  # its own renders (8-bit PNGs)
    original = read_ply(tmp_path / "gs" / "point_cloud.ply")
    vgg, groups = _single_transfer(tmp_path, 64)
    labels = torch.zeros(original.num_gaussians, dtype=torch.long)
    view_labels = [np.zeros((c.height, c.width), np.int64) for c in scene.cameras]
    cm = color_match_and_refit(original, scene, labels, view_labels, groups,
                               ColorMatchParams(refit_iterations=12, refine_every=refine_every), progress=False)
    assert (cm.model.num_gaussians > original.num_gaussians) == (refine_every > 0)
    sp = StylizeParams(optim=StylizeOptim(iterations=4, color_pass_iterations=2), layers=["relu3_1"], style_height=64)
    res = stylize(cm.model, scene.cameras, view_labels, labels[fitted_rows(cm.model)], groups, vgg, sp,
                  depth_model=original, progress=False)
    with torch.no_grad():
        assert not torch.equal(res.model.sh0, original.sh0)
    (tmp_path / "stylized.ply").parent.mkdir(exist_ok=True)
    from abcgs.gaussians.ply import write_ply

    write_ply(tmp_path / "stylized.ply", res.model)
    returned = give_back(tmp_path / "stylized.ply", tmp_path / "gs" / "splat_source.json", tmp_path / "returned")
    assert returned["format"] == "splat" and returned["file"] == "scene.splat"
    back = read_splat(tmp_path / "returned" / "scene.splat").model
    assert back.num_gaussians == returned["n_gaussians"] == res.model.num_gaussians
    assert back.num_gaussians == model.num_gaussians or refine_every > 0


def _single_transfer(tmp_path, size: int):
    """A random-weight VGG (relu3_1) and the matching group of a single transfer from a random size × size painting."""
    vgg = VGG16Features(random_state_dict(0), ["relu3_1"])
    style = tmp_path / "style.png"
    save_image(style, np.random.default_rng(0).random((size, size, 3)).astype(np.float32))
    groups = build_groups(TransferSpec(scene="s", transfer="single", style="p"), {"p": str(style)}, {}, set(), vgg,
                          style_height=size, layers=["relu3_1"])
    return vgg, groups


@pytest.mark.parametrize("mode", ["zero", "frozen", "optimized", "degree1"])
def test_higher_sh_modes_start_from_and_train_what_they_say(mode, tmp_path):
    original = make_model(800, 3, seed=4)
    matched = original.detach()
    matched.shN = torch.zeros_like(matched.shN)  # what the colour match hands over
    start = with_higher_sh(matched, original, mode)
    expect = {"zero": torch.zeros_like(original.shN), "frozen": original.shN, "optimized": original.shN,
              "degree1": torch.cat([original.shN[:, :3], torch.zeros_like(original.shN[:, 3:])], 1)}[mode]
    assert torch.equal(start.shN, expect)
    cams, _ = cameras_around(original, SplatViewsParams(kind="orbit", count=4, width=48, height=36))
    paths = []
    for c in cams:
        with torch.no_grad():
            save_image(tmp_path / c.name, render(original, c)[0].clamp(0, 1).numpy())
        paths.append(tmp_path / c.name)
    vgg, groups = _single_transfer(tmp_path, 48)
    labels = torch.zeros(original.num_gaussians, dtype=torch.long)
    view_labels = [np.zeros((c.height, c.width), np.int64) for c in cams]
    sp = StylizeParams(optim=StylizeOptim(iterations=3, color_pass_iterations=2, lr_shN=0.01), layers=["relu3_1"],
                       style_height=48, higher_sh=mode)
    res = stylize(start, cams, view_labels, labels, groups, vgg, sp, depth_model=original, progress=False)
    out = res.model.shN
    assert out.shape == original.shN.shape  # the degree is kept in every mode
    if mode == "zero":
        assert torch.equal(out, torch.zeros_like(out))
    elif mode == "frozen":
        assert torch.equal(out, original.shN)
    elif mode == "optimized":
        assert not torch.equal(out, original.shN)
    else:
        assert not torch.equal(out[:, :3], original.shN[:, :3])
        assert torch.equal(out[:, 3:], torch.zeros_like(out[:, 3:]))


def test_a_refitted_scene_takes_the_bands_of_the_fitted_gaussians_it_descends_from():
    original = make_model(50, 3, seed=6)
    rows = torch.tensor([0, 3, 3, 49, 7, 7, 7])  # survivors, clones and split children of fitted rows
    matched = original.index(rows)
    matched.shN = torch.zeros_like(matched.shN)
    matched.attributes = {FITTED_ROW: rows}
    assert torch.equal(with_higher_sh(matched, original, "frozen").shN, original.shN[rows])
    band1 = with_higher_sh(matched, original, "degree1").shN
    assert torch.equal(band1[:, :3], original.shN[rows, :3]) and not bool(band1[:, 3:].any())


def test_read_colormatch_checks_its_rows_against_the_fitted_scene(tmp_path):
    d = ColorMatchDir(tmp_path / "m")
    d.root.mkdir()
    write_ply(d.ply, make_model(6, 0, seed=1))
    with pytest.raises(InputError, match="dvc repro colormatch@m"):
        read_colormatch(d.root, "m", 4)  # no fitted_rows.npy
    for bad in (np.array([0, 1, 2, 3, 3]), np.array([0, 1, 2, 3, 3, 4]), np.array([0, 1, 2, 3, 3, -1]),
                np.zeros(6, np.float32), np.array([[0, 1, 2], [3, 3, 1]])):
        np.save(d.fitted_rows, bad)
        with pytest.raises(InputError, match="does not map 6 Gaussians onto the 4 fitted ones; re-run the colour"):
            read_colormatch(d.root, "m", 4)
        assert _on_stylized_rows(np.arange(4), d.fitted_rows, 6) is None  # the viewer drops its labels layer
    np.save(d.fitted_rows, np.array([0, 1, 2, None, 3, 1], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match="re-run the colour match"):  # a pickle is never loaded
        read_colormatch(d.root, "m", 4)
    np.save(d.fitted_rows, np.arange(6))
    whole = d.fitted_rows.read_bytes()
    for cut in (0, len(whole) - 8):  # empty, or one row short of its header's shape
        d.fitted_rows.write_bytes(whole[:cut])
        with pytest.raises(InputError, match="re-run the colour match"):
            read_colormatch(d.root, "m", 4)
        assert _on_stylized_rows(np.arange(4), d.fitted_rows, 6) is None
    np.save(d.fitted_rows, np.array([0, 1, 2, 3, 3, 1]))
    assert read_colormatch(d.root, "m", 4).attributes[FITTED_ROW].tolist() == [0, 1, 2, 3, 3, 1]
    assert _on_stylized_rows(np.array([5, 6, 7, 8]), d.fitted_rows, 6).tolist() == [5, 6, 7, 8, 8, 6]
    assert _on_stylized_rows(np.arange(4), tmp_path / "none.npy", 4).tolist() == [0, 1, 2, 3]  # no rows: as fitted

