"""Degenerate inputs (finite outputs and gradients on both backends), empty scenes, expected depth and
background compositing."""

from __future__ import annotations

import pytest
import torch
from render_scenes import GRAD_FIELDS

from abcgs.render import rasterize
from abcgs.render.cpu import is_available

BACKENDS = ["reference", pytest.param("cpu", marks=pytest.mark.skipif(not is_available(), reason="C++ backend not built"))]
W, H = 16, 12


def _camera(dtype, width=W, height=H, f=16.0):
    """Identity pose (world = camera, OpenCV axes: +z forward), principal point at the image centre."""
    K = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=dtype)
    return torch.eye(4, dtype=dtype), K


def _gaussians(means, dtype, *, scale=0.3, opacity=0.8, quats=None, scales=None, opacities=None, channels=3):
    means = torch.as_tensor(means, dtype=dtype).reshape(-1, 3)
    n = means.shape[0]
    g = torch.Generator().manual_seed(n)
    if quats is None:
        quats = torch.randn(n, 4, generator=g, dtype=torch.float64)
    if scales is None:
        scales = scale * (0.5 + torch.rand(n, 3, generator=g, dtype=torch.float64))
    if opacities is None:
        opacities = torch.full((n,), opacity, dtype=torch.float64)
    colors = torch.rand(n, channels, generator=g, dtype=torch.float64)
    def as_t(t, *shape):
        return torch.as_tensor(t).to(dtype).reshape(n, *shape)

    return dict(means=means, quats=as_t(quats, 4), scales=as_t(scales, 3), opacities=as_t(opacities), colors=colors.to(dtype))


NORMAL = [[0.0, 0.0, 3.0], [0.4, -0.2, 2.5], [-0.5, 0.3, 4.0]]


def _case(name, dtype):
    """(gaussian dict, width, height) for a named degenerate case."""
    w, h = W, H
    if name == "behind_camera":
        g = _gaussians([[0, 0, -2.0], [0.1, 0, -0.5], [0, 0, -1e-3]] + NORMAL, dtype)
    elif name == "camera_plane":  # exactly at z=0, between 0 and near, at near, just past near
        near_plane = [[0.0, 0.0, 0.0], [0.1, 0.0, 0.005], [0.0, 0.0, 0.01], [0.001, 0.0, 0.0101], [0.5, 0.5, 0.02]]
        g = _gaussians(near_plane + NORMAL, dtype)
    elif name == "zero_opacity":
        g = _gaussians(NORMAL + NORMAL, dtype, opacities=[0.0, 0.0, 0.0, 1e-3, 0.0039, 1.0 / 255.0])
    elif name == "empty":
        g = _gaussians(torch.zeros(0, 3), dtype)
    elif name == "one_pixel":
        w = h = 1
        g = _gaussians(NORMAL, dtype)
    elif name == "huge":  # covers the screen and far beyond; one is centred off-screen
        g = _gaussians([[0, 0, 3.0], [50.0, 0, 3.0]] + NORMAL, dtype, scales=[[1e3] * 3, [1e2] * 3] + [[0.3] * 3] * 3)
    elif name == "zero_quaternion":
        g = _gaussians(NORMAL, dtype, quats=torch.zeros(3, 4))
    elif name == "zero_scale":
        g = _gaussians(NORMAL + NORMAL[:1], dtype, scales=[[0.0] * 3, [0.0, 0.3, 0.2], [0.0, 0.0, 0.5], [1e-30] * 3])
    elif name == "far_off_screen":
        g = _gaussians(
            [[1e4, 0, 3.0], [-1e8, 5e7, 3.0], [0, 1e6, 2.0], [3.0, 3.0, 1e12], [0, 0, 2e10]] + NORMAL, dtype
        )
    elif name == "identical_depth":
        same_z = [[0.0, 0.0, 3.0], [0.1, 0.05, 3.0], [-0.1, 0.0, 3.0], [0.0, 0.0, 3.0]]
        g = _gaussians(same_z, dtype, scales=torch.full((4, 3), 0.3))
    elif name == "opaque_stack":  # clamp at 0.99 and the transmittance stop
        g = _gaussians([[0.0, 0.0, 2.0 + 0.2 * i] for i in range(6)], dtype, opacity=1.0, scale=0.5)
    else:
        raise KeyError(name)
    return g, w, h


CASES = [
    "behind_camera", "camera_plane", "zero_opacity", "empty", "one_pixel", "huge", "zero_quaternion",
    "zero_scale", "far_off_screen", "identical_depth", "opaque_stack",
]


def _render(g, width, height, backend, dtype, **kw):
    viewmat, K = _camera(dtype, width, height, f=16.0 * width / W)
    leaves = {k: v.detach().clone().requires_grad_(True) for k, v in g.items()}
    bg = torch.tensor([0.1, 0.6, 0.3], dtype=dtype, requires_grad=True)
    image, alpha, meta = rasterize(
        leaves["means"], leaves["quats"], leaves["scales"], leaves["opacities"], leaves["colors"], viewmat, K, width, height,
        background=bg, render_mode="RGB+D", backend=backend, **kw,
    )
    meta.means2d.retain_grad()
    wts = torch.Generator().manual_seed(0)
    loss = sum(
        (o * torch.randn(o.shape, generator=wts, dtype=torch.float64).to(dtype)).sum() for o in (image, alpha, meta.depth)
    )
    loss.backward()
    grads = {k: leaves[k].grad for k in GRAD_FIELDS}
    grads["background"] = bg.grad
    return image.detach(), alpha.detach(), meta, grads


def _case_specific_checks(case, alpha, meta):
    """Make sure each case builds the situation it is named after."""
    vis = meta.visible
    if case == "behind_camera":
        assert not vis[:3].any() and vis[3:].all()
    elif case == "camera_plane":
        assert not vis[:3].any() and vis[3] and vis[5:].all()  # z=0, z<near, z=near culled; z>near kept
    elif case == "zero_opacity":
        assert not vis[:5].any()  # opacity < 1/255 can never reach the alpha threshold
    elif case == "huge":
        assert vis[:2].all() and alpha.min() > 0.5  # covers every pixel
    elif case == "far_off_screen":
        assert not vis[:5].any() and vis[5:].all()
    elif case in ("zero_quaternion", "zero_scale", "identical_depth", "one_pixel", "opaque_stack"):
        assert vis.all()
    if case == "opaque_stack":
        assert alpha.max() > 0.999


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
@pytest.mark.parametrize("case", CASES)
def test_degenerate_inputs_finite(case, dtype):
    g, w, h = _case(case, dtype)
    results = {}
    for backend in ("reference", "cpu") if is_available() else ("reference",):
        image, alpha, meta, grads = _render(g, w, h, backend, dtype)
        assert image.shape == (h, w, 3) and alpha.shape == (h, w, 1) and meta.depth.shape == (h, w, 1)
        for name, t in (("image", image), ("alpha", alpha), ("depth", meta.depth), ("means2d", meta.means2d)):
            assert torch.isfinite(t).all(), f"{backend}: non-finite {name}"
        assert (alpha >= 0).all() and (alpha <= 1).all()
        for k, v in grads.items():
            assert v is not None, f"{backend}: no gradient for {k} (the output is not attached to it)"
            assert v.shape == (g[k].shape if k in g else (3,)), k
            assert torch.isfinite(v).all(), f"{backend}: non-finite d/d{k}: {v}"
        assert meta.means2d.grad is not None and torch.isfinite(meta.means2d.grad).all()
        assert (meta.radii[~meta.visible] == 0).all()
        _case_specific_checks(case, alpha, meta)
        results[backend] = (image, alpha, meta)
    if len(results) == 2:
        tol = 1e-5 if dtype == torch.float32 else 1e-10
        torch.testing.assert_close(results["cpu"][0], results["reference"][0], atol=tol, rtol=0)
        torch.testing.assert_close(results["cpu"][1], results["reference"][1], atol=tol, rtol=0)
        torch.testing.assert_close(results["cpu"][2].depth, results["reference"][2].depth, atol=tol * 10, rtol=0)
        assert torch.equal(results["cpu"][2].visible, results["reference"][2].visible)


@pytest.mark.parametrize("backend", BACKENDS)
def test_culled_gaussians_do_not_change_the_image(backend):
    """Adding Gaussians behind the camera, at the camera plane, off-screen, beyond `far` or with zero opacity
    leaves the render (and the normal Gaussians' gradients) unchanged; they get zero gradients."""
    dtype = torch.float64
    normal = _gaussians(NORMAL, dtype)
    junk = _gaussians([[0, 0, -2.0], [0, 0, 0.0], [0, 0, 0.005], [1e4, 0, 3.0], [0, 0, 2e10], [0.1, 0.1, 3.0]], dtype,
                      opacities=[0.8, 0.8, 0.8, 0.8, 0.8, 0.0])
    both = {k: torch.cat([normal[k], junk[k]]) for k in normal}
    img_a, alpha_a, meta_a, grads_a = _render(normal, W, H, backend, dtype)
    img_b, alpha_b, meta_b, grads_b = _render(both, W, H, backend, dtype)
    torch.testing.assert_close(img_b, img_a, atol=1e-12, rtol=0)
    torch.testing.assert_close(alpha_b, alpha_a, atol=1e-12, rtol=0)
    assert not meta_b.visible[3:].any() and meta_b.visible[:3].all()
    for k in GRAD_FIELDS:
        torch.testing.assert_close(grads_b[k][:3], grads_a[k], atol=1e-10, rtol=1e-10)
        assert (grads_b[k][3:] == 0).all(), k


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
def test_empty_scene_is_background(backend, dtype):
    g, w, h = _case("empty", dtype)
    image, alpha, meta, grads = _render(g, w, h, backend, dtype)
    bg = torch.tensor([0.1, 0.6, 0.3], dtype=dtype)
    assert torch.equal(image, bg.expand(h, w, 3))
    assert torch.equal(alpha, torch.zeros(h, w, 1, dtype=dtype))
    assert torch.equal(meta.depth, torch.zeros(h, w, 1, dtype=dtype))
    assert meta.means2d.shape == (0, 2) and meta.radii.shape[0] == 0
    # without background: zeros
    viewmat, K = _camera(dtype)
    args = (g["means"], g["quats"], g["scales"], g["opacities"], g["colors"], viewmat, K, w, h)
    image, alpha, _ = rasterize(*args, backend=backend)
    assert torch.equal(image, torch.zeros(h, w, 3, dtype=dtype))


@pytest.mark.parametrize("backend", BACKENDS)
def test_expected_depth_single_gaussian(backend):
    """One Gaussian facing the camera at z = d: depth = alpha·d (RGB+D); RGB+ED gives d where alpha > 0."""
    dtype, d = torch.float64, 3.7
    viewmat, K = _camera(dtype)
    means = torch.tensor([[0.1, -0.05, d]], dtype=dtype)
    args = (means, torch.tensor([[1.0, 0, 0, 0]], dtype=dtype), torch.tensor([[0.25, 0.15, 1e-3]], dtype=dtype),
            torch.tensor([0.9], dtype=dtype), torch.ones(1, 3, dtype=dtype), viewmat, K, W, H)
    _, alpha, meta = rasterize(*args, render_mode="RGB+D", backend=backend)
    assert alpha.max() > 0.5 and (alpha == 0).any(), "test scene should have covered and empty pixels"
    torch.testing.assert_close(meta.depth, alpha * d, atol=1e-12, rtol=1e-12)
    _, alpha_n, meta_n = rasterize(*args, render_mode="RGB+ED", backend=backend)
    torch.testing.assert_close(alpha_n, alpha)
    covered = alpha[..., 0] > 0
    torch.testing.assert_close(meta_n.depth[covered], torch.full_like(meta_n.depth[covered], d), atol=1e-9, rtol=0)
    assert (meta_n.depth[~covered] == 0).all()
    assert meta.depths.tolist() == pytest.approx([d])


@pytest.mark.parametrize("backend", BACKENDS)
def test_expected_depth_two_layers_front_to_back(backend):
    """Depth = a1·d1 + (1 - a1)·a2·d2 with the nearer Gaussian first, whatever the input order."""
    dtype, d1, d2 = torch.float64, 2.0, 5.0
    viewmat, K = _camera(dtype)
    q = torch.tensor([[1.0, 0, 0, 0]], dtype=dtype)

    def one(z, s, o):
        t = lambda v: torch.tensor(v, dtype=dtype)  # noqa: E731
        return t([[0.0, 0.0, z]]), t([[s, s, s]]), t([o])

    (m1, s1, o1), (m2, s2, o2) = one(d1, 0.2, 0.6), one(d2, 0.6, 0.7)

    def render(m, s, o):
        n = m.shape[0]
        ones = torch.ones(n, 1, dtype=dtype)
        _, a, meta = rasterize(m, q.expand(n, 4), s, o, ones, viewmat, K, W, H, render_mode="RGB+D", backend=backend)
        return a, meta.depth

    a1, _ = render(m1, s1, o1)
    a2, _ = render(m2, s2, o2)
    alpha, depth = render(torch.cat([m2, m1]), torch.cat([s2, s1]), torch.cat([o2, o1]))  # far one listed first
    torch.testing.assert_close(depth, a1 * d1 + (1 - a1) * a2 * d2, atol=1e-12, rtol=1e-12)
    torch.testing.assert_close(alpha, 1 - (1 - a1) * (1 - a2), atol=1e-12, rtol=1e-12)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("channels", [3, 7])
def test_background_compositing(backend, channels):
    dtype = torch.float32
    g = _gaussians(NORMAL + [[0.3, 0.3, 3.5]], dtype, channels=channels)
    viewmat, K = _camera(dtype)
    args = (g["means"], g["quats"], g["scales"], g["opacities"], g["colors"], viewmat, K, W, H)
    bg = torch.linspace(0.2, 0.9, channels)
    image, alpha, _ = rasterize(*args, backend=backend)
    image_bg, alpha_bg, _ = rasterize(*args, background=bg, backend=backend)
    assert (alpha < 0.01).any() and (alpha > 0.3).any()
    torch.testing.assert_close(alpha_bg, alpha, atol=0, rtol=0)
    torch.testing.assert_close(image_bg, image + (1 - alpha) * bg, atol=1e-6, rtol=0)
