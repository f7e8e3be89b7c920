"""Objects on nothing: generated views that frame the whole object upright, a per-scene background, colour match and
stylization that act on the object only and leave empty space empty, ``color_only``, the object metrics."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from abcgs.cameras import Cameras
from abcgs.evaluation.objects import object_scores
from abcgs.features.matching import build_groups
from abcgs.features.params import TransferSpec
from abcgs.features.vgg import VGG16Features, random_state_dict
from abcgs.gaussians import FITTED_ROW, GaussianModel, fitted_rows, render
from abcgs.io.images import load_render, save_image
from abcgs.layout import ColmapDir
from abcgs.losses.terms import background_loss, silhouette_loss
from abcgs.masks.lifting import render_label_map
from abcgs.scene.params import TinySceneParams
from abcgs.scene.synthetic import write_object_dataset
from abcgs.sfm.model import read_scene
from abcgs.sfm.params import ReconstructParams
from abcgs.silhouette import composite_rgba, object_gaussians, silhouettes
from abcgs.sources.blender import read_blender_source
from abcgs.sources.model import write_source_model
from abcgs.sources.params import SceneParams
from abcgs.splats.cameras import cameras_around, world_up
from abcgs.splats.params import SplatViewsParams
from abcgs.stylize.colormatch import color_match_and_refit
from abcgs.stylize.loop import stylize
from abcgs.stylize.params import ColorMatchParams, StylizeOptim, StylizeParams
from abcgs.types import FRAME_FILLING, Background, CalibratedScene

sys.path.insert(0, str(Path(__file__).parent))
from test_splats import make_model  # noqa: E402

OBJECT = Background(object=True)


def _project(cam, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = (cam.viewmat @ np.c_[x, np.ones(len(x))].T)[:3]
    return (cam.K @ p)[:2] / p[2], p[2]


# ------------------------------------------------------------------------------------------------ generated views
def test_orbit_views_hold_every_gaussian_that_matters_uncropped_and_upright():
    model = make_model(3000, 0, seed=5)
    model.means[:, 0] *= 2.5  # an elongated object: a ring at the old quantile distance would crop it
    model.opacity_logits[:50] = -5.0  # faint floaters do not count
    model.means[:50] *= 4.0
    params = SplatViewsParams(kind="orbit", count=12, width=96, height=72)
    cams, kind = cameras_around(model, params)
    assert kind == "orbit" and len(cams) == 12
    matters = (model.opacities >= 0.1).numpy()
    x = model.means.numpy()[matters]
    sigma = 2.0 * model.scales.max(dim=1).values.numpy()[matters]
    up = world_up("auto")
    heights = []
    for c in cams:
        uv, z = _project(c, x)
        r = c.K[0, 0] * sigma / z
        assert (z > 0).all()
        assert (uv[0] - r >= 0).all() and (uv[0] + r <= c.width).all()
        assert (uv[1] - r >= 0).all() and (uv[1] + r <= c.height).all()
        with torch.no_grad():
            alpha = render(model, c)[1][..., 0].numpy()
        assert max(alpha[0].max(), alpha[-1].max(), alpha[:, 0].max(), alpha[:, -1].max()) < 0.5  # no object on the border
        centre = x.mean(0)
        (u0, v0), _ = _project(c, centre[None])
        (u1, v1), _ = _project(c, (centre + 0.3 * up)[None])
        assert v1[0] < v0[0]  # the up axis points up in the image
        heights.append(float(c.center @ up))
    assert np.ptp(heights) > 0.3 * np.linalg.norm(cams[0].center - centre)  # rings at several elevations


def test_forward_views_spread_over_the_parallax_asked_for():
    g = torch.Generator().manual_seed(1)
    n = 3000
    means = torch.rand(n, 3, generator=g) * torch.tensor([4.0, 3.0, 6.0]) - torch.tensor([2.0, 1.5, 0.0])
    facing = GaussianModel(means, torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1), torch.log(0.004 * (means[:, 2:3] + 3.0)).repeat(1, 3),
                           torch.full((n,), 2.0), torch.zeros(n, 1, 3), torch.zeros(n, 0, 3))
    cams, kind = cameras_around(facing, SplatViewsParams(count=8, width=64, height=48, parallax_deg=40.0))
    assert kind == "forward"
    axes = [c.viewmat[2, :3] for c in cams]
    widest = max(np.degrees(np.arccos(np.clip(a @ b, -1, 1))) for a in axes for b in axes)
    assert widest >= 30.0


def _flat_object(n: int = 4000, seed: int = 3) -> GaussianModel:
    """A flat oval object (2 × 1.2 across in x, y; 0.2 deep in z), off the origin, trained from its -z side: its
    Gaussians grow away from that side (σ × e^1.2 across its depth), so ``auto`` faces it from -z."""
    g = torch.Generator().manual_seed(seed)
    r, t = torch.sqrt(torch.rand(n, generator=g)), torch.rand(n, generator=g) * 2 * np.pi
    z = (torch.rand(n, generator=g) - 0.5) * 0.2
    means = torch.stack([r * torch.cos(t), 0.6 * r * torch.sin(t), z], 1) + torch.tensor([0.3, -0.2, 1.0])
    return GaussianModel(means, torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1), (float(np.log(0.02)) + 6.0 * z)[:, None].repeat(1, 3),
                         torch.full((n,), 3.0), torch.randn(n, 1, 3, generator=g) * 0.5, torch.zeros(n, 0, 3))


def _border_and_cover(model: GaussianModel, cams) -> tuple[float, float]:
    """The largest alpha of the original on any view's border pixels, and the least share of a view it covers."""
    border, cover = 0.0, 1.0
    for c in cams:
        with torch.no_grad():
            alpha = render(model, c)[1][..., 0].numpy()
        border = max(border, alpha[0].max(), alpha[-1].max(), alpha[:, 0].max(), alpha[:, -1].max())
        cover = min(cover, float((alpha >= 0.5).mean()))
    return float(border), cover


def test_forward_views_of_an_object_hold_all_of_it_and_orbit_framing_is_the_same(tmp_path):
    """A flat object seen from one side gets forward views (auto) that frame all of it when its scene is an object
    (a background: read_splat_source as the stages call it); the same views as a frame-filling scene frame its
    quantiles, which crop it (74-79 % of each view's border on the object). Orbit views frame every Gaussian either
    way, so the object flag does not move them."""
    from abcgs.gaussians.ply import write_ply
    from abcgs.sources.bare_splat import read_splat_source

    model = _flat_object()
    params = SplatViewsParams(count=12, width=64, height=48)
    write_ply(tmp_path / "brooch.ply", model)
    source = read_splat_source(tmp_path / "brooch.ply", tmp_path / "views", params, background=(0.0, 0.0, 0.0))
    assert source.metadata["views_kind"] == "forward" and len(source.cameras) == 12
    assert all(c.viewmat[2, 2] > 0.9 and c.center[2] < 0.0 for c in source.cameras)  # facing it from -z, face on
    border, cover = _border_and_cover(model, list(source.cameras))
    assert border < 0.5 and cover > 0.3, (border, cover)  # whole, and not a speck
    scene_cams, kind = cameras_around(model, params)  # a frame-filling scene: the quantile framing crops it
    assert kind == "forward" and _border_and_cover(model, scene_cams)[0] >= 0.5
    same = read_splat_source(tmp_path / "brooch.ply", tmp_path / "views_scene", params)
    assert all(np.array_equal(a.viewmat, b.viewmat) for a, b in zip(same.cameras, scene_cams))
    forward = SplatViewsParams(kind="forward", count=8, width=96, height=72, parallax_deg=60.0)
    assert _border_and_cover(model, cameras_around(model, forward, object_scene=True)[0])[0] < 0.5
    orbit = SplatViewsParams(kind="orbit", count=12, width=64, height=48)
    for m in (model, make_model(3000, 0, seed=5)):
        as_object, as_scene = cameras_around(m, orbit, object_scene=True)[0], cameras_around(m, orbit)[0]
        assert all(np.array_equal(a.viewmat, b.viewmat) for a, b in zip(as_object, as_scene))


# ------------------------------------------------------------------------------------------------ the background
def test_a_scenes_background_is_resolved_from_its_entry_and_format():
    assert SceneParams(path="x").resolved_background("photos") == FRAME_FILLING
    assert SceneParams(path="x").resolved_background("splat") == Background((0.0, 0.0, 0.0), object=True)
    assert SceneParams(path="x").resolved_background("blender") == Background((1.0, 1.0, 1.0), object=True)
    assert SceneParams(path="x", background=[0.2, 0.3, 0.4]).resolved_background("colmap").color == (0.2, 0.3, 0.4)
    assert SceneParams(path="x", background="transparent").resolved_background("photos").transparent
    with pytest.raises(ValueError):
        SceneParams(path="x", background="pink")


def test_an_rgba_dataset_records_its_background_and_alpha_for_the_stages(tmp_path):
    folder = write_object_dataset(tmp_path / "obj", TinySceneParams(n_views=9, width=64, height=48, supersample=1))
    source = read_blender_source(folder, background=(0.0, 0.0, 0.0))
    write_source_model(source, tmp_path / "colmap", ReconstructParams(), background=OBJECT)
    colmap = ColmapDir(tmp_path / "colmap")
    scene = read_scene(colmap.root)
    assert scene.background == OBJECT and scene.format == "blender"
    assert json.loads(colmap.scene.read_text())["background"]["object"] is True
    assert scene.alpha_paths is not None and len(scene.alpha_paths) == 9
    assert all(p.parent == colmap.root / "alpha" and p.is_file() for p in scene.alpha_paths)
    write_source_model(source, tmp_path / "frame", ReconstructParams())  # no background given: a frame-filling scene
    assert read_scene(tmp_path / "frame").background == FRAME_FILLING


def test_transparent_renders_are_written_straight_alpha_and_read_back_on_black(tmp_path):
    rng = np.random.default_rng(0)
    alpha = rng.random((8, 10, 1)).astype(np.float32)
    color = rng.random((8, 10, 3)).astype(np.float32)
    rgba = composite_rgba(color * alpha, alpha, Background(transparent=True, object=True))
    assert rgba.shape == (8, 10, 4)
    save_image(tmp_path / "r.png", rgba)
    back = load_render(tmp_path / "r.png", Background(transparent=True, object=True))
    np.testing.assert_allclose(back, color * alpha, atol=3 / 255)


def test_object_losses():
    alpha = torch.zeros(4, 5, 1)
    ref = torch.zeros(4, 5, 1)
    ref[1:3, 1:4] = 1.0
    assert float(silhouette_loss(alpha, ref)) == pytest.approx(6 / 20)
    img = torch.full((4, 5, 3), 0.2)
    empty = ref[..., 0] < 0.5
    assert float(background_loss(img, torch.zeros(3), empty)) == pytest.approx(0.2)
    assert float(background_loss(img, torch.zeros(3), torch.zeros(4, 5, dtype=torch.bool))) == 0.0


# ------------------------------------------------------------------------------------------------ stylization
def _object_scene(tmp_path, n_views=6, size=(64, 48)):
    """A blob object with a faint floater cloud beside it; its renders on black are the photos."""
    model = make_model(1500, 0, seed=7)
    haze = make_model(200, 0, seed=8)
    haze.means[:] = haze.means * 0.3 + torch.tensor([0.0, 0.0, 1.6])  # off to one side
    haze.opacity_logits[:] = -4.0  # about 0.018 each, and black: invisible on black, a fog once recoloured
    haze.sh0[:] = (0.0 - 0.5) / 0.28209479177387814
    model = GaussianModel(**{k: torch.cat([getattr(model, k), getattr(haze, k)]) for k, _ in model.items()})
    cams, _ = cameras_around(model, SplatViewsParams(kind="orbit", count=n_views, width=size[0], height=size[1]))
    paths = []
    for c in cams:
        with torch.no_grad():
            save_image(tmp_path / c.name, render(model, c)[0].clamp(0, 1).numpy())
        paths.append(tmp_path / c.name)
    scene = CalibratedScene(Cameras.from_list(cams), paths, model.means.numpy()[:10], np.zeros((10, 3), np.float32))
    return model, scene


def _single_transfer(tmp_path, size: int):
    vgg = VGG16Features(random_state_dict(0), ["relu3_1"])
    style = tmp_path / "style.png"
    yy, xx = np.mgrid[0:size, 0:size] / size
    save_image(style, np.stack([0.2 + 0.7 * xx, 0.9 - 0.5 * yy, 0.5 + 0.4 * np.sin(8 * xx)], -1).astype(np.float32))
    groups = build_groups(TransferSpec(scene="s", transfer="single", style="p"), {"p": str(style)}, {}, set(), vgg,
                          style_height=size, layers=["relu3_1"])
    return vgg, groups


def _run(model, scene, vgg, groups, background, **sp_kw):
    labels = torch.zeros(model.num_gaussians, dtype=torch.long)
    view_labels = [np.zeros((c.height, c.width), np.int64) for c in scene.cameras]
    sp = StylizeParams(optim=StylizeOptim(iterations=12, color_pass_iterations=4), layers=["relu3_1"], style_height=48,
                       **sp_kw)
    cm = color_match_and_refit(model, scene, labels, view_labels, groups, ColorMatchParams(refit_iterations=6),
                               progress=False, background=background, color_only=sp.color_only)
    return stylize(cm.model, scene.cameras, view_labels, labels[fitted_rows(cm.model)], groups, vgg, sp,
                   depth_model=model, progress=False,
                   background=background).model


def _renders(model, cams):
    with torch.no_grad():
        out = [render(model, c) for c in cams]
    return [o[0].clamp(0, 1).numpy() for o in out], [o[1][..., 0].numpy() for o in out]


def test_an_object_scene_keeps_its_empty_space_and_silhouette(tmp_path):
    model, scene = _object_scene(tmp_path)
    vgg, groups = _single_transfer(tmp_path, 48)
    on_object = object_gaussians(model, scene.cameras, silhouettes(model, scene.cameras))
    # the haze is not the object (but where a view sees it over the object), the blob is
    assert on_object[1500:].float().mean() < 0.3 and on_object[:1500].float().mean() > 0.9
    (orig, orig_a) = _renders(model, scene.cameras)
    as_object = _run(model, scene, vgg, groups, OBJECT)
    as_frame = _run(model, scene, vgg, groups, FRAME_FILLING)
    res = {}
    for name, m in (("object", as_object), ("frame", as_frame)):
        imgs, alphas = _renders(m, scene.cameras)
        res[name] = object_scores(orig, imgs, orig_a, alphas, _no_pairs(), _no_pairs())
    assert res["object"].background_change <= 0.01
    assert res["object"].silhouette_iou >= 0.98
    _, blob_a = _renders(model.index(torch.arange(1500)), scene.cameras)
    haze_px = [(a >= 0.005) & (b < 0.01) for a, b in zip(orig_a, blob_a)]  # where only the black haze is
    fog = {name: np.mean([np.abs(i - o).max(-1)[m].mean() for i, o, m in zip(_renders(m, scene.cameras)[0], orig, haze_px)])
           for name, m in (("object", as_object), ("frame", as_frame))}
    assert fog["object"] < 0.25 * fog["frame"]
    for k, t in as_object.items():  # the Gaussians off the object are kept exactly
        assert torch.equal(t[~on_object], getattr(model, k)[~on_object]), k
    assert not torch.equal(as_object.sh0[:1500], model.sh0[:1500])


def test_the_colour_match_refit_densifies_the_object_and_keeps_its_rest_and_rows(tmp_path):
    """The re-fit densifies: the object's Gaussians are cloned, split and pruned, each re-fitted Gaussian names the
    fitted row it descends from, and the Gaussians off the object are each kept once, exactly."""
    model, scene = _object_scene(tmp_path)
    vgg, groups = _single_transfer(tmp_path, 48)
    on_object = object_gaussians(model, scene.cameras, silhouettes(model, scene.cameras))
    labels = torch.zeros(model.num_gaussians, dtype=torch.long)
    view_labels = [np.zeros((c.height, c.width), np.int64) for c in scene.cameras]
    cm = color_match_and_refit(model, scene, labels, view_labels, groups,
                               ColorMatchParams(refit_iterations=60, refine_every=10), progress=False,
                               background=OBJECT)
    rows = cm.model.attributes[FITTED_ROW]
    assert rows.shape == (cm.model.num_gaussians,) and int(rows.min()) >= 0 and int(rows.max()) < model.num_gaussians
    counts = torch.bincount(rows, minlength=model.num_gaussians)
    assert int((counts > 1).sum()) > 20  # clones and split children carry their parent's row
    assert bool(on_object[counts > 1].all())  # only the object grew
    off = torch.where(~on_object)[0]
    assert torch.equal(counts[off], torch.ones_like(off))
    at = torch.argsort(rows)[torch.searchsorted(rows.sort().values, off)]  # where each off-object row went
    for k, t in cm.model.items():
        assert torch.equal(t[at], getattr(model, k)[off]), k
    # the labels follow: the fitted labels by row render as the fitted scene's labels do, in every view, but where
    # a split child of a Gaussian across the two halves' border lands on the other side (0.885-0.912 here, where the
    # re-fit grows 1,700 Gaussians to 10,716; 0.98 when it keeps them, refine_every 0; a random label each: about 0.5)
    halves = torch.where(model.means[:, 0] > 0, 1, 2) * on_object
    for cam in scene.cameras:
        before = render_label_map(model, halves, 3, cam)
        after = render_label_map(cm.model, halves[rows], 3, cam)
        seen = (before > 0) | (after > 0)
        assert (before == after)[seen].mean() > 0.85, cam.name


def _no_pairs():
    from abcgs.evaluation.consistency import Consistency

    return Consistency(float("nan"), float("nan"), 1.0, 0, ())


@pytest.mark.parametrize("background", [OBJECT, FRAME_FILLING], ids=["object", "frame"])
def test_color_only_leaves_every_geometric_parameter_bit_identical(tmp_path, background):
    model, scene = _object_scene(tmp_path, n_views=4, size=(48, 36))
    vgg, groups = _single_transfer(tmp_path, 48)
    out = _run(model, scene, vgg, groups, background, color_only=True)
    for k in ("means", "log_scales", "quats", "opacity_logits"):
        assert torch.equal(getattr(out, k), getattr(model, k)), k
    assert not torch.equal(out.sh0, model.sh0)


# ------------------------------------------------------------------------------------------------ metrics
def test_object_metrics_count_moved_empty_pixels_and_the_silhouette():
    h, w = 20, 30
    ref_a = np.zeros((h, w), np.float32)
    ref_a[5:15, 5:15] = 1.0
    orig = np.zeros((h, w, 3), np.float32)
    orig[5:15, 5:15] = 0.5
    sty = orig.copy()
    sty[0, :10] = 0.3  # 10 empty pixels moved
    sty[8, 8] = 0.9  # an object pixel: not counted as background change
    sty_a = ref_a.copy()
    sty_a[5:15, 14] = 0.0  # one column of the silhouette lost
    s = object_scores([orig], [sty], [ref_a], [sty_a], _no_pairs(), _no_pairs())
    empty = (ref_a < 0.02).sum()
    assert s.background_change == pytest.approx(10 / empty)
    assert s.silhouette_iou == pytest.approx(90 / 100)
    assert s.object_fraction == pytest.approx(100 / (h * w))


def test_a_nerfstudio_capture_with_masks_is_cut_out_by_them_on_its_background(tmp_path, tiny_scene):
    from test_sources import write_nerfstudio

    from abcgs.io.images import load_image, load_labels
    from abcgs.scene.synthetic import cameras_from_json
    from abcgs.sources.nerfstudio import read_nerfstudio_source

    cams = cameras_from_json(json.loads((tiny_scene / "cameras.json").read_text()))[:6]
    folder = tmp_path / "ns"
    folder.mkdir()
    write_nerfstudio(folder, tiny_scene, cams)
    meta = json.loads((folder / "transforms.json").read_text())
    for frame, c in zip(meta["frames"], cams):  # every frame masked: the box and the sphere are the object
        labels = load_labels(tiny_scene / "masks" / c.name)
        save_image(folder / "masks" / c.name, np.where(labels >= 2, 1.0, 0.0).astype(np.float32))
        frame["mask_path"] = f"masks/{c.name}"
    (folder / "transforms.json").write_text(json.dumps(meta))
    bg = Background((0.2, 0.4, 0.6), object=True)
    write_source_model(read_nerfstudio_source(folder), tmp_path / "colmap", ReconstructParams(), background=bg)
    scene = read_scene(tmp_path / "colmap")
    assert scene.alpha_paths is not None
    img, alpha = load_image(scene.image_paths[0]), load_image(scene.alpha_paths[0])[..., 0]
    assert 0.05 < alpha.mean() < 0.95
    np.testing.assert_allclose(img[alpha == 0], np.broadcast_to([0.2, 0.4, 0.6], img[alpha == 0].shape), atol=1 / 255)
