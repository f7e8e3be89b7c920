"""accumulate_weights (ABC-GS Eq. 2): w_ij = Σ_p α_i(p) T_i(p) M_j(p), against a naive per-pixel loop."""

from __future__ import annotations

import pytest
import torch
from render_scenes import random_scene

from abcgs.render import accumulate_weights, project_gaussians, rasterize
from abcgs.render.cpu import is_available
from abcgs.render.projection import ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_EPS

BACKENDS = ["reference", pytest.param("cpu", marks=pytest.mark.skipif(not is_available(), reason="C++ backend not built"))]
F64 = torch.float64


def _weights(scene, pixel_weights, backend):
    s = scene
    return accumulate_weights(s.means, s.quats, s.scales, s.opacities, s.viewmat, s.K, pixel_weights, backend=backend)


def naive_blend_weights(scene):
    """(N, H, W) blending weights α_i(p)·T_i(p), one pixel and one Gaussian at a time in plain Python,
    following the rule in reference.py's docstring. Also counts clamps and early stops (coverage)."""
    s = scene
    proj = project_gaussians(s.means, s.quats, s.scales, s.opacities, s.viewmat, s.K, s.width, s.height)
    order = [i for i in sorted(range(scene.n), key=lambda i: float(proj.depths[i])) if bool(proj.visible[i])]
    m, con, o = proj.means2d.tolist(), proj.conics.tolist(), scene.opacities.tolist()
    w = torch.zeros(scene.n, scene.height, scene.width, dtype=F64)
    clamps = stops = 0
    for y in range(scene.height):
        for x in range(scene.width):
            T = 1.0
            for i in order:
                dx, dy = x + 0.5 - m[i][0], y + 0.5 - m[i][1]
                sigma = 0.5 * (con[i][0] * dx * dx + con[i][2] * dy * dy) + con[i][1] * dx * dy
                if sigma < 0:
                    continue
                raw = o[i] * torch.exp(torch.tensor(-sigma, dtype=F64)).item()
                alpha = min(MAX_ALPHA, raw)
                clamps += raw > MAX_ALPHA
                if alpha < ALPHA_THRESHOLD:
                    continue
                if T * (1 - alpha) <= TRANSMITTANCE_EPS:
                    stops += 1
                    break
                w[i, y, x] = alpha * T
                T *= 1 - alpha
    return w, clamps, stops


@pytest.fixture(scope="module")
def dense_scene():
    """Tiny, overlapping, near-opaque Gaussians, so that the clamp and the early stop both occur."""
    scene = random_scene(10, 14, 11, F64, 9, scale_range=(0.6, 1.5), opacity_range=(0.97, 1.0), margin=-0.2)
    w, clamps, stops = naive_blend_weights(scene)
    assert clamps > 0 and stops > 0, (clamps, stops)
    return scene, w


@pytest.fixture(scope="module")
def sparse_scene():
    scene = random_scene(8, 14, 11, F64, 4, scale_range=(0.15, 0.5), opacity_range=(0.2, 0.8))
    return scene, naive_blend_weights(scene)[0]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("which", ["dense_scene", "sparse_scene"])
def test_accumulate_weights_matches_naive_loop(backend, which, request):
    scene, w_naive = request.getfixturevalue(which)
    g = torch.Generator().manual_seed(0)
    labels = torch.randint(0, 3, (scene.height, scene.width), generator=g)
    one_hot = torch.nn.functional.one_hot(labels, 3).to(F64)
    soft = torch.rand(scene.height, scene.width, 2, generator=g, dtype=F64)
    masks = torch.cat([one_hot, soft], dim=-1)  # 3 one-hot content masks + 2 soft weight maps
    w = _weights(scene, masks, backend)
    expected = torch.einsum("nhw,hwj->nj", w_naive, masks)
    assert w.shape == (scene.n, 5)
    torch.testing.assert_close(w, expected, atol=1e-12, rtol=1e-10)
    assert (w >= 0).all()
    # one-hot labels partition the pixels: the per-label weights add up to the all-ones weight
    torch.testing.assert_close(w[:, :3].sum(1), w_naive.sum((1, 2)), atol=1e-12, rtol=1e-10)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
def test_all_ones_weights_sum_to_alpha(backend, dtype):
    scene = random_scene(300, 48, 36, dtype, 6, scale_range=(0.03, 0.2), opacity_range=(0.3, 1.0))
    ones = torch.ones(36, 48, 1, dtype=dtype)
    w = _weights(scene, ones, backend)
    _, alpha, _ = rasterize(*scene.args(), backend=backend)
    tol = 1e-3 if dtype == torch.float32 else 1e-9
    torch.testing.assert_close(w.sum(), alpha.sum(), atol=0, rtol=tol)
    assert w.shape == (scene.n, 1) and (w >= 0).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_accumulate_weights_leaves_inputs_alone(backend):
    """No gradient leaks into the caller's parameters, and it works without grad mode."""
    scene = random_scene(20, 16, 12, torch.float32, 1).leaves()
    masks = torch.ones(12, 16, 2)
    with torch.no_grad():
        w = _weights(scene, masks, backend)
    assert not w.requires_grad
    assert all(getattr(scene, k).grad is None for k in ("means", "quats", "scales", "opacities"))
    torch.testing.assert_close(w[:, 0], w[:, 1], atol=0, rtol=0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_accumulate_weights_empty_view(backend):
    """All Gaussians culled (behind the camera): zero weights, no exception."""
    scene = random_scene(5, 16, 12, torch.float32, 2)
    scene.viewmat = scene.viewmat.clone()
    scene.viewmat[:3, :3] = -scene.viewmat[:3, :3]  # turn the camera around
    scene.viewmat[:3, 3] = -scene.viewmat[:3, 3]
    w = _weights(scene, torch.ones(12, 16, 3), backend)
    assert torch.equal(w, torch.zeros(5, 3))
