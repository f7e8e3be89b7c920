"""gsplat 1.5's CUDA wrapper functions in plain PyTorch, so that gsplat runs on the CPU in the tests.

    install(monkeypatch)   # gsplat.<fn> and gsplat.rendering.<fn> now run here, on CPU tensors

``gsplat.rasterization`` (and abcgs's gsplat adapter) call five CUDA wrappers: ``fully_fused_projection``,
``isect_tiles``, ``isect_offset_encode``, ``spherical_harmonics`` and ``rasterize_to_pixels``. Each twin below
follows the CUDA kernel of gsplat 1.5.3 (``gsplat/cuda/csrc``), reusing gsplat's own PyTorch pieces
(``gsplat.cuda._torch_impl``) where they exist:

- projection (``ProjectionEWA3DGSFused.cu``): gsplat's ``_world_to_cam`` and ``_persp_proj``, then the kernel's
  culling: ``z < near or z > far``, ``det <= 0`` after adding ``eps2d``, ``opacity < 1/255``, the radius
  ``ceil(min(3.33, sqrt(2 ln(255 o))) · sqrt(cov))`` per axis, ``radius <= radius_clip`` on both axes, and the
  integer box off the image. Culled rows get NaN in means2d, depths and conics (the kernel leaves them unwritten).
- spherical harmonics (``SphericalHarmonicsCUDA.cu``): gsplat's ``_spherical_harmonics``; masked rows NaN.
- tile intersection and offsets: gsplat's ``_isect_tiles`` and ``_isect_offset_encode``.
- compositing (``RasterizeToPixels3DGSFwd.cu``): :func:`rasterize_to_pixels`, written here, because gsplat's
  ``_rasterize_to_pixels`` needs a CUDA helper and nerfacc.
"""

from __future__ import annotations

import importlib
import math

import gsplat
import gsplat.rendering
import torch
from gsplat.cuda import _torch_impl
from torch import Tensor

ALPHA_THRESHOLD = 1.0 / 255.0
"""``ALPHA_THRESHOLD`` in gsplat's ``cuda/include/Common.h``."""
MAX_ALPHA = 0.999
"""``min(0.999f, opac * __expf(-sigma))`` in ``RasterizeToPixels3DGSFwd.cu``."""
TRANSMITTANCE_EPS = 1e-4
"""``if (next_T <= 1e-4f)``: the pixel is done, without this Gaussian."""


def fully_fused_projection(
    means, covars, quats, scales, viewmats, Ks, width, height, eps2d=0.3, near_plane=0.01, far_plane=1e10,
    radius_clip=0.0, packed=False, sparse_grad=False, calc_compensations=False, camera_model="pinhole", opacities=None,
):
    """``gsplat.fully_fused_projection`` (unpacked pinhole): radii ``[C, N, 2]`` int32, means2d, depths, conics."""
    if packed or sparse_grad or calc_compensations or camera_model != "pinhole":
        raise NotImplementedError("the test twin covers the unpacked pinhole projection without compensations")
    if covars is None:
        covars, _ = _torch_impl._quat_scale_to_covar_preci(quats, scales, compute_preci=False)
    else:
        covars = covars[..., [0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(covars.shape[:-1] + (3, 3))
    means_c, covars_c = _torch_impl._world_to_cam(means, covars, viewmats)
    depths = means_c[..., 2]
    in_depth = (depths >= near_plane) & (depths <= far_plane)
    # rows behind the near plane never reach the division (the kernel returns before projecting them)
    safe = torch.where(in_depth[..., None], means_c, torch.tensor([0.0, 0.0, 1.0], dtype=means_c.dtype))
    means2d, cov2d = _torch_impl._persp_proj(safe, covars_c, Ks, width, height)
    cov2d = cov2d + eps2d * torch.eye(2, dtype=cov2d.dtype)
    det = cov2d[..., 0, 0] * cov2d[..., 1, 1] - cov2d[..., 0, 1] * cov2d[..., 1, 0]
    keep = in_depth & (det > 0)
    det = torch.where(keep, det, torch.ones_like(det))
    conics = torch.stack([cov2d[..., 1, 1] / det, -cov2d[..., 0, 1] / det, cov2d[..., 0, 0] / det], dim=-1)
    with torch.no_grad():
        extend = torch.full_like(depths, 3.33)
        if opacities is not None:
            o = opacities[..., None, :].expand_as(depths)
            keep = keep & (o >= ALPHA_THRESHOLD)
            extend = torch.minimum(extend, torch.sqrt(2.0 * torch.log((o / ALPHA_THRESHOLD).clamp_min(1.0))))
        diag = torch.stack([cov2d[..., 0, 0], cov2d[..., 1, 1]], dim=-1).detach()
        radius = torch.ceil(extend[..., None] * diag.clamp_min(0).sqrt())
        keep = keep & (radius > radius_clip).any(dim=-1)
        m = means2d.detach()
        keep = keep & (m[..., 0] + radius[..., 0] > 0) & (m[..., 0] - radius[..., 0] < width)
        keep = keep & (m[..., 1] + radius[..., 1] > 0) & (m[..., 1] - radius[..., 1] < height)
        radii = torch.where(keep[..., None], radius, torch.zeros_like(radius)).int()
    nan = torch.tensor(float("nan"), dtype=means2d.dtype)
    means2d = torch.where(keep[..., None], means2d, nan)
    conics = torch.where(keep[..., None], conics, nan)
    depths = torch.where(keep, depths, nan)
    return radii, means2d, depths, conics, None


def spherical_harmonics(degrees_to_use: int, dirs: Tensor, coeffs: Tensor, masks: Tensor | None = None) -> Tensor:
    """``gsplat.spherical_harmonics``: raw SH values ``[..., 3]`` (NaN where ``masks`` is False)."""
    out = _torch_impl._spherical_harmonics(degrees_to_use, dirs, coeffs)
    if masks is not None:
        out = torch.where(masks[..., None], out, torch.tensor(float("nan"), dtype=out.dtype))
    return out


def isect_tiles(means2d, radii, depths, tile_size, tile_width, tile_height, sort=True, segmented=False, packed=False,
                n_images=None, image_ids=None, gaussian_ids=None):
    """``gsplat.isect_tiles`` (unpacked): tiles per Gaussian, intersection ids (image | tile | depth bits), indices."""
    if packed:
        raise NotImplementedError("the test twin covers unpacked inputs")
    return _torch_impl._isect_tiles(means2d, radii, depths, tile_size, tile_width, tile_height, sort)


def isect_offset_encode(isect_ids: Tensor, n_images: int, tile_width: int, tile_height: int) -> Tensor:
    """``gsplat.isect_offset_encode``: the first intersection of each tile ``[I, tile_height, tile_width]``."""
    return _torch_impl._isect_offset_encode(isect_ids, n_images, tile_width, tile_height)


def rasterize_to_pixels(
    means2d, conics, colors, opacities, image_width, image_height, tile_size, isect_offsets, flatten_ids,
    backgrounds=None, masks=None, packed=False, absgrad=False,
):
    """``gsplat.rasterize_to_pixels`` (unpacked): ``[..., H, W, D]`` colours and ``[..., H, W, 1]`` alphas.

    The kernel's loop, vectorised over the pixels of a tile: each tile visits its Gaussians in intersection order
    (depth-sorted) and, per pixel centre (x + 0.5, y + 0.5), with ``d = mean - centre``,
    ``sigma = 0.5 (a dx² + c dy²) + b dx dy``, ``alpha = min(0.999, o·exp(-sigma))``; skips ``sigma < 0`` or
    ``alpha < 1/255``; stops before a Gaussian that would bring ``T`` to ≤ 1e-4; adds ``T·background``.
    Differentiable by autograd.
    """
    if packed or masks is not None or absgrad:
        raise NotImplementedError("the test twin covers unpacked inputs without tile masks or absgrad")
    image_dims = means2d.shape[:-2]
    n, d = means2d.shape[-2], colors.shape[-1]
    n_images = math.prod(image_dims)
    tiles_y, tiles_x = isect_offsets.shape[-2:]
    m_all, con_all = means2d.reshape(n_images * n, 2), conics.reshape(n_images * n, 3)
    col_all, o_all = colors.reshape(n_images * n, d), opacities.reshape(n_images * n)
    starts = isect_offsets.reshape(-1).tolist()
    ends = starts[1:] + [flatten_ids.numel()]
    dtype = means2d.dtype
    images, alphas = [], []
    for i in range(n_images):
        rows_c, rows_a = [], []
        for ty in range(tiles_y):
            tiles_c, tiles_a = [], []
            for tx in range(tiles_x):
                x0, x1 = tx * tile_size, min(image_width, (tx + 1) * tile_size)
                y0, y1 = ty * tile_size, min(image_height, (ty + 1) * tile_size)
                py, px = torch.meshgrid(
                    torch.arange(y0, y1, dtype=dtype) + 0.5, torch.arange(x0, x1, dtype=dtype) + 0.5, indexing="ij"
                )
                px, py = px.reshape(-1), py.reshape(-1)
                t = (i * tiles_y + ty) * tiles_x + tx
                ids = flatten_ids[starts[t] : ends[t]].long()
                m, con, col, o = m_all[ids], con_all[ids], col_all[ids], o_all[ids]
                T = torch.ones_like(px)
                out = torch.zeros(px.shape[0], d, dtype=dtype)
                done = torch.zeros(px.shape[0], dtype=torch.bool)
                for k in range(ids.numel()):
                    dx, dy = m[k, 0] - px, m[k, 1] - py
                    sigma = 0.5 * (con[k, 0] * dx * dx + con[k, 2] * dy * dy) + con[k, 1] * dx * dy
                    alpha = torch.clamp(o[k] * torch.exp(-sigma), max=MAX_ALPHA)
                    live = ~done & (sigma >= 0) & (alpha >= ALPHA_THRESHOLD)
                    next_T = T * (1.0 - alpha)
                    stop = live & (next_T <= TRANSMITTANCE_EPS)
                    done = done | stop
                    use = live & ~stop
                    out = out + torch.where(use, alpha * T, torch.zeros_like(T))[:, None] * col[k]
                    T = torch.where(use, next_T, T)
                if backgrounds is not None:
                    out = out + T[:, None] * backgrounds.reshape(n_images, d)[i]
                tiles_c.append(out.reshape(y1 - y0, x1 - x0, d))
                tiles_a.append((1.0 - T).reshape(y1 - y0, x1 - x0, 1))
            rows_c.append(torch.cat(tiles_c, dim=1))
            rows_a.append(torch.cat(tiles_a, dim=1))
        images.append(torch.cat(rows_c, dim=0))
        alphas.append(torch.cat(rows_a, dim=0))
    shape = image_dims + (image_height, image_width)
    # like the CUDA autograd function's outputs, attached to every input even where no Gaussian reaches a pixel
    link = means2d[..., :0].sum() + conics[..., :0].sum() + colors[..., :0].sum() + opacities[..., :0].sum()
    if backgrounds is not None:
        link = link + backgrounds[..., :0].sum()
    return torch.stack(images).reshape(shape + (d,)) + link, torch.stack(alphas).reshape(shape + (1,)) + link


TWINS = {
    "fully_fused_projection": fully_fused_projection,
    "spherical_harmonics": spherical_harmonics,
    "isect_tiles": isect_tiles,
    "isect_offset_encode": isect_offset_encode,
    "rasterize_to_pixels": rasterize_to_pixels,
}


def install(monkeypatch) -> None:
    """For the rest of the test (pytest's ``monkeypatch``): point ``gsplat.<fn>`` (what abcgs's adapter calls) and
    ``gsplat.rendering.<fn>`` (what ``gsplat.rasterization`` calls) at the twins above, and let
    ``rasterize(..., backend="gsplat")`` take CPU tensors (other backends are selected as usual)."""
    for name, fn in TWINS.items():
        monkeypatch.setattr(gsplat, name, fn)
        monkeypatch.setattr(gsplat.rendering, name, fn)
    module = importlib.import_module("abcgs.render.rasterize")
    select_backend = module.select_backend

    def select_on_cpu(device: torch.device, requested: str = "auto") -> str:
        return "gsplat" if requested == "gsplat" else select_backend(device, requested)

    monkeypatch.setattr(module, "select_backend", select_on_cpu)
