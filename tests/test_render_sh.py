"""Spherical harmonics: conventions, known values, and their use inside rasterize()."""

from __future__ import annotations

import math

import pytest
import torch
from render_scenes import random_scene

from abcgs.render import eval_sh, num_sh_bases, rasterize, rgb_to_sh0, sh0_to_rgb
from abcgs.render.cpu import is_available
from abcgs.render.sh import sh_to_color

BACKENDS = ["reference", pytest.param("cpu", marks=pytest.mark.skipif(not is_available(), reason="C++ backend not built"))]
F64 = torch.float64


def _basis(degree, dirs):
    """(N, K) values of each real SH basis function, via eval_sh on one-hot coefficients."""
    K = num_sh_bases(degree)
    n = dirs.shape[0]
    coeffs = torch.eye(K, dtype=F64)[None].expand(n, K, K)  # channel k = basis k
    return eval_sh(degree, coeffs, dirs)


def _scipy_real_sh(l, m, dirs):  # noqa: E741
    """Real SH in the 3DGS convention, from scipy's complex SH (Condon–Shortley phase included):
    m > 0: √2·Re Y_l^m,  m < 0: √2·Im Y_l^|m|,  m = 0: Y_l^0;  coefficient index l² + l + m."""
    special = pytest.importorskip("scipy.special")
    d = dirs / dirs.norm(dim=-1, keepdim=True)
    theta = torch.arccos(d[:, 2].clamp(-1, 1)).numpy()
    phi = torch.atan2(d[:, 1], d[:, 0]).numpy()
    y = special.sph_harm_y(l, abs(m), theta, phi)
    if m > 0:
        v = math.sqrt(2) * y.real
    elif m < 0:
        v = math.sqrt(2) * y.imag
    else:
        v = y.real
    return torch.from_numpy(v)


def test_num_sh_bases():
    assert [num_sh_bases(d) for d in range(4)] == [1, 4, 9, 16]
    for bad in (-1, 4):
        with pytest.raises(ValueError):
            num_sh_bases(bad)


def test_eval_sh_matches_scipy_all_bases():
    dirs = torch.randn(50, 3, generator=torch.Generator().manual_seed(0), dtype=F64)
    vals = _basis(3, dirs)
    for l in range(4):  # noqa: E741
        for m in range(-l, l + 1):
            expected = _scipy_real_sh(l, m, dirs)
            torch.testing.assert_close(vals[:, l * l + l + m], expected, atol=1e-12, rtol=1e-12, msg=f"l={l} m={m}")


def test_eval_sh_known_values():
    C0, C1 = 0.5 / math.sqrt(math.pi), math.sqrt(3 / (4 * math.pi))
    ex, ey, ez = torch.eye(3, dtype=F64)[:, None]
    # along +z only the m = 0 functions are non-zero: Y_l0(z=1) = sqrt((2l+1)/4π)
    expected_z = torch.zeros(16, dtype=F64)
    for l in range(4):  # noqa: E741
        expected_z[l * l + l] = math.sqrt((2 * l + 1) / (4 * math.pi))
    torch.testing.assert_close(_basis(3, ez)[0], expected_z, atol=1e-12, rtol=0)
    torch.testing.assert_close(_basis(3, 2.5 * ez)[0], expected_z, atol=1e-12, rtol=0)  # length-invariant
    # band 1 is (-C1·y, C1·z, -C1·x)
    torch.testing.assert_close(_basis(1, ex)[0], torch.tensor([C0, 0, 0, -C1], dtype=F64), atol=1e-12, rtol=0)
    torch.testing.assert_close(_basis(1, ey)[0], torch.tensor([C0, -C1, 0, 0], dtype=F64), atol=1e-12, rtol=0)
    # band 2 along x: xx-yy term = sqrt(15/16π), (2zz-xx-yy) term = -sqrt(5/16π)
    b2 = _basis(2, ex)[0]
    torch.testing.assert_close(b2[8], torch.tensor(math.sqrt(15 / (16 * math.pi)), dtype=F64))
    torch.testing.assert_close(b2[6], torch.tensor(-math.sqrt(5 / (16 * math.pi)), dtype=F64))
    # band 3, direction (1,1,0)/√2: -C3·y(3xx-yy) with C3 = sqrt(35/32π) → -sqrt(35/32π)·(1/√2)·(3/2-1/2)
    b3 = _basis(3, torch.tensor([[1.0, 1.0, 0.0]], dtype=F64))[0]
    torch.testing.assert_close(b3[9], torch.tensor(-math.sqrt(35 / (32 * math.pi)) / math.sqrt(2), dtype=F64))


def test_eval_sh_orthonormal_on_sphere():
    """Monte-Carlo check that the 16 bases are orthonormal: 4π·mean(Y_i Y_j) ≈ δ_ij."""
    dirs = torch.randn(200_000, 3, generator=torch.Generator().manual_seed(1), dtype=F64)
    Y = _basis(3, dirs)
    gram = 4 * math.pi * (Y.T @ Y) / dirs.shape[0]
    torch.testing.assert_close(gram, torch.eye(16, dtype=F64), atol=0.03, rtol=0)


def test_eval_sh_ignores_coefficients_beyond_degree():
    g = torch.Generator().manual_seed(2)
    coeffs = torch.randn(10, 16, 3, generator=g, dtype=F64)
    dirs = torch.randn(10, 3, generator=g, dtype=F64)
    for degree in range(4):
        K = num_sh_bases(degree)
        trimmed = coeffs.clone()
        trimmed[:, K:] = 0
        torch.testing.assert_close(eval_sh(degree, coeffs, dirs), eval_sh(degree, trimmed, dirs))
        torch.testing.assert_close(eval_sh(degree, coeffs[:, :K], dirs), eval_sh(degree, coeffs, dirs))


def test_rgb_sh0_inverse():
    rgb = torch.rand(20, 3, generator=torch.Generator().manual_seed(3), dtype=F64)
    torch.testing.assert_close(sh0_to_rgb(rgb_to_sh0(rgb)), rgb, atol=1e-14, rtol=0)
    sh = torch.randn(20, 3, dtype=F64)
    torch.testing.assert_close(rgb_to_sh0(sh0_to_rgb(sh)), sh, atol=1e-13, rtol=0)
    # degree 0 evaluation of the DC coefficient + 0.5 reproduces rgb for any direction
    dirs = torch.randn(20, 3, dtype=F64)
    torch.testing.assert_close(eval_sh(0, rgb_to_sh0(rgb)[:, None], dirs) + 0.5, rgb, atol=1e-14, rtol=0)


def test_sh_to_color_clamps_at_zero():
    coeffs = torch.full((2, 1, 3), -10.0, dtype=F64)
    out = sh_to_color(0, coeffs, torch.zeros(2, 3, dtype=F64), torch.ones(3, dtype=F64))
    assert (out == 0).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_degree0_reproduces_constant_colours(backend):
    scene = random_scene(40, 32, 24, F64, 0, scale_range=(0.05, 0.3))
    image, alpha, _ = rasterize(*scene.args(), backend=backend)
    sh = rgb_to_sh0(scene.colors)[:, None, :]
    image0, alpha0, _ = rasterize(*scene.args()[:4], sh, *scene.args()[5:], sh_degree=0, backend=backend)
    torch.testing.assert_close(image0, image, atol=1e-12, rtol=0)
    torch.testing.assert_close(alpha0, alpha, atol=0, rtol=0)
    # higher degree with zero higher bands: still the constant colours
    sh3 = torch.cat([sh, torch.zeros(scene.n, 15, 3, dtype=F64)], dim=1)
    image3, _, _ = rasterize(*scene.args()[:4], sh3, *scene.args()[5:], sh_degree=3, backend=backend)
    torch.testing.assert_close(image3, image, atol=1e-12, rtol=0)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("degree", [1, 2, 3])
def test_rasterize_sh_uses_direction_from_camera_centre(backend, degree):
    """rasterize(sh_degree=d) == rasterize of colours evaluated along (mean − camera centre),
    the camera centre being −Rᵀt of the world→camera matrix."""
    scene = random_scene(30, 32, 24, F64, degree, scale_range=(0.05, 0.3), sh_degree=degree)
    R, t = scene.viewmat[:3, :3], scene.viewmat[:3, 3]
    centre = -R.T @ t
    # camera centre maps to the camera-space origin
    torch.testing.assert_close(R @ centre + t, torch.zeros(3, dtype=F64), atol=1e-12, rtol=0)
    rgb = (eval_sh(degree, scene.colors, scene.means - centre) + 0.5).clamp_min(0)
    image_sh, _, _ = rasterize(*scene.args(), sh_degree=degree, backend=backend)
    image_rgb, _, _ = rasterize(*scene.args()[:4], rgb, *scene.args()[5:], backend=backend)
    torch.testing.assert_close(image_sh, image_rgb, atol=1e-12, rtol=0)
    # and view dependence is real: the same Gaussians seen along a different direction change colour
    shifted = scene.means - centre + torch.tensor([3.0, 0, 0], dtype=F64)
    rgb_other = (eval_sh(degree, scene.colors, shifted) + 0.5).clamp_min(0)
    assert (rgb_other - rgb).abs().max() > 1e-3
