"""Rendering with frozen geometry: a view's image as a fixed sparse linear map of the Gaussians' colours.

When means, rotations, scales and opacities do not change (the colour pass with its geometry frozen), every
pixel's blending weights ``w_i(p) = α_i(p) T_i(p)`` and its final transmittance stay the same from step to step:

    image(p) = Σ_i w_i(p) c_i + T_final(p) · background

:func:`record_view` runs the CPU rasterizer's projection, binning and blending once and keeps that map
(:class:`FrozenView`); :func:`render_frozen` then applies it to the colours, and its backward pass applies the
transpose, both in C++ (``csrc/frozen_cpu.cpp``) with the rasterizer's own decisions, so a replayed render equals
:func:`abcgs.render.rasterize` of the same scene. With the higher SH bands frozen as well, a view's colours are
``max(C0 · sh0 + h + 0.5, 0)`` with ``h``, the higher bands' part, fixed per view: a colour step touches only
the DC coefficients of the Gaussians the view blends.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from abcgs.render import cpu as cpu_backend
from abcgs.render.rasterize import camera_position
from abcgs.render.sh import C0, eval_sh


@dataclass(frozen=True)
class FrozenView:
    """One view's recorded blending map (CPU, float32), and the fixed part of its Gaussians' colours.

    ``ids`` ``(G,)`` int64: the Gaussians that blend into at least one pixel, ascending. ``higher`` ``(G, 3)``: the
    SH bands above DC evaluated for this view's directions (zeros for a degree-0 scene). ``trans`` ``(H, W, 1)``:
    the transmittance left behind each pixel. The rest is the map in tile-major runs (``csrc/frozen_cpu.cpp``):
    ``tile_runs`` ``(n_tiles + 1,)``, ``run_group`` ``(R,)`` int32 (a run's row in ``ids``), ``run_entries``
    ``(R + 1,)``, ``entry_pix`` ``(E,)`` uint8, ``entry_w`` ``(E,)`` float32, and each Gaussian's runs
    ``group_runs`` ``(R,)`` / ``group_offsets`` ``(G + 1,)``.
    """

    width: int
    height: int
    tile_size: int
    ids: Tensor
    higher: Tensor
    trans: Tensor
    tile_runs: Tensor
    run_group: Tensor
    run_entries: Tensor
    entry_pix: Tensor
    entry_w: Tensor
    group_runs: Tensor
    group_offsets: Tensor

    @property
    def nbytes(self) -> int:
        """Memory the map holds, in bytes."""
        return sum(t.numel() * t.element_size() for t in (
            self.ids, self.higher, self.trans, self.tile_runs, self.run_group, self.run_entries, self.entry_pix,
            self.entry_w, self.group_runs, self.group_offsets))

    def map_args(self) -> tuple:
        return self.tile_runs, self.run_group, self.run_entries, self.entry_pix, self.entry_w


@torch.no_grad()
def record_view(
    means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, shN: Tensor, sh_degree: int,
    viewmat: Tensor, K: Tensor, width: int, height: int, *, near: float = 0.01, far: float = 1e10,
    eps2d: float = 0.3, tile_size: int = 16,
) -> FrozenView:
    """Record one view's blending map (arguments as :func:`abcgs.render.rasterize`, float32 CPU tensors; ``shN``
    ``(N, K - 1, 3)`` the higher SH bands, fixed from now on, and ``sh_degree`` the degree they are evaluated at)."""
    ext = cpu_backend.load_extension()
    proj = cpu_backend.project_cpu(means, quats, scales, opacities, viewmat, K, width, height, near=near, far=far,
                                   eps2d=eps2d)
    trans, tile_runs, run_slot, run_entries, entry_pix, entry_w, order = ext.blend_weights(
        proj.means2d.contiguous(), proj.conics.contiguous(), opacities.contiguous(), proj.depths.contiguous(),
        proj.extents.contiguous(), width, height, tile_size,
    )
    gauss = order.long()[run_slot.long()]
    ids, run_group = torch.unique(gauss, sorted=True, return_inverse=True)
    group_runs = torch.argsort(run_group, stable=True)
    counts = torch.bincount(run_group, minlength=ids.numel())
    group_offsets = torch.zeros(ids.numel() + 1, dtype=torch.long)
    torch.cumsum(counts, 0, out=group_offsets[1:])
    if sh_degree > 0 and shN.shape[1] > 0:
        coeffs = torch.cat([torch.zeros_like(shN[ids, :1]), shN[ids]], dim=1)
        higher = eval_sh(sh_degree, coeffs, means[ids] - camera_position(viewmat))
    else:
        higher = torch.zeros(ids.numel(), 3, dtype=means.dtype)
    return FrozenView(width, height, tile_size, ids, higher.contiguous(), trans[..., None], tile_runs,
                      run_group.int().contiguous(), run_entries, entry_pix, entry_w, group_runs, group_offsets)


class _FrozenBlend(torch.autograd.Function):
    """image = map(colors); the gradient is the transposed map."""

    @staticmethod
    def forward(ctx, colors: Tensor, view: FrozenView) -> Tensor:
        ctx.view = view
        return cpu_backend.load_extension().frozen_blend_forward(
            *view.map_args(), colors.contiguous(), view.width, view.height, view.tile_size)

    @staticmethod
    def backward(ctx, v_image: Tensor):
        view = ctx.view
        v_colors = cpu_backend.load_extension().frozen_blend_backward(
            *view.map_args(), view.group_runs, view.group_offsets, v_image.contiguous(), view.width, view.height,
            view.tile_size)
        return v_colors, None


def blend_frozen(view: FrozenView, colors: Tensor, background: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Image ``(H, W, C)`` and alpha ``(H, W, 1)`` of ``colors`` ``(G, C)`` (one row per ``view.ids``) through the
    recorded map, ``background`` ``(C,)`` composited behind."""
    image = _FrozenBlend.apply(colors, view)
    if background is not None:
        image = image + view.trans * background.to(image)
    return image, 1.0 - view.trans


def render_frozen(view: FrozenView, sh0: Tensor, background: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """:func:`blend_frozen` of the colours ``max(C0 · sh0 + higher + 0.5, 0)`` of the view's Gaussians, from the DC
    coefficients ``sh0`` ``(N, 1, 3)`` of all Gaussians (differentiable in ``sh0``)."""
    colors = (C0 * sh0[view.ids, 0] + view.higher + 0.5).clamp_min(0.0)
    return blend_frozen(view, colors, background)
