"""float64 finite-difference gradient checks of the rasterizer, every input group, both CPU backends.

Each check renders a tiny scene (≤ 8 Gaussians, 12×10 px, 8-px tiles so Gaussians straddle tile borders)
and compares autograd with central differences (step 1e-6) of random weighted sums of each output
(image, alpha, depth) with respect to every element of every input.

Why these are stable: the blending rule has discontinuities (alpha < 1/255 skip, the 1e-4 transmittance
stop) and a kink (the 0.99 alpha clamp). A 1e-6 step moves log(alpha) by ≲ 1e-5 here, so before each
check we assert with :func:`render_scenes.blend_margins` that every (pixel, Gaussian) pair is at least
1e-3 (relative) away from all three, which a perturbation cannot cross. Away from them the renderer is
smooth and central differences agree with autograd to ~1e-9 (tolerance: 1e-6 abs + 1e-5 rel).
"""

from __future__ import annotations

import pytest
import torch
from render_scenes import blend_margins, finite_difference_check, random_scene

from abcgs.render import rasterize
from abcgs.render.cpu import is_available, rasterize_batch_cpu
from abcgs.render.projection import project_gaussians
from abcgs.render.sh import sh_to_color

F64 = torch.float64
W, H, TILE = 12, 10, 8
MIN_MARGIN = 1e-3
# The cpu backend's fused C++ projection treats the camera as constant (no viewmat gradient), so the
# camera-pose gradient is only checked on the reference backend.
CAMERA_GRAD_BACKENDS = ("reference",)
BACKENDS = ["reference", pytest.param("cpu", marks=pytest.mark.skipif(not is_available(), reason="C++ backend not built"))]


def _check_margins(scene, *, clamped=False, stopped=False):
    m = blend_margins(scene)
    assert min(m["threshold"], m["clamp"], m["stop"]) > MIN_MARGIN, f"scene too close to a blending threshold: {m}"
    if clamped:
        assert m["clamped"] > 0, f"scene does not exercise the 0.99 clamp: {m}"
    if stopped:
        assert m["stopped"] > 0, f"scene does not exercise the transmittance stop: {m}"
    return m


def _weights(seed, channels):
    g = torch.Generator().manual_seed(1000 + seed)
    return [torch.randn(H, W, c, generator=g, dtype=F64) for c in (channels, 1, 1)]


def _render_losses(scene, backend, weights, **kw):
    """f(**inputs) -> [image loss, alpha loss, depth loss] for finite_difference_check."""

    def f(means, quats, scales, opacities, colors, background, viewmat=scene.viewmat):
        image, alpha, meta = rasterize(
            means, quats, scales, opacities, colors, viewmat, scene.K, W, H, background=background,
            tile_size=TILE, backend=backend, **{"render_mode": "RGB+D", **kw},
        )
        outs = (image, alpha, meta.depth)
        return torch.stack([(o * w).sum() for o, w in zip(outs, weights)])

    return f


def _inputs(scene, background, backend):
    inputs = dict(
        means=scene.means, quats=scene.quats, scales=scene.scales, opacities=scene.opacities,
        colors=scene.colors, background=background,
    )
    if backend in CAMERA_GRAD_BACKENDS:
        inputs["viewmat"] = scene.viewmat
    return inputs


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("seed", [0, 1])
def test_fd_all_inputs(backend, seed):
    """means, quats, scales, opacities, colours, background (viewmat: reference) × image, alpha, depth."""
    scene = random_scene(6, W, H, F64, seed, scale_range=(0.15, 0.5), opacity_range=(0.2, 0.7))
    _check_margins(scene)
    bg = torch.tensor([0.2, 0.5, 0.9], dtype=F64)
    finite_difference_check(_render_losses(scene, backend, _weights(seed, 3)), _inputs(scene, bg, backend))


@pytest.mark.parametrize("backend", BACKENDS)
def test_fd_clamp_and_stop(backend):
    """Near-opaque overlapping Gaussians: the 0.99 clamp and the early transmittance stop are active."""
    scene = random_scene(8, W, H, F64, 18, scale_range=(0.6, 1.5), opacity_range=(0.97, 1.0), margin=-0.2)
    _check_margins(scene, clamped=True, stopped=True)
    bg = torch.tensor([0.7, 0.1, 0.3], dtype=F64)
    finite_difference_check(_render_losses(scene, backend, _weights(5, 3)), _inputs(scene, bg, backend))


@pytest.mark.parametrize("backend", BACKENDS)
def test_fd_normalized_depth_many_channels(backend):
    """The expected depth (RGB+ED) divides by alpha inside the graph; 5 colour channels."""
    scene = random_scene(5, W, H, F64, 2, scale_range=(0.15, 0.5), opacity_range=(0.2, 0.7), channels=5)
    _check_margins(scene)
    finite_difference_check(
        _render_losses(scene, backend, _weights(2, 5), render_mode="RGB+ED"),
        _inputs(scene, torch.zeros(5, dtype=F64), backend),
    )


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("degree", [1, 2, 3])
def test_fd_sh_coefficients(backend, degree):
    """SH coefficients (N, K, 3) and means (which set the view direction), sh_degree 1..3."""
    scene = random_scene(4, W, H, F64, 10 + degree, scale_range=(0.2, 0.6), opacity_range=(0.2, 0.7), sh_degree=degree)
    _check_margins(scene)
    R, t = scene.viewmat[:3, :3], scene.viewmat[:3, 3]
    rgb = sh_to_color(degree, scene.colors, scene.means, -R.T @ t)
    assert rgb.min() > 0.02, "SH colours too close to the clamp at 0"
    weights = _weights(degree, 3)

    def f(means, colors, viewmat=scene.viewmat):
        image, alpha, _ = rasterize(
            means, scene.quats, scene.scales, scene.opacities, colors, viewmat, scene.K, W, H,
            sh_degree=degree, tile_size=TILE, backend=backend,
        )
        return torch.stack([(image * weights[0]).sum(), (alpha * weights[1]).sum()])

    inputs = dict(means=scene.means, colors=scene.colors)
    if backend in CAMERA_GRAD_BACKENDS:
        inputs["viewmat"] = scene.viewmat
    finite_difference_check(f, inputs)


@pytest.mark.skipif(not is_available(), reason="C++ backend not built")
def test_gradcheck_cpu_kernel_full_jacobian():
    """torch.autograd.gradcheck (full Jacobian, not a projection) of the C++ forward/backward pair
    in screen space: means2d, conics, colours, opacities → image and alpha."""
    scene = random_scene(5, W, H, F64, 3, scale_range=(0.15, 0.5), opacity_range=(0.3, 0.8))
    _check_margins(scene)
    proj = project_gaussians(scene.means, scene.quats, scene.scales, scene.opacities, scene.viewmat, scene.K, W, H)
    assert bool(proj.visible.all())

    def kernel(means2d, conics, colors, opacities):  # one view: a batch of one
        image, alpha = rasterize_batch_cpu(means2d[None], conics[None], colors, opacities, proj.depths[None],
                                           proj.extents[None], W, H, tile_size=TILE)
        return image[0], alpha[0]

    raw = (proj.means2d, proj.conics, scene.colors, scene.opacities)
    inputs = tuple(t.detach().clone().requires_grad_(True) for t in raw)
    assert torch.autograd.gradcheck(kernel, inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


@pytest.mark.skipif(not is_available(), reason="C++ backend not built")
def test_cpu_viewmat_gradient_matches_reference():
    """With backend='cpu' a viewmat that requires grad takes the autograd projection, so camera
    optimisation gets the full pose gradient (the fused C++ projection treats the camera as constant)."""
    scene = random_scene(6, W, H, F64, 0, scale_range=(0.15, 0.5), opacity_range=(0.2, 0.7))
    grads = {}
    for backend in ("reference", "cpu"):
        v = scene.viewmat.clone().requires_grad_(True)
        image, _, _ = rasterize(*scene.args()[:5], v, scene.K, W, H, tile_size=TILE, backend=backend)
        (grads[backend],) = torch.autograd.grad(image.sum(), v, allow_unused=True)
    assert grads["cpu"] is not None
    torch.testing.assert_close(grads["cpu"], grads["reference"], atol=1e-8, rtol=1e-8)
