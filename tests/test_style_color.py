"""Colour match (mean/covariance transfer), per-group application, luminance-only colour preservation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from abcgs.errors import InputError
from abcgs.stylize import color


def _pixels(n, seed, scale):
    g = torch.Generator().manual_seed(seed)
    mix = torch.randn(3, 3, generator=g, dtype=torch.float64) * scale
    return (torch.rand(n, 3, generator=g, dtype=torch.float64) @ mix.t() + torch.rand(3, generator=g)).float()


def _mean_cov(p):
    p = p.double()
    mu = p.mean(0)
    d = p - mu
    return mu, d.t() @ d / p.shape[0]


def test_transform_meets_target_mean_and_covariance():
    pc = _pixels(5000, 0, 0.6)
    ps = _pixels(3000, 1, 0.3)
    a, b = color.fit_color_transform(pc, ps)
    assert a.shape == (3, 3) and b.shape == (3,) and a.dtype == torch.float32
    out = color.apply_color_transform(pc, a, b)
    mu_o, cov_o = _mean_cov(out)
    mu_s, cov_s = _mean_cov(ps)
    assert torch.allclose(mu_o, mu_s, atol=1e-4)
    assert torch.allclose(cov_o, cov_s, atol=1e-4)


def test_formula_and_numpy_input():
    pc = _pixels(400, 2, 1.0).numpy()
    ps = _pixels(300, 3, 0.5).numpy().reshape(20, 15, 3)  # any leading shape
    a, b = color.fit_color_transform(pc, ps)
    mu_c, cov_c = np.mean(pc.astype(np.float64), 0), np.cov(pc.T.astype(np.float64), bias=True)
    mu_s, cov_s = np.mean(ps.reshape(-1, 3).astype(np.float64), 0), np.cov(ps.reshape(-1, 3).T.astype(np.float64), bias=True)
    lc, uc = np.linalg.eigh(cov_c)
    ls, us = np.linalg.eigh(cov_s)
    a_ref = us @ np.diag(np.sqrt(ls)) @ us.T @ uc @ np.diag(1 / np.sqrt(lc)) @ uc.T
    assert np.allclose(a.numpy(), a_ref, atol=1e-5)
    assert np.allclose(b.numpy(), mu_s - a_ref @ mu_c, atol=1e-5)


def test_apply_shapes_clip_and_grad():
    a = torch.eye(3) * 2
    b = torch.tensor([0.1, 0.0, -0.1])
    img = torch.rand(4, 5, 3)
    out = color.apply_color_transform(img, a, b, clip=(0.0, 1.0))
    assert out.shape == img.shape and out.min() >= 0 and out.max() <= 1
    x = torch.rand(6, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: color.apply_color_transform(t, a.double(), b.double()), (x,))


def test_per_group_transforms():
    pc1, pc2 = _pixels(500, 4, 0.5), _pixels(500, 5, 0.8)
    ps1, ps2 = _pixels(500, 6, 0.2), _pixels(500, 7, 0.4)
    tf = {1: color.fit_color_transform(pc1, ps1), 2: color.fit_color_transform(pc2, ps2)}
    x = torch.cat([pc1, pc2, pc1[:10]])
    labels = torch.cat([torch.ones(500), torch.full((500,), 2), torch.zeros(10)]).long()
    out = color.apply_group_transforms(x, [labels == 1, labels == 2], [tf[1], tf[2]])
    assert torch.equal(x, torch.cat([pc1, pc2, pc1[:10]]))  # the input is not changed
    for lab, ps in ((1, ps1), (2, ps2)):
        mu_o, cov_o = _mean_cov(out[labels == lab])
        mu_s, cov_s = _mean_cov(ps)
        assert torch.allclose(mu_o, mu_s, atol=1e-4) and torch.allclose(cov_o, cov_s, atol=1e-4)
    assert torch.equal(out[labels == 0], x[labels == 0])  # unassigned untouched


def test_preserve_color_luminance_and_chroma():
    g = torch.Generator().manual_seed(0)
    stylized = torch.rand(2, 3, 8, 9, generator=g, dtype=torch.float64)
    original = torch.rand(2, 3, 8, 9, generator=g, dtype=torch.float64) * 0.5 + 0.25
    out = color.preserve_color(stylized, original, channel_dim=1, clip=None)
    yo, ys, yy = (color.rgb_to_yiq(t, 1) for t in (out, stylized, original))
    assert torch.allclose(yo[:, 0], ys[:, 0], atol=1e-12)
    assert torch.allclose(yo[:, 1:], yy[:, 1:], atol=1e-12)
    # round trip and (H, W, 3) layout
    x = torch.rand(5, 4, 3, dtype=torch.float64)
    assert torch.allclose(color.yiq_to_rgb(color.rgb_to_yiq(x)), x, atol=1e-12)
    assert torch.allclose(color.preserve_color(x, x, clip=None), x, atol=1e-12)


def test_bad_inputs():
    with pytest.raises(InputError, match="last dimension 3"):
        color.fit_color_transform(torch.rand(10, 4), torch.rand(10, 3))
    with pytest.raises(InputError, match="at least 2"):
        color.fit_color_transform(torch.rand(1, 3), torch.rand(10, 3))
    with pytest.raises(InputError, match="NaN"):
        color.fit_color_transform(torch.full((5, 3), float("nan")), torch.rand(10, 3))
    with pytest.raises(InputError):
        color.apply_color_transform(torch.rand(4, 2), torch.eye(3), torch.zeros(3))
    with pytest.raises(InputError, match="selection shape"):
        color.apply_group_transforms(torch.rand(4, 3), [torch.ones(5, dtype=torch.bool)], [(torch.eye(3), torch.zeros(3))])
    with pytest.raises(InputError):
        color.preserve_color(torch.rand(4, 4, 3), torch.rand(4, 4, 2))
