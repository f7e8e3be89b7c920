"""The fused SH colours and the frozen-geometry replay (C++ kernels) against the renderer they stand in for."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from abcgs.gaussians import render
from abcgs.render import cpu as cpu_backend
from abcgs.render.frozen import record_view, render_frozen
from abcgs.render.sh import sh_to_color
from abcgs.splats.cameras import cameras_around
from abcgs.splats.params import SplatViewsParams
from abcgs.stylize import passes, replay, sh_bands
from abcgs.stylize.params import StylizeOptim, StylizeParams

sys.path.insert(0, str(Path(__file__).parent))
from test_splats import make_model  # noqa: E402

pytestmark = pytest.mark.skipif(not cpu_backend.is_available(), reason="the C++ kernels are not built here")


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_fused_sh_colours_match_the_torch_reference_and_their_gradients_pass_gradcheck(degree):
    g = torch.Generator().manual_seed(degree)
    n = 64
    sh0 = torch.randn(n, 1, 3, generator=g, dtype=torch.float64, requires_grad=True)
    shN = torch.randn(n, 15, 3, generator=g, dtype=torch.float64, requires_grad=True)
    means = torch.randn(n, 3, generator=g, dtype=torch.float64, requires_grad=True)
    cam = torch.randn(3, generator=g, dtype=torch.float64)
    mask = torch.rand(n, generator=g) > 0.25
    fused = cpu_backend.sh_colors_cpu(degree, sh0, shN, means, cam, mask)
    ref = sh_to_color(degree, torch.cat([sh0, shN], 1), means, cam) * mask[:, None]
    assert torch.allclose(fused, ref, atol=1e-12)
    assert bool((fused[~mask] == 0).all())
    v = torch.randn(n, 3, generator=g, dtype=torch.float64)
    leaves = (sh0, shN, means)
    for x, a, b in zip(leaves, torch.autograd.grad(fused, leaves, v),
                       torch.autograd.grad(ref, leaves, v, allow_unused=True)):
        assert torch.allclose(a, torch.zeros_like(x) if b is None else b, atol=1e-12)
    assert torch.autograd.gradcheck(lambda a, b, c: cpu_backend.sh_colors_cpu(degree, a, b, c, cam, mask),
                                    (sh0, shN, means))


def test_a_rasterized_sh_scene_through_the_fused_kernel_matches_the_reference_backend():
    model = make_model(400, degree=3, seed=3)
    cam = cameras_around(model, SplatViewsParams(kind="orbit", count=3, width=50, height=38))[0][1]
    leaves = model.as_parameters()
    out = {}
    for backend in ("cpu", "reference"):
        m = model.as_parameters()
        img, alpha, _ = render(m, cam, backend=backend)
        grads = torch.autograd.grad((img * torch.linspace(0, 1, img.numel()).view_as(img)).sum() + alpha.sum(),
                                    (m.sh0, m.shN, m.means))
        out[backend] = (img.detach(), *grads)
    assert leaves.num_gaussians == 400
    for a, b in zip(out["cpu"], out["reference"]):
        assert torch.allclose(a, b, atol=2e-4, rtol=1e-3)


def _view_and_model(seed: int, width: int = 61, height: int = 45):
    model = make_model(1500, degree=3, seed=seed)
    cam = cameras_around(model, SplatViewsParams(kind="orbit", count=4, width=width, height=height))[0][seed % 4]
    view = record_view(model.means, model.quats, model.scales, model.opacities, model.shN, 3,
                       cam.torch_viewmat("cpu"), cam.torch_K("cpu"), width, height)
    return model, cam, view


@pytest.mark.parametrize("seed", [0, 1])
def test_a_replayed_view_equals_the_rasterizer_in_image_alpha_and_dc_gradient(seed):
    model, cam, view = _view_and_model(seed)
    bg = torch.tensor([0.1, 0.5, 0.9])
    m = model.as_parameters()
    img, alpha, _ = render(m, cam, background=bg, backend="cpu")
    img2, alpha2 = render_frozen(view, m.sh0, bg)
    assert torch.allclose(img, img2, atol=1e-5)
    assert torch.equal(alpha, alpha2)  # the same blends and stops: the same transmittance
    w = torch.randn(img.shape, generator=torch.Generator().manual_seed(seed))
    (g_ref,) = torch.autograd.grad((img * w).sum(), m.sh0)
    (g_rep,) = torch.autograd.grad((img2 * w).sum(), m.sh0)
    assert torch.allclose(g_ref, g_rep, atol=1e-4, rtol=1e-4)
    # only the Gaussians the view blends are in its map, and the others get no gradient
    assert view.ids.numel() < model.num_gaussians
    others = torch.ones(model.num_gaussians, dtype=torch.bool)
    others[view.ids] = False
    assert bool((g_rep[others] == 0).all()) and bool((g_ref[others] == 0).all())


def test_a_replayed_view_does_not_depend_on_the_kernel_thread_count():
    model, cam, _ = _view_and_model(2, width=70, height=52)
    out = []
    for threads in (1, 2, 3):
        with cpu_backend.kernel_threads(threads):
            view = record_view(model.means, model.quats, model.scales, model.opacities, model.shN, 3,
                               cam.torch_viewmat("cpu"), cam.torch_K("cpu"), 70, 52)
            sh0 = model.sh0.clone().requires_grad_(True)
            img, _ = render_frozen(view, sh0)
            (g,) = torch.autograd.grad((img * img).sum(), sh0)
        out.append((img.detach(), g))
    for img, g in out[1:]:
        assert torch.equal(img, out[0][0]) and torch.equal(g, out[0][1])


def test_the_colour_pass_replays_its_views_only_when_its_geometry_is_frozen_and_ends_where_rendering_ends(monkeypatch):
    model = make_model(800, degree=3, seed=5)
    model.shN.zero_()  # the colour match zeroes the higher bands
    lrs = {"sh0": 0.01, "quats": 0.0, "shN": 0.0}
    assert replay.can_replay(model, "auto", lrs)
    assert not replay.can_replay(model, "auto", lrs | {"quats": 1e-3})
    assert not replay.can_replay(model, "reference", lrs)
    cams = cameras_around(model, SplatViewsParams(kind="orbit", count=3, width=40, height=30))[0]
    views = replay.ReplayedViews(model.as_parameters(), cams)
    rendered = [views.render(i, None) for i in (0, 1, 0)]
    assert len(views.views) == 2 and views.held == sum(v.nbytes for v in views.views.values())
    assert torch.equal(rendered[0], rendered[2])
    for i, img in zip((0, 1), rendered):
        ref = render(model, cams[i], backend="cpu")[0]
        assert torch.allclose(img.detach(), ref, atol=1e-5)
    # past the budget a view renders as before
    tight = replay.ReplayedViews(model.as_parameters(), cams, budget_bytes=1)
    tight.render(0, None)
    tight.render(1, None)
    assert list(tight.views) == [0]


def test_a_colour_pass_that_replays_its_views_ends_where_one_that_renders_every_step_ends(tmp_path, monkeypatch):
    from test_objects import _object_scene, _single_transfer  # noqa: E402

    from abcgs.stylize.loop import stylize
    from abcgs.types import FRAME_FILLING

    model, scene = _object_scene(tmp_path, n_views=3, size=(40, 30))
    vgg, groups = _single_transfer(tmp_path, 32)
    labels = torch.zeros(model.num_gaussians, dtype=torch.long)
    view_labels = [np.zeros((c.height, c.width), np.int64) for c in scene.cameras]
    sp = StylizeParams(optim=StylizeOptim(iterations=2, color_pass_iterations=5, color_pass_rotations=False),
                       layers=["relu3_1"], style_height=32)
    calls = []
    real = replay.ReplayedViews.render

    def counted(self, i, background):
        calls.append(i)
        return real(self, i, background)

    monkeypatch.setattr(replay.ReplayedViews, "render", counted)
    replayed = stylize(model, scene.cameras, view_labels, labels, groups, vgg, sp, depth_model=model, progress=False,
                       background=FRAME_FILLING).model
    assert len(calls) == 5
    monkeypatch.setattr(passes, "can_replay", lambda *a: False)
    rendered = stylize(model, scene.cameras, view_labels, labels, groups, vgg, sp, depth_model=model, progress=False,
                       background=FRAME_FILLING).model
    assert len(calls) == 5
    assert torch.allclose(replayed.sh0, rendered.sh0, atol=1e-4)
    for k in ("means", "quats", "log_scales", "opacity_logits"):
        assert torch.equal(getattr(replayed, k), getattr(rendered, k)), k


def test_a_pass_with_zero_untrained_higher_bands_renders_at_degree_0_with_the_same_image_and_gradients():
    """``higher_sh: zero``: the passes render at degree 0 (:func:`sh_bands.render_sh_degree`) and get the image, the
    depth and the gradients of the degree-3 render of the zeroed bands, bit for bit; trained or nonzero bands keep
    every stored band."""
    model = make_model(1500, degree=3, seed=7)
    model.shN = torch.zeros_like(model.shN)
    cam = cameras_around(model, SplatViewsParams(kind="orbit", count=3, width=48, height=36))[0][1]
    assert sh_bands.render_sh_degree(model, {"sh0": 1e-3, "shN": 0.0}) == 0
    outs = []
    for degree in (None, 0):
        m = model.as_parameters(trainable=["means", "sh0", "quats", "log_scales", "opacity_logits"])
        img, alpha, meta = render(m, [cam], sh_degree=degree, render_mode="RGB+D")
        (img.square().sum() + meta.depth.sum() + alpha.sum()).backward()
        outs.append([img.detach(), alpha.detach(), meta.depth.detach()]
                    + [getattr(m, k).grad for k in ("means", "sh0", "quats", "log_scales", "opacity_logits")])
    for a, b in zip(*outs):
        assert torch.equal(a, b)
    assert sh_bands.render_sh_degree(model, {"shN": 1e-4}) is None  # trained bands
    model.shN[0, 0, 0] = 0.1
    assert sh_bands.render_sh_degree(model, {"shN": 0.0}) is None  # a band that is not zero
