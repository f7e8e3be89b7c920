"""Real spherical harmonics (degrees 0–3), the 3DGS convention: colour = SH(dir) + 0.5, clamped at 0."""

from __future__ import annotations

from torch import Tensor

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
C3 = (
    -0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
    -0.4570457994644658, 1.445305721320277, -0.5900435899266435,
)


def num_sh_bases(degree: int) -> int:
    """Number of SH coefficients per channel for ``degree`` (1, 4, 9, 16)."""
    if not 0 <= degree <= 3:
        raise ValueError(f"SH degree must be 0..3, got {degree}")
    return (degree + 1) ** 2


def rgb_to_sh0(rgb: Tensor) -> Tensor:
    """DC coefficient that renders as ``rgb`` (inverse of ``C0·f + 0.5``)."""
    return (rgb - 0.5) / C0


def sh0_to_rgb(sh0: Tensor) -> Tensor:
    return sh0 * C0 + 0.5


def eval_sh(degree: int, coeffs: Tensor, dirs: Tensor) -> Tensor:
    """Evaluate SH.

    Args:
        degree: 0..3, the highest band used (coefficients beyond it are ignored).
        coeffs: ``(N, K, C)`` with K ≥ (degree+1)².
        dirs: ``(N, 3)`` view directions (any length; normalised here).
    Returns:
        ``(N, C)`` raw SH values (add 0.5 and clamp for colours: see :func:`sh_to_color`).
    """
    out = C0 * coeffs[:, 0]
    if degree == 0:
        return out
    d = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    x, y, z = (d[:, i : i + 1] for i in range(3))
    out = out - C1 * y * coeffs[:, 1] + C1 * z * coeffs[:, 2] - C1 * x * coeffs[:, 3]
    if degree == 1:
        return out
    xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
    out = (
        out
        + C2[0] * xy * coeffs[:, 4]
        + C2[1] * yz * coeffs[:, 5]
        + C2[2] * (2 * zz - xx - yy) * coeffs[:, 6]
        + C2[3] * xz * coeffs[:, 7]
        + C2[4] * (xx - yy) * coeffs[:, 8]
    )
    if degree == 2:
        return out
    return (
        out
        + C3[0] * y * (3 * xx - yy) * coeffs[:, 9]
        + C3[1] * xy * z * coeffs[:, 10]
        + C3[2] * y * (4 * zz - xx - yy) * coeffs[:, 11]
        + C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * coeffs[:, 12]
        + C3[4] * x * (4 * zz - xx - yy) * coeffs[:, 13]
        + C3[5] * z * (xx - yy) * coeffs[:, 14]
        + C3[6] * x * (xx - 3 * yy) * coeffs[:, 15]
    )


def sh_to_color(degree: int, coeffs: Tensor, means: Tensor, campos: Tensor) -> Tensor:
    """View-dependent colours ``(N, C)`` for a camera at ``campos`` ``(3,)``: SH + 0.5, clamped at 0."""
    return (eval_sh(degree, coeffs, means - campos) + 0.5).clamp_min(0.0)
