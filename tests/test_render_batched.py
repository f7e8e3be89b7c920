"""Batched cameras: ``rasterize`` with ``viewmats`` ``(C, 4, 4)`` and ``Ks`` ``(C, 3, 3)`` against per-view renders.

On the CPU kernels every view of a batch is the per-view render bit for bit (image, alpha, depth, the projection
in ``meta``), and so are the per-view gradients (``meta.means2d``'s). The gradients of the per-Gaussian inputs are
the sums over the views: the C++ backward adds the views' gradients in camera order, ``(g_0 + g_1) + g_2``, so
they equal, exactly, the per-view gradients added in that order. (One ``backward()`` through a Python loop of
per-view renders adds them in autograd's order instead, which float rounding tells apart: the tests add the
per-view gradients explicitly.) A finite-difference check and the reference backend cover the batched path's
values; the gsplat path is checked on gsplat's PyTorch twin (``tests/gsplat_torch.py``).
"""

from __future__ import annotations

import pytest
import torch
from render_scenes import blend_margins, finite_difference_check, look_rotation, random_scene

from abcgs.cameras import Camera
from abcgs.gaussians import GaussianModel, render, render_each
from abcgs.render import rasterize
from abcgs.render.cpu import is_available

needs_cpu = pytest.mark.skipif(not is_available(), reason="C++ backend not built")
C = 3


def _cameras(scene, n: int, seed: int = 0, max_angle: float = 0.08) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` cameras near the scene's: view 0 is the scene's own, the others turned by up to ``max_angle`` rad,
    moved a little and with another focal length. Returns viewmats ``(n, 4, 4)`` and Ks ``(n, 3, 3)``."""
    g = torch.Generator().manual_seed(100 + seed)
    vms, ks = [scene.viewmat], [scene.K]
    for _ in range(n - 1):
        delta = torch.eye(4, dtype=torch.float64)
        delta[:3, :3] = look_rotation(g, max_angle, torch.float64)
        delta[:3, 3] = 0.1 * torch.randn(3, generator=g, dtype=torch.float64)
        vms.append((delta @ scene.viewmat.double()).to(scene.viewmat.dtype))
        k = scene.K.clone()
        k[0, 0] *= 0.9 + 0.2 * float(torch.rand((), generator=g))
        k[1, 1] = k[0, 0]
        ks.append(k)
    return torch.stack(vms), torch.stack(ks)


def _setup(sh: bool, seed: int = 0, dtype=torch.float32, n: int = 400, width: int = 64, height: int = 48):
    """A scene with plain colours ``(N, 3)`` or degree-3 SH in ``(sh0, shN)`` blocks, as leaves; its C cameras."""
    scene = random_scene(n, width, height, dtype, seed, sh_degree=3 if sh else None, margin=0.3)
    viewmats, Ks = _cameras(scene, C, seed)
    leaves = {k: getattr(scene, k).detach().clone().requires_grad_(True)
              for k in ("means", "quats", "scales", "opacities")}
    if sh:
        leaves["sh0"] = scene.colors[:, :1].detach().clone().requires_grad_(True)
        leaves["shN"] = scene.colors[:, 1:].detach().clone().requires_grad_(True)
    else:
        leaves["colors"] = scene.colors.detach().clone().requires_grad_(True)
    return scene, viewmats, Ks, leaves


def _args(leaves):
    colors = (leaves["sh0"], leaves["shN"]) if "sh0" in leaves else leaves["colors"]
    return leaves["means"], leaves["quats"], leaves["scales"], leaves["opacities"], colors


def _weights(seed: int, h: int, w: int, dtype) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(C, h, w, c, generator=g).to(dtype) for c in (3, 1, 1)]


def _loss(outs, weights):
    return sum((o * w).sum() for o, w in zip(outs, weights) if o is not None)


def _batched(scene, viewmats, Ks, leaves, weights, backend, **kw):
    sh = "sh0" in leaves
    image, alpha, meta = rasterize(*_args(leaves), viewmats, Ks, scene.width, scene.height,
                                   sh_degree=3 if sh else None, backend=backend, **kw)
    meta.means2d.retain_grad()
    grads = torch.autograd.grad(_loss((image, alpha, meta.depth), weights), list(leaves.values()), retain_graph=True)
    _loss((image, alpha, meta.depth), weights).backward(inputs=[meta.means2d])
    return (image, alpha, meta), dict(zip(leaves, grads))


def _per_view(scene, viewmats, Ks, leaves, weights, backend, background=None, **kw):
    """Per-view renders stacked, and the per-view gradients added in camera order."""
    sh = "sh0" in leaves
    views, total = [], None
    for c in range(viewmats.shape[0]):
        bg = background[c] if background is not None and background.dim() == 2 else background
        image, alpha, meta = rasterize(*_args(leaves), viewmats[c], Ks[c], scene.width, scene.height,
                                       sh_degree=3 if sh else None, background=bg, backend=backend, **kw)
        meta.means2d.retain_grad()
        loss = _loss((image, alpha, meta.depth), [w[c] for w in weights])
        grads = torch.autograd.grad(loss, list(leaves.values()), retain_graph=True)
        loss.backward(inputs=[meta.means2d])
        total = list(grads) if total is None else [t + g for t, g in zip(total, grads)]
        views.append((image, alpha, meta))
    return views, dict(zip(leaves, total))


CASES = {
    "rgb-depth-background": (False, {"render_mode": "RGB+D", "background": torch.tensor([0.2, 0.5, 0.9])}),
    "sh3-blocks-expected-depth-view-backgrounds": (
        True, {"render_mode": "RGB+ED", "background": torch.tensor([[0.1, 0.2, 0.3], [1.0, 1.0, 1.0], [0.0, 0.5, 0.0]])},
    ),
    "sh3-blocks-rgb": (True, {"render_mode": "RGB"}),
}


@needs_cpu
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("case", list(CASES))
def test_batched_cpu_equals_per_view_exactly(case, dtype):
    """C = 3 cameras of one size in one call: every output and every gradient equals the per-view path's exactly."""
    sh, kw = CASES[case]
    scene, viewmats, Ks, leaves = _setup(sh, seed=1, dtype=dtype)
    viewmats, Ks = viewmats.to(dtype), Ks.to(dtype)
    kw = {k: v.to(dtype) if isinstance(v, torch.Tensor) else v for k, v in kw.items()}
    weights = _weights(7, scene.height, scene.width, dtype)
    (image, alpha, meta), grads = _batched(scene, viewmats, Ks, leaves, weights, "cpu", **kw)
    views, expected = _per_view(scene, viewmats, Ks, leaves, weights, "cpu", **kw)

    assert image.shape == (C, scene.height, scene.width, 3) and alpha.shape == (C, scene.height, scene.width, 1)
    assert meta.means2d.shape == (C, scene.n, 2) and meta.backend == "cpu"
    for c, (img_c, alpha_c, meta_c) in enumerate(views):
        assert torch.equal(image[c], img_c) and torch.equal(alpha[c], alpha_c)
        if kw["render_mode"] != "RGB":
            assert torch.equal(meta.depth[c], meta_c.depth)
        else:
            assert meta.depth is None
        for field in ("means2d", "radii", "depths", "visible"):
            assert torch.equal(getattr(meta, field)[c], getattr(meta_c, field)), field
        assert torch.equal(meta.means2d.grad[c], meta_c.means2d.grad)
    # the views differ (else the test would not tell them apart) and every view sees Gaussians
    assert not torch.equal(image[0], image[1]) and bool(meta.visible.any(dim=1).all())
    for name, g in grads.items():
        assert g.abs().sum() > 0, name
        assert torch.equal(g, expected[name]), f"{name}: max diff {(g - expected[name]).abs().max()}"


@needs_cpu
def test_one_camera_batch_equals_the_unbatched_call():
    """``(1, 4, 4)`` renders what ``(4, 4)`` does, with a leading axis of 1; gradients identical."""
    scene, viewmats, Ks, leaves = _setup(True, seed=2)
    weights = [w[:1] for w in _weights(3, scene.height, scene.width, torch.float32)]
    kw = {"render_mode": "RGB+D", "background": torch.tensor([0.3, 0.3, 0.3])}
    (image, alpha, meta), grads = _batched(scene, viewmats[:1], Ks[:1], leaves, weights, "cpu", **kw)
    views, expected = _per_view(scene, viewmats[:1], Ks[:1], leaves, weights, "cpu", **kw)
    assert torch.equal(image[0], views[0][0]) and torch.equal(meta.depth[0], views[0][2].depth)
    for name in grads:
        assert torch.equal(grads[name], expected[name]), name


@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_one_camera_is_a_batch_of_one_bit_for_bit(backend):
    """The unbatched call is the batch of one: image, alpha, depth, every projection field and every gradient,
    ``meta.means2d``'s included (the densifier's statistic, read through ``retain_grad()``), equal exactly."""
    if backend == "cpu" and not is_available():
        pytest.skip("C++ backend not built")
    scene, viewmats, Ks, leaves = _setup(True, seed=4, n=120, width=40, height=30)
    weights = [w[:1] for w in _weights(9, scene.height, scene.width, torch.float32)]
    kw = {"render_mode": "RGB+ED", "background": torch.tensor([0.2, 0.4, 0.6])}
    (image, alpha, meta), grads = _batched(scene, viewmats[:1], Ks[:1], leaves, weights, backend, **kw)
    views, expected = _per_view(scene, viewmats[:1], Ks[:1], leaves, weights, backend, **kw)
    one_image, one_alpha, one_meta = views[0]
    assert one_image.shape == image.shape[1:] and one_meta.means2d.shape == (scene.n, 2)
    assert torch.equal(image[0], one_image) and torch.equal(alpha[0], one_alpha)
    for field in ("means2d", "radii", "depths", "visible", "depth"):
        assert torch.equal(getattr(meta, field)[0], getattr(one_meta, field)), field
    assert one_meta.means2d.grad is not None and one_meta.means2d.grad.abs().sum() > 0
    assert torch.equal(meta.means2d.grad[0], one_meta.means2d.grad)
    for name in grads:
        assert torch.equal(grads[name], expected[name]), name


def test_batched_reference_backend_equals_per_view():
    """The reference backend's batch is its per-view renders stacked; gradients equal the per-view sums up to the
    order autograd adds them in (float32 rounding)."""
    scene, viewmats, Ks, leaves = _setup(True, seed=3, n=60, width=24, height=20)
    weights = _weights(5, scene.height, scene.width, torch.float32)
    (image, alpha, meta), grads = _batched(scene, viewmats, Ks, leaves, weights, "reference", render_mode="RGB+D")
    views, expected = _per_view(scene, viewmats, Ks, leaves, weights, "reference", render_mode="RGB+D")
    for c, (img_c, alpha_c, meta_c) in enumerate(views):
        assert torch.equal(image[c], img_c) and torch.equal(alpha[c], alpha_c)
        assert torch.equal(meta.depth[c], meta_c.depth) and torch.equal(meta.means2d.grad[c], meta_c.means2d.grad)
    for name, g in grads.items():
        torch.testing.assert_close(g, expected[name], rtol=1e-5, atol=1e-6, msg=name)


@needs_cpu
def test_batched_cpu_matches_reference_backend():
    """The batched kernels against the batched reference: same images and gradients up to float32 rounding. The
    gradients are held to the float64 reference: each within what float32 rounding costs the float32 reference
    itself there (its largest error against float64, twice, at least 1e-4), since a gradient summed over many pixels
    with cancellations loses more than 1e-4 in float32 on some CPUs' kernel variants, in both backends."""
    scene, viewmats, Ks, leaves = _setup(True, seed=4, n=80, width=32, height=24)
    weights = _weights(9, scene.height, scene.width, torch.float32)
    kw = {"render_mode": "RGB+ED", "background": torch.tensor([0.5, 0.1, 0.7])}
    (image, alpha, meta), grads = _batched(scene, viewmats, Ks, leaves, weights, "cpu", **kw)
    (image_r, alpha_r, meta_r), grads_r = _batched(scene, viewmats, Ks, leaves, weights, "reference", **kw)
    torch.testing.assert_close(image, image_r, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(alpha, alpha_r, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(meta.depth, meta_r.depth, rtol=1e-4, atol=1e-4)
    s64, v64, k64, l64 = _setup(True, seed=4, n=80, width=32, height=24, dtype=torch.float64)
    kw64 = {"render_mode": "RGB+ED", "background": torch.tensor([0.5, 0.1, 0.7], dtype=torch.float64)}
    (_, _, meta_64), grads_64 = _batched(s64, v64, k64, l64, _weights(9, s64.height, s64.width, torch.float64),
                                         "reference", **kw64)
    pairs = {"means2d": (meta.means2d.grad, meta_r.means2d.grad, meta_64.means2d.grad)}
    pairs.update({name: (grads[name], grads_r[name], grads_64[name]) for name in grads})
    for name, (cpu, ref, exact) in pairs.items():
        rounding = float((ref.double() - exact).abs().max())
        torch.testing.assert_close(cpu.double(), exact, rtol=1e-3, atol=max(1e-4, 2 * rounding), msg=name)


@needs_cpu
def test_batched_cpu_finite_differences():
    """float64 central differences of the batched kernels (two cameras, plain colours, RGB+D, background) for every
    per-Gaussian input; each view is kept away from the blending thresholds as in test_render_gradients.py."""
    W, H = 12, 10
    scene = random_scene(6, W, H, torch.float64, 0, scale_range=(0.15, 0.5), opacity_range=(0.2, 0.7))
    viewmats, Ks = _cameras(scene, 2, 0, max_angle=0.05)
    for c in range(2):
        one = type(scene)(scene.means, scene.quats, scene.scales, scene.opacities, scene.colors, viewmats[c], Ks[c], W, H)
        m = blend_margins(one)
        assert min(m["threshold"], m["clamp"], m["stop"]) > 1e-3, m
    g = torch.Generator().manual_seed(11)
    weights = [torch.randn(2, H, W, k, generator=g, dtype=torch.float64) for k in (3, 1, 1)]
    bg = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)

    def f(means, quats, scales, opacities, colors):
        image, alpha, meta = rasterize(means, quats, scales, opacities, colors, viewmats, Ks, W, H, background=bg,
                                       tile_size=8, render_mode="RGB+D", backend="cpu")
        return torch.stack([(o * w).sum() for o, w in zip((image, alpha, meta.depth), weights)])

    finite_difference_check(f, dict(means=scene.means, quats=scene.quats, scales=scene.scales,
                                    opacities=scene.opacities, colors=scene.colors))


def test_batched_gsplat_adapter_equals_per_view(monkeypatch):
    """The gsplat path passes the batch to gsplat (here its PyTorch twin): every view equals the one-camera call up
    to float32 rounding (the twin's batched matrix products round apart from its per-camera ones, as gsplat's CUDA
    kernels do not promise bit-equal batches either)."""
    gsplat_torch = pytest.importorskip("gsplat_torch")
    gsplat_torch.install(monkeypatch)
    scene = random_scene(60, 24, 20, torch.float32, 5, sh_degree=3, margin=0.3)
    viewmats, Ks = _cameras(scene, C, 5)
    kw = {"sh_degree": 3, "render_mode": "RGB+D", "background": torch.tensor([0.2, 0.4, 0.6]), "backend": "gsplat"}
    args = (scene.means, scene.quats, scene.scales, scene.opacities, scene.colors)
    image, alpha, meta = rasterize(*args, viewmats, Ks, scene.width, scene.height, **kw)
    assert image.shape == (C, scene.height, scene.width, 3) and meta.means2d.shape == (C, scene.n, 2)
    for c in range(C):
        img_c, alpha_c, meta_c = rasterize(*args, viewmats[c], Ks[c], scene.width, scene.height, **kw)
        torch.testing.assert_close(image[c], img_c, rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(alpha[c], alpha_c, rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(meta.depth[c], meta_c.depth, rtol=1e-5, atol=1e-5)
        assert torch.equal(meta.visible[c], meta_c.visible) and torch.equal(meta.radii[c], meta_c.radii)
    leaves = [t.detach().requires_grad_(True) for t in args]
    image, _, meta = rasterize(*leaves, viewmats, Ks, scene.width, scene.height, **kw)
    meta.means2d.retain_grad()
    image.sum().backward()
    assert meta.means2d.grad.shape == (C, scene.n, 2) and meta.means2d.grad.abs().sum() > 0
    assert all(t.grad is not None and t.grad.abs().sum() > 0 for t in leaves)


@pytest.mark.parametrize(
    ("viewmats", "Ks", "match"),
    [
        (torch.eye(4).repeat(3, 1, 1), torch.eye(3).repeat(2, 1, 1), "viewmats has 3 cameras but Ks has 2"),
        (torch.eye(4).repeat(3, 1, 1), torch.eye(3), "viewmats .* and Ks .*: give both"),
        (torch.eye(4)[:3], torch.eye(3), r"viewmats must be \(4, 4\) or \(C, 4, 4\)"),
        (torch.eye(4).repeat(2, 2, 1, 1), torch.eye(3).repeat(2, 2, 1, 1), "viewmats must be"),
        (torch.eye(4).repeat(2, 1, 1), torch.eye(4).repeat(2, 1, 1), r"Ks must be \(3, 3\) or \(C, 3, 3\)"),
        (torch.zeros(0, 4, 4), torch.zeros(0, 3, 3), "at least one camera"),
    ],
)
def test_camera_shape_errors(viewmats, Ks, match):
    scene = random_scene(5, 8, 6)
    with pytest.raises(ValueError, match=match):
        rasterize(scene.means, scene.quats, scene.scales, scene.opacities, scene.colors, viewmats, Ks, 8, 6,
                  backend="reference")


def test_background_per_view_shape_error():
    scene = random_scene(5, 8, 6)
    viewmats, Ks = _cameras(scene, C)
    with pytest.raises(ValueError, match="background must be"):
        rasterize(scene.means, scene.quats, scene.scales, scene.opacities, scene.colors, viewmats, Ks, 8, 6,
                  background=torch.zeros(2, 3), backend="reference")


def _camera(seed: int, width: int = 40, height: int = 30) -> Camera:
    g = torch.Generator().manual_seed(seed)
    viewmat = torch.eye(4, dtype=torch.float64)
    viewmat[:3, :3] = look_rotation(g, 0.3, torch.float64)
    viewmat[:3, 3] = torch.tensor([0.0, 0.0, 3.0], dtype=torch.float64) + 0.2 * torch.randn(3, generator=g, dtype=torch.float64)
    f = 40.0 + 5 * seed
    K = torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]], dtype=torch.float64)
    return Camera(f"cam{seed}", K.numpy(), viewmat.numpy(), width, height)


@needs_cpu
def test_model_renders_a_list_of_cameras_in_one_call():
    """``gaussians.render`` over a list of cameras of one size equals rendering them one by one; cameras of other
    sizes are refused with the sizes named."""
    g = torch.Generator().manual_seed(0)
    pts = (torch.rand(300, 3, generator=g) - 0.5).numpy()
    model = GaussianModel.from_points(pts, torch.rand(300, 3, generator=g).numpy(), 3, 0.5)
    cams = [_camera(s) for s in range(3)]
    image, alpha, meta = render(model, cams, backend="cpu", render_mode="RGB+D")
    assert image.shape == (3, 30, 40, 3) and meta.depth.shape == (3, 30, 40, 1)
    for c, cam in enumerate(cams):
        img_c, alpha_c, meta_c = render(model, cam, backend="cpu", render_mode="RGB+D")
        assert torch.equal(image[c], img_c) and torch.equal(alpha[c], alpha_c) and torch.equal(meta.depth[c], meta_c.depth)
    with pytest.raises(ValueError, match="one size"):
        render(model, [cams[0], _camera(5, 20, 10)], backend="cpu")


@needs_cpu
@pytest.mark.parametrize("max_elements", [1, 3000, 2**24])
def test_render_each_batches_cameras_of_one_size(max_elements):
    """``render_each`` yields every view in order, each equal to its own render, whatever the batching: runs of one
    size are split where the size changes and where a batch would pass ``max_elements``."""
    g = torch.Generator().manual_seed(1)
    model = GaussianModel.from_points((torch.rand(200, 3, generator=g) - 0.5).numpy(),
                                      torch.rand(200, 3, generator=g).numpy(), 1, 0.5)
    cams = [_camera(0), _camera(1), _camera(2, 20, 10), _camera(3), _camera(4), _camera(5)]
    views = list(render_each(model, cams, max_elements=max_elements, backend="cpu", render_mode="RGB+D"))
    assert len(views) == len(cams)
    for (image, alpha, meta), cam in zip(views, cams):
        img_c, alpha_c, meta_c = render(model, cam, backend="cpu", render_mode="RGB+D")
        assert image.shape == (cam.height, cam.width, 3) and meta.means2d.shape == (200, 2)
        assert torch.equal(image, img_c) and torch.equal(alpha, alpha_c) and torch.equal(meta.depth, meta_c.depth)
