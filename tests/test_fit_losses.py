"""3DGS losses and metrics: SSIM identities, agreement with the 2-D-window formulation, gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from abcgs.fit import metrics
from abcgs.fit.losses import dssim, l1, reconstruction_loss, ssim, ssim_map


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
