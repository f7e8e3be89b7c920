"""3DGS losses and metrics: SSIM identities, agreement with the 2-D-window formulation, gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from abcgs.fit import metrics
from abcgs.fit.losses import dssim, l1, l1_ssim, reconstruction_loss, ssim, ssim_map
from abcgs.render import cpu as cpu_backend

needs_kernel = pytest.mark.skipif(not cpu_backend.is_available(), reason="C++ extension not built")


def ssim_3dgs_2d(img1: torch.Tensor, img2: torch.Tensor) -> torch.Tensor:
    """The reference code's SSIM (utils/loss_utils.py) written independently: 2-D window, zero padding."""
    x = img1.permute(2, 0, 1)[None]
    y = img2.permute(2, 0, 1)[None]
    c = x.shape[1]
    g = torch.tensor([math.exp(-((i - 5) ** 2) / (2 * 1.5**2)) for i in range(11)], dtype=x.dtype)
    g = g / g.sum()
    w = (g[:, None] @ g[None, :]).expand(c, 1, 11, 11).contiguous()
    conv = lambda t: F.conv2d(t, w, padding=5, groups=c)  # noqa: E731
    mu1, mu2 = conv(x), conv(y)
    s1 = conv(x * x) - mu1**2
    s2 = conv(y * y) - mu2**2
    s12 = conv(x * y) - mu1 * mu2
    c1, c2 = 0.01**2, 0.03**2
    return (((2 * mu1 * mu2 + c1) * (2 * s12 + c2)) / ((mu1**2 + mu2**2 + c1) * (s1 + s2 + c2))).mean()


def test_ssim_identity_and_range():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(24, 31, 3, generator=g)
    assert float(ssim(x, x)) == pytest.approx(1.0, abs=1e-6)
    y = torch.rand(24, 31, 3, generator=g)
    assert -1.0 <= float(ssim(x, y)) < 0.2
    assert float(dssim(x, x)) == pytest.approx(0.0, abs=1e-6)


def test_ssim_matches_2d_window_formulation():
    g = torch.Generator().manual_seed(1)
    x = torch.rand(20, 17, 3, generator=g, dtype=torch.float64)
    y = (x + 0.2 * torch.randn(20, 17, 3, generator=g, dtype=torch.float64)).clamp(0, 1)
    assert float(ssim(x, y)) == pytest.approx(float(ssim_3dgs_2d(x, y)), abs=1e-12)
    batched = ssim_map(torch.stack([x, y]), torch.stack([y, x]))
    assert batched.shape == (2, 3, 20, 17)


def test_ssim_gradient_matches_finite_differences():
    g = torch.Generator().manual_seed(2)
    x = torch.rand(5, 4, 2, generator=g, dtype=torch.float64, requires_grad=True)
    y = torch.rand(5, 4, 2, generator=g, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda a: ssim(a, y), (x,), eps=1e-6, atol=1e-7)


def test_reconstruction_loss_is_3dgs_formula():
    g = torch.Generator().manual_seed(3)
    x, y = torch.rand(16, 16, 3, generator=g), torch.rand(16, 16, 3, generator=g)
    terms = reconstruction_loss(x, y, 0.2)
    expected = 0.8 * (x - y).abs().mean() + 0.2 * (1.0 - ssim(x, y))
    assert float(terms.total) == pytest.approx(float(expected), rel=1e-6)
    assert float(terms.l1) == pytest.approx(float(l1(x, y)))


def test_metrics():
    x = np.full((8, 8, 3), 0.5, np.float32)
    y = x + 0.1
    assert metrics.psnr(x, y) == pytest.approx(20.0, abs=1e-4)
    assert metrics.psnr(x, x) == math.inf
    assert metrics.ssim(x, x) == pytest.approx(1.0, abs=1e-6)
    # renders outside [0, 1] are clamped before scoring
    assert metrics.psnr(x * 0 + 1.5, np.ones_like(x)) == math.inf


# ---- the fused CPU kernel (abcgs/render/csrc/image_loss_cpu.cpp) against the torch ops above ----


def _pair(shape, dtype, seed):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(shape, generator=g, dtype=dtype)
    y = (x + 0.3 * torch.randn(shape, generator=g, dtype=dtype)).clamp(0, 1)
    x[..., :2, :3, :] = y[..., :2, :3, :]  # exact ties: sign(0) = 0 in the L1 gradient
    return x.requires_grad_(True), y


@needs_kernel
@pytest.mark.parametrize(
    "shape",
    [(70, 45, 3), (5, 7, 1), (2, 33, 20, 4), (40, 3, 2)],  # 70 rows: three row blocks; images smaller than the window
)
def test_fused_loss_matches_torch_values_and_gradients(shape):
    x, y = _pair(shape, torch.float64, 4)
    ref = reconstruction_loss(x, y, 0.2, fused=False)
    fused = reconstruction_loss(x, y, 0.2, fused=True)
    assert "Fused" in type(fused.l1.grad_fn).__name__
    for name in ("total", "l1", "ssim"):
        assert float(getattr(fused, name).detach()) == pytest.approx(float(getattr(ref, name).detach()), abs=1e-13), name
    for weights in ((1.0, 0.0), (0.0, 1.0), (0.8, -0.2)):  # each term's gradient on its own, then the loss's
        g_ref, = torch.autograd.grad(weights[0] * ref.l1 + weights[1] * ref.ssim, x, retain_graph=True)
        g_fused, = torch.autograd.grad(weights[0] * fused.l1 + weights[1] * fused.ssim, x, retain_graph=True)
        torch.testing.assert_close(g_fused, g_ref, atol=1e-14, rtol=1e-10)


@needs_kernel
def test_fused_loss_float32_agrees_with_torch():
    x, y = _pair((96, 130, 3), torch.float32, 5)
    ref = reconstruction_loss(x, y, 0.2, fused=False)
    fused = reconstruction_loss(x, y, 0.2)  # default: fused on the CPU
    assert "Fused" in type(fused.ssim.grad_fn).__name__
    assert float(fused.total.detach()) == pytest.approx(float(ref.total.detach()), rel=1e-6)
    g_ref, = torch.autograd.grad(ref.total, x)
    g_fused, = torch.autograd.grad(fused.total, x)
    torch.testing.assert_close(g_fused, g_ref, atol=1e-6 * float(g_ref.abs().max()), rtol=0)


@needs_kernel
def test_fused_loss_gradient_matches_finite_differences():
    x, y = _pair((9, 12, 2), torch.float64, 6)
    assert torch.autograd.gradcheck(lambda a: reconstruction_loss(a, y, 0.2, fused=True).total, (x,), eps=1e-6,
                                    atol=1e-8)
    assert torch.autograd.gradcheck(lambda a: l1_ssim(a, y, fused=True)[1], (x,), eps=1e-6, atol=1e-8)


@needs_kernel
def test_fused_loss_is_bit_identical_for_any_thread_count():
    x, y = _pair((101, 67, 3), torch.float32, 7)
    results = []
    for n in (1, 2, 3):
        with cpu_backend.kernel_threads(n):
            terms = reconstruction_loss(x, y, 0.2)
            grad, = torch.autograd.grad(terms.total, x)
        results.append((terms.l1.detach(), terms.ssim.detach(), grad))
    for other in results[1:]:
        for a, b in zip(results[0], other):
            assert torch.equal(a, b)


def test_fused_loss_refuses_what_it_cannot_do():
    x = torch.rand(8, 8, 3, requires_grad=True)
    with pytest.raises(ValueError, match="fused L1 \\+ SSIM kernel"):
        l1_ssim(x, torch.rand(8, 8, 3, dtype=torch.float64), fused=True)  # dtype mismatch
    with pytest.raises(ValueError, match="target without gradient"):
        l1_ssim(x, torch.rand(8, 8, 3, requires_grad=True), fused=True)
    # the default falls back to the torch ops where the kernel cannot run, and keeps both gradients
    y = torch.rand(8, 8, 3, requires_grad=True)
    total = reconstruction_loss(x, y, 0.2).total
    gx, gy = torch.autograd.grad(total, (x, y))
    assert gx.abs().sum() > 0 and gy.abs().sum() > 0
