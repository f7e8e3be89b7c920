"""EWA projection of 3-D Gaussians to screen space (pure PyTorch, differentiable by autograd).

Conventions follow gsplat so that every backend sees the same 2-D Gaussians:
pixel centres at +0.5 (``K`` maps to pixel-corner coordinates), 0.3 px² added to the 2-D covariance,
the Jacobian evaluated with the view direction clamped to 1.3× the field of view, conics as the
upper triangle ``(a, b, c)`` of the inverse 2-D covariance, so that the Gaussian's exponent at pixel offset
``(dx, dy)`` is ``sigma = 0.5 (a dx² + c dy²) + b dx dy``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

ALPHA_THRESHOLD = 1.0 / 255.0
"""Alpha below which a Gaussian is skipped at a pixel."""
MAX_ALPHA = 0.99
"""Alpha is clamped to this value (3DGS's cap; keeps 1 - alpha ≥ 0.01 for the backward pass)."""
TRANSMITTANCE_EPS = 1e-4
"""Blending at a pixel stops before transmittance would fall to this value."""
RADIUS_SIGMAS = 3.33
"""Screen radius in standard deviations (exp(-0.5·3.33²) ≈ 1/255)."""


@dataclass
class Projected:
    """Screen-space Gaussians, one row per input Gaussian.

    Attributes:
        means2d: ``(N, 2)`` pixel coordinates (x right, y down; pixel centres at +0.5).
        conics: ``(N, 3)`` inverse 2-D covariance ``(a, b, c)`` in 1/px².
        depths: ``(N,)`` camera-space z in world units.
        extents: ``(N, 2)`` half-size in px of the box outside which alpha < 1/255 (opacity-aware);
            0 for culled Gaussians.
        radii: ``(N, 2)`` int32 3.33-sigma half-extent in px (gsplat's ``radii``); 0 when culled.
        visible: ``(N,)`` bool, in front of the near plane, positive-definite, overlapping the image.
    """

    means2d: Tensor
    conics: Tensor
    depths: Tensor
    extents: Tensor
    radii: Tensor
    visible: Tensor


def normalize_quats(quats: Tensor) -> Tensor:
    """Unit quaternions ``(N, 4)`` wxyz; zero quaternions map to identity instead of NaN."""
    norm = quats.norm(dim=-1, keepdim=True)
    ident = torch.zeros_like(quats)
    ident[..., 0] = 1.0
    return torch.where(norm > 1e-12, quats / norm.clamp_min(1e-12), ident)


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Rotation matrices ``(N, 3, 3)`` from wxyz quaternions ``(N, 4)`` (normalised inside)."""
    w, x, y, z = normalize_quats(quats).unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(quats.shape[:-1] + (3, 3))


def covariance_3d(quats: Tensor, scales: Tensor) -> Tensor:
    """World-space covariances ``(N, 3, 3)`` = R S Sᵀ Rᵀ from quaternions and per-axis scales (world units)."""
    M = quat_to_rotmat(quats) * scales[..., None, :]
    return M @ M.transpose(-1, -2)


def project_gaussians(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e10,
    eps2d: float = 0.3,
) -> Projected:
    """Project Gaussians into one pinhole camera.

    Args:
        means: ``(N, 3)`` world positions. quats: ``(N, 4)`` wxyz (any norm). scales: ``(N, 3)`` world units.
        opacities: ``(N,)`` in [0, 1]. viewmat: ``(4, 4)`` world→camera. K: ``(3, 3)`` intrinsics in px.
        width, height: image size in px. near, far: z clipping planes (world units).
        eps2d: px² added to the diagonal of the 2-D covariance (low-pass filter).
    """
    R, t = viewmat[:3, :3], viewmat[:3, 3]
    p = means @ R.T + t
    x, y, z = p.unbind(-1)
    in_depth = (z > near) & (z < far)
    zs = torch.where(in_depth, z, torch.ones_like(z))  # keeps culled rows finite (no inf/NaN in the graph)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]

    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx
    lim_x_neg = cx / fx + 0.3 * tan_fovx
    lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy
    lim_y_neg = cy / fy + 0.3 * tan_fovy
    tx = zs * torch.minimum(lim_x_pos, torch.maximum(-lim_x_neg, x / zs))
    ty = zs * torch.minimum(lim_y_pos, torch.maximum(-lim_y_neg, y / zs))
    zero = torch.zeros_like(zs)
    J = torch.stack(
        [fx / zs, zero, -fx * tx / (zs * zs), zero, fy / zs, -fy * ty / (zs * zs)], dim=-1
    ).reshape(-1, 2, 3)

    cov_world = covariance_3d(quats, scales)
    cov_cam = R @ cov_world @ R.T
    cov2d = J @ cov_cam @ J.transpose(-1, -2)
    a = cov2d[:, 0, 0] + eps2d
    b = cov2d[:, 0, 1]
    c = cov2d[:, 1, 1] + eps2d
    det = a * c - b * b
    pos_def = det > 1e-12
    det_s = torch.where(pos_def, det, torch.ones_like(det))
    conics = torch.stack([c / det_s, -b / det_s, a / det_s], dim=-1)

    means2d = torch.stack([fx * x / zs + cx, fy * y / zs + cy], dim=-1)

    extents, radii, visible = screen_bounds(means2d, torch.stack([a.detach(), c.detach()], -1), opacities, in_depth & pos_def, width, height)
    return Projected(means2d, conics, z, extents, radii, visible)


@torch.no_grad()
def screen_bounds(
    means2d: Tensor, cov_diag: Tensor, opacities: Tensor, kept: Tensor, width: int, height: int
) -> tuple[Tensor, Tensor, Tensor]:
    """Screen boxes of projected Gaussians: ``(extents, radii, visible)`` as in :class:`Projected`.

    Args:
        means2d: ``(N, 2)`` px. cov_diag: ``(N, 2)`` diagonal of the 2-D covariance (eps2d included), px².
        opacities: ``(N,)``. kept: ``(N,)`` bool, Gaussians the projection did not cull (depth, determinant).
        means2d, cov_diag and kept may carry a leading camera axis ``(C, N, ·)``; the outputs then do too.
    """
    # Opacity-aware extent: alpha = o·exp(-sigma) ≥ 1/255 needs sigma ≤ log(255·o); the level set
    # sigma = s of the 2-D Gaussian has half-widths sqrt(2 s a_cov) along x and sqrt(2 s c_cov) along y.
    s_max = torch.log((opacities.detach() / ALPHA_THRESHOLD).clamp_min(1.0))
    half = cov_diag.detach().clamp_min(0).sqrt()
    # padded slightly so the box is a strict superset of the alpha ≥ 1/255 region (rounding)
    extents = torch.sqrt(2.0 * s_max)[..., None] * half * 1.001 + 1e-3
    radii = torch.ceil(RADIUS_SIGMAS * half)
    m = means2d.detach()
    on_screen = (
        (m[..., 0] + extents[..., 0] > 0) & (m[..., 0] - extents[..., 0] < width)
        & (m[..., 1] + extents[..., 1] > 0) & (m[..., 1] - extents[..., 1] < height)
    )
    visible = kept & (s_max > 0) & on_screen & torch.isfinite(m).all(-1)
    extents = torch.where(visible[..., None], extents, torch.zeros_like(extents))
    radii = torch.where(visible[..., None], radii, torch.zeros_like(radii)).to(torch.int32)
    return extents, radii, visible
