"""Reference rasterizer: pure PyTorch, tile-binned, chunked over depth, autograd for the backward pass.

This is the readable specification of the blending rule and the oracle the fast backends are tested
against. Per pixel, Gaussians are visited front to back (sorted by camera z):

    sigma = 0.5 (a dx² + c dy²) + b dx dy,  alpha = min(0.99, o · exp(-sigma))
    skip if sigma < 0 or alpha < 1/255
    stop (without this Gaussian) once T · (1 - alpha) ≤ 1e-4
    C += c · alpha · T;  T ← T · (1 - alpha)

Memory stays bounded: each tile's work is wrapped in activation checkpointing and processes its
Gaussians in depth chunks, carrying the transmittance across chunks.
"""

from __future__ import annotations

import math

import torch
import torch.utils.checkpoint
from torch import Tensor

from abcgs.render.projection import ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_EPS


def tile_ranges(means2d: Tensor, extents: Tensor, width: int, height: int, tile_size: int) -> Tensor:
    """Inclusive tile index ranges ``(N, 4)`` int64 = (tx0, ty0, tx1, ty1) of each Gaussian's box.

    A Gaussian touches tile (tx, ty) when its box ``means2d ± extents`` overlaps the tile's pixel
    centres. Rows with zero extent get an empty range (tx0 > tx1).
    """
    m, e = means2d.detach(), extents.detach()
    # pixel centre of column x is x + 0.5: a box [lo, hi] covers centres x with lo <= x + 0.5 <= hi
    x0 = torch.ceil(m[:, 0] - e[:, 0] - 0.5).clamp(0, width - 1)
    x1 = torch.floor(m[:, 0] + e[:, 0] - 0.5).clamp(0, width - 1)
    y0 = torch.ceil(m[:, 1] - e[:, 1] - 0.5).clamp(0, height - 1)
    y1 = torch.floor(m[:, 1] + e[:, 1] - 0.5).clamp(0, height - 1)
    r = torch.stack([x0 // tile_size, y0 // tile_size, x1 // tile_size, y1 // tile_size], -1).long()
    empty = (e[:, 0] <= 0) | (m[:, 0] + e[:, 0] - 0.5 < x0) | (m[:, 1] + e[:, 1] - 0.5 < y0)
    empty |= (m[:, 0] - e[:, 0] - 0.5 > x1) | (m[:, 1] - e[:, 1] - 0.5 > y1)
    r[empty] = torch.tensor([1, 1, 0, 0])
    return r


def _blend_tile(px: Tensor, py: Tensor, means2d: Tensor, conics: Tensor, opacities: Tensor, colors: Tensor, chunk: int):
    """Blend one tile's depth-sorted Gaussians; returns (colour (P, C), final transmittance (P,))."""
    P = px.shape[0]
    T = torch.ones(P, dtype=colors.dtype, device=colors.device)
    done = torch.zeros(P, dtype=torch.bool, device=colors.device)
    out = torch.zeros(P, colors.shape[1], dtype=colors.dtype, device=colors.device)
    for s in range(0, means2d.shape[0], chunk):
        m, con, o, col = means2d[s : s + chunk], conics[s : s + chunk], opacities[s : s + chunk], colors[s : s + chunk]
        dx = px[:, None] - m[None, :, 0]
        dy = py[:, None] - m[None, :, 1]
        sigma = 0.5 * (con[None, :, 0] * dx * dx + con[None, :, 2] * dy * dy) + con[None, :, 1] * dx * dy
        alpha = torch.clamp(o[None, :] * torch.exp(-sigma), max=MAX_ALPHA)
        valid = (sigma >= 0) & (alpha >= ALPHA_THRESHOLD)
        alpha = torch.where(valid, alpha, torch.zeros_like(alpha))
        one_minus = 1.0 - alpha
        t_after = T[:, None] * torch.cumprod(one_minus, dim=1)
        t_before = torch.cat([T[:, None], t_after[:, :-1]], dim=1)
        include = (t_after > TRANSMITTANCE_EPS) & ~done[:, None]
        weights = torch.where(include, alpha * t_before, torch.zeros_like(alpha))
        out = out + weights @ col
        T = T * torch.where(include, one_minus, torch.ones_like(one_minus)).prod(dim=1)
        done = done | (t_after <= TRANSMITTANCE_EPS).any(dim=1)
        if bool(done.all()):
            break
    return out, T


def rasterize_reference(
    means2d: Tensor,
    conics: Tensor,
    colors: Tensor,
    opacities: Tensor,
    depths: Tensor,
    extents: Tensor,
    width: int,
    height: int,
    *,
    tile_size: int = 16,
    chunk: int = 512,
    checkpoint: bool = True,
) -> tuple[Tensor, Tensor]:
    """Alpha-blend projected Gaussians into an image.

    Args:
        means2d ``(N, 2)`` px, conics ``(N, 3)``, colors ``(N, C)``, opacities ``(N,)``,
        depths ``(N,)`` sort keys, extents ``(N, 2)`` px (0 = culled).
    Returns:
        image ``(H, W, C)`` without background, alpha ``(H, W, 1)``.
    """
    C = colors.shape[1]
    dtype, device = colors.dtype, colors.device
    image = torch.zeros(height, width, C, dtype=dtype, device=device)
    trans = torch.ones(height, width, dtype=dtype, device=device)
    # Keep the outputs attached to every input's graph (zero gradients, like the other backends) even when
    # no Gaussian reaches any tile, so backward() / autograd.grad on an empty view does not raise. Empty
    # slices never read the values, so this stays finite even for inf/NaN rows of culled Gaussians.
    link = means2d[:0].sum() + conics[:0].sum() + colors[:0].sum() + opacities[:0].sum()
    vis = torch.nonzero(extents[:, 0] > 0).squeeze(1)
    if vis.numel() == 0:
        return image + link, (1.0 - trans)[..., None] + link
    vis = vis[torch.argsort(depths.detach()[vis], stable=True)]
    ranges = tile_ranges(means2d[vis], extents[vis], width, height, tile_size)
    tw, th = math.ceil(width / tile_size), math.ceil(height / tile_size)
    rows = []
    for ty in range(th):
        y0, y1 = ty * tile_size, min(height, (ty + 1) * tile_size)
        row = []
        for tx in range(tw):
            x0, x1 = tx * tile_size, min(width, (tx + 1) * tile_size)
            hit = (ranges[:, 0] <= tx) & (ranges[:, 2] >= tx) & (ranges[:, 1] <= ty) & (ranges[:, 3] >= ty)
            ids = vis[hit]
            ys, xs = torch.meshgrid(
                torch.arange(y0, y1, dtype=dtype, device=device) + 0.5,
                torch.arange(x0, x1, dtype=dtype, device=device) + 0.5,
                indexing="ij",
            )
            px, py = xs.reshape(-1), ys.reshape(-1)
            if ids.numel() == 0:
                tile_img = torch.zeros(px.shape[0], C, dtype=dtype, device=device)
                tile_T = torch.ones(px.shape[0], dtype=dtype, device=device)
            else:
                args = (px, py, means2d[ids], conics[ids], opacities[ids], colors[ids])
                if checkpoint and torch.is_grad_enabled():
                    tile_img, tile_T = torch.utils.checkpoint.checkpoint(_blend_tile, *args, chunk, use_reentrant=False)
                else:
                    tile_img, tile_T = _blend_tile(*args, chunk)
            row.append((tile_img.reshape(y1 - y0, x1 - x0, C), tile_T.reshape(y1 - y0, x1 - x0)))
        rows.append(row)
    image = torch.cat([torch.cat([t[0] for t in row], dim=1) for row in rows], dim=0)
    trans = torch.cat([torch.cat([t[1] for t in row], dim=1) for row in rows], dim=0)
    return image + link, (1.0 - trans)[..., None] + link


def rasterize_brute_force(
    means2d: Tensor, conics: Tensor, colors: Tensor, opacities: Tensor, depths: Tensor, extents: Tensor, width: int, height: int
) -> tuple[Tensor, Tensor]:
    """Untiled oracle: every visible Gaussian against every pixel (for tests on tiny scenes only)."""
    vis = torch.nonzero(extents[:, 0] > 0).squeeze(1)
    vis = vis[torch.argsort(depths.detach()[vis], stable=True)]
    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=colors.dtype) + 0.5, torch.arange(width, dtype=colors.dtype) + 0.5, indexing="ij"
    )
    img, T = _blend_tile(xs.reshape(-1), ys.reshape(-1), means2d[vis], conics[vis], opacities[vis], colors[vis], 1 << 30)
    return img.reshape(height, width, -1), (1.0 - T).reshape(height, width, 1)
