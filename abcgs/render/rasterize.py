"""The public rasterizer API (gsplat's shape): one function, backends behind it.

    image, alpha, meta = rasterize(means, quats, scales, opacities, colors, viewmat, K, width, height)

Backends:
    ``"reference"`` pure PyTorch (readable spec, test oracle; any device),
    ``"cpu"``       compiled C++ kernel with a hand-written backward (CPU tensors),
    ``"gsplat"``    ``gsplat.rasterization`` (CUDA tensors; optional dependency),
    ``"auto"``      (default) gsplat for CUDA tensors, the compiled kernel for CPU tensors, falling back to
                    the reference backend with a warning when the preferred one cannot run.
The environment variable ``ABCGS_RENDER_BACKEND`` overrides ``"auto"``. A backend named explicitly never
falls back: it runs or raises :class:`BackendUnavailable`.

Every backend has one path, over a batch of C cameras (gsplat's ``viewmats [C, 4, 4]``): one camera renders as a
batch of one, and its outputs and gradients are those of the batch bit for bit (``tests/test_render_batched.py``).
"""

from __future__ import annotations

import functools
import math
import os
import re
import typing
import warnings
from collections.abc import Sequence
from dataclasses import fields, replace

import torch
from torch import Tensor

from abcgs.render import cpu as cpu_backend
from abcgs.render.cpu import BackendUnavailable
from abcgs.render.projection import Projected, project_gaussians, screen_bounds
from abcgs.render.reference import rasterize_reference
from abcgs.render.sh import sh_to_color
from abcgs.types import Backend, RenderMeta, RenderMode

BACKENDS: tuple[Backend, ...] = typing.get_args(Backend)
_warned: set[str] = set()


def select_backend(device: torch.device, requested: Backend = "auto") -> Backend:
    """Resolve ``requested`` (or ``$ABCGS_RENDER_BACKEND`` when ``"auto"``) to a runnable backend name."""
    if requested == "auto":
        requested = os.environ.get("ABCGS_RENDER_BACKEND", "auto") or "auto"
    if requested not in BACKENDS:
        raise ValueError(f"unknown rasterizer backend {requested!r}; choose one of {BACKENDS}")
    if requested == "gsplat":
        if device.type != "cuda":
            raise BackendUnavailable("the gsplat backend needs CUDA tensors; use backend='cpu' or 'reference' on the CPU")
        _import_gsplat()
        return "gsplat"
    if requested == "cpu":
        if device.type != "cpu":
            raise BackendUnavailable("the cpu backend needs CPU tensors")
        cpu_backend.load_extension()
        return "cpu"
    if requested == "reference":
        return "reference"
    # auto
    if device.type == "cuda":
        try:
            _import_gsplat()
            return "gsplat"
        except BackendUnavailable as exc:
            _warn_once("gsplat", f"{exc}; falling back to the (slow) reference rasterizer")
            return "reference"
    if device.type == "cpu":
        try:
            cpu_backend.load_extension()
            return "cpu"
        except BackendUnavailable as exc:
            _warn_once("cpu", f"{exc} Falling back to the (slow) reference rasterizer.")
            return "reference"
    return "reference"


def _warn_once(key: str, message: str) -> None:
    if key not in _warned:
        _warned.add(key)
        warnings.warn(message, RuntimeWarning, stacklevel=3)


GSPLAT_TESTED = ">=1.5,<1.6"
"""The gsplat versions the adapter is tested with (``pyproject.toml``'s ``cuda`` extra; docs/RENDERING.md)."""
_GSPLAT_RANGE = ((1, 5), (1, 6))


def gsplat_version_problem(version: str) -> tuple[str, str] | None:
    """``("refuse" | "warn", message)`` when gsplat ``version`` is outside :data:`GSPLAT_TESTED`, else None.

    Versions below 1.5 have another API (one radius per Gaussian, no opacity-aware projection) and are refused;
    newer ones are used with a warning, since their conventions may have moved.
    """
    match = re.match(r"(\d+)\.(\d+)", version)
    fix = f"pip install 'gsplat{GSPLAT_TESTED}'"
    if match is None:
        return "warn", f"gsplat reports the version {version!r}, which abcgs cannot read (tested: gsplat{GSPLAT_TESTED}); {fix}"
    found = (int(match[1]), int(match[2]))
    if found < _GSPLAT_RANGE[0]:
        return "refuse", (
            f"gsplat {version} is older than the gsplat backend supports (tested: gsplat{GSPLAT_TESTED}; before 1.5 "
            f"the projection returns one radius per Gaussian and takes no opacities); {fix}"
        )
    if found >= _GSPLAT_RANGE[1]:
        return "warn", (
            f"gsplat {version} is untested with abcgs (tested: gsplat{GSPLAT_TESTED}); its conventions may differ from "
            f"those in docs/RENDERING.md ('gsplat conventions'): check with `pytest -m cuda tests/test_gsplat_adapter.py` "
            f"or {fix}"
        )
    return None


def _import_gsplat():
    try:
        import gsplat
    except Exception as exc:
        raise BackendUnavailable(f"gsplat is not importable ({exc}); install it with `pip install 'gsplat{GSPLAT_TESTED}'`") from exc
    problem = gsplat_version_problem(str(getattr(gsplat, "__version__", "unknown")))
    if problem is not None:
        kind, message = problem
        if kind == "refuse":
            raise BackendUnavailable(message)
        _warn_once("gsplat-version", message)
    return gsplat


def rasterize(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor | Sequence[Tensor],
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    *,
    sh_degree: int | None = None,
    background: Tensor | None = None,
    render_mode: RenderMode = "RGB",
    near: float = 0.01,
    far: float = 1e10,
    eps2d: float = 0.3,
    tile_size: int = 16,
    backend: Backend = "auto",
) -> tuple[Tensor, Tensor, RenderMeta]:
    """Render N 3-D Gaussians into one pinhole view or a batch of C views of one size (differentiable in every
    float input).

    Args:
        means: ``(N, 3)`` world positions (world units).
        quats: ``(N, 4)`` rotations, wxyz, any norm (normalised inside the graph).
        scales: ``(N, 3)`` standard deviations along the local axes (world units, not log).
        opacities: ``(N,)`` in [0, 1] (not logits).
        colors: ``(N, D)`` any number of channels, or SH coefficients ``(N, K, 3)`` with ``sh_degree`` set, which
            may come as two blocks along K, the DC band ``(N, 1, 3)`` and the higher bands ``(N, K - 1, 3)``
            (as :class:`abcgs.gaussians.GaussianModel` stores them: the CPU backend then builds no ``(N, K, 3)``
            copy). The CPU backend evaluates SH only for the Gaussians the projection keeps.
        viewmats: ``(4, 4)`` world→camera (OpenCV axes), or ``(C, 4, 4)`` for C cameras (gsplat's ``viewmats``).
        Ks: ``(3, 3)`` intrinsics in px, or ``(C, 3, 3)``, batched like ``viewmats``.
        width, height: output size in px (every camera of a batch renders at this size).
        sh_degree: evaluate ``colors`` as SH of this degree (0..3); ``None`` = plain colours.
        background: ``(D,)`` colour composited behind: ``image + (1 - alpha) · background``; with C cameras also
            ``(C, D)``, one per view.
        render_mode: ``RGB``; ``RGB+D`` also returns the accumulated depth Σ T_i α_i z_i in ``meta.depth``
            ``(H, W, 1)`` (world units × alpha); ``RGB+ED`` the expected depth, that divided by alpha where
            alpha > 0 (gsplat's modes of the same names).
        near, far: clip planes on camera z. eps2d: px² added to the projected covariance.
        backend: see the module docstring.

    Returns:
        image ``(H, W, D)``, alpha ``(H, W, 1)``, :class:`RenderMeta` for one camera; for C cameras image
        ``(C, H, W, D)``, alpha ``(C, H, W, 1)`` and a :class:`RenderMeta` whose fields have a leading camera axis.
        Each view of a batch equals its one-camera render exactly, and the gradients of the per-Gaussian inputs are
        the sums over the views. The CPU kernels take the whole batch in one call per pass (the loop over cameras
        runs in C++); gsplat takes it as its batch; the reference backend renders view by view.
    """
    if width < 1 or height < 1:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    n_cameras = camera_batch(viewmats, Ks)
    if n_cameras is not None and background is not None and background.dim() == 2 and background.shape[0] != n_cameras:
        raise ValueError(f"background must be (D,) or ({n_cameras}, D) for {n_cameras} cameras, got {tuple(background.shape)}")
    name = select_backend(means.device, backend)
    single = n_cameras is None  # one camera renders as a batch of one
    if single:
        viewmats, Ks = viewmats[None], Ks[None]
    impl = _rasterize_gsplat if name == "gsplat" else functools.partial(_rasterize_batch, name)
    image, alpha, meta = impl(
        means, quats, scales, opacities, colors, viewmats, Ks, width, height, single=single, sh_degree=sh_degree,
        background=background, render_mode=render_mode, near=near, far=far, eps2d=eps2d, tile_size=tile_size,
    )
    return (image[0], alpha[0], meta) if single else (image, alpha, meta)


def camera_batch(viewmats: Tensor, Ks: Tensor) -> int | None:
    """The number of cameras C of batched ``viewmats`` ``(C, 4, 4)`` and ``Ks`` ``(C, 3, 3)``; None for one camera
    (``(4, 4)`` and ``(3, 3)``). Raises ValueError naming the argument for any other shape or a mismatch."""
    if viewmats.dim() not in (2, 3) or tuple(viewmats.shape[-2:]) != (4, 4):
        raise ValueError(f"viewmats must be (4, 4) or (C, 4, 4), got {tuple(viewmats.shape)}")
    if Ks.dim() not in (2, 3) or tuple(Ks.shape[-2:]) != (3, 3):
        raise ValueError(f"Ks must be (3, 3) or (C, 3, 3), got {tuple(Ks.shape)}")
    if viewmats.dim() != Ks.dim():
        raise ValueError(
            f"viewmats {tuple(viewmats.shape)} and Ks {tuple(Ks.shape)}: give both for one camera or both batched"
        )
    if viewmats.dim() == 2:
        return None
    if viewmats.shape[0] != Ks.shape[0]:
        raise ValueError(f"viewmats has {viewmats.shape[0]} cameras but Ks has {Ks.shape[0]}")
    if viewmats.shape[0] == 0:
        raise ValueError("viewmats: a batch of cameras needs at least one camera, got (0, 4, 4)")
    return int(viewmats.shape[0])


def _rasterize_batch(
    name: Backend, means, quats, scales, opacities, colors, viewmats, Ks, width, height, *, single, sh_degree,
    background, render_mode, near, far, eps2d, tile_size,
) -> tuple[Tensor, Tensor, RenderMeta]:
    """:func:`rasterize` for C cameras on the CPU kernels or the reference backend (gsplat: :func:`_rasterize_gsplat`):
    image ``(C, H, W, D)``, alpha ``(C, H, W, 1)`` and the meta, of the one camera when ``single`` (C = 1).

    The CPU kernels project (with the SH colours) and blend all views in one call each (``csrc/batch_cpu.cpp``).
    The reference backend, and the CPU backend when a camera takes gradients, project view by view with
    :func:`project_gaussians` and stack the views; the reference backend then blends view by view too."""
    n_cameras = viewmats.shape[0]
    depth_channel = render_mode != "RGB"
    camera_grad = viewmats.requires_grad or Ks.requires_grad
    if name == "cpu" and not camera_grad:
        sh0, shN = sh_blocks(colors) if sh_degree is not None else (None, None)
        proj, sh_colors = cpu_backend.project_batch_cpu(
            means, quats, scales, opacities, viewmats, Ks, width, height, near=near, far=far, eps2d=eps2d,
            sh_degree=sh_degree, sh0=sh0, shN=shN,
        )
        colors = colors if sh_colors is None else sh_colors
    else:
        views = [project_gaussians(means, quats, scales, opacities, viewmats[c], Ks[c], width, height, near=near,
                                   far=far, eps2d=eps2d) for c in range(n_cameras)]
        proj = Projected(*(torch.stack([getattr(v, f.name) for v in views]) for f in fields(Projected)))
        if sh_degree is not None and name == "cpu":
            sh0, shN = sh_blocks(colors)
            colors = torch.stack([cpu_backend.sh_colors_cpu(sh_degree, sh0, shN, means, camera_position(viewmats[c]),
                                                             proj.visible[c]) for c in range(n_cameras)])
        elif sh_degree is not None:
            coeffs = sh_coefficients(colors)
            colors = torch.stack([sh_to_color(sh_degree, coeffs, means, camera_position(viewmats[c]))
                                  for c in range(n_cameras)])
    n_color = colors.shape[-1]
    means2d, meta_means2d = _screen_positions(proj.means2d, single)
    if name == "cpu":
        out, alpha = cpu_backend.rasterize_batch_cpu(
            means2d, proj.conics, colors, opacities, proj.depths, proj.extents, width, height,
            tile_size=tile_size, depth_channel=depth_channel,
        )
    else:
        views = []
        for c in range(n_cameras):
            col = colors[c] if colors.dim() == 3 else colors
            feats = torch.cat([col, proj.depths[c][:, None]], dim=1) if depth_channel else col
            views.append(rasterize_reference(means2d[c], proj.conics[c], feats, opacities, proj.depths[c],
                                             proj.extents[c], width, height, tile_size=tile_size))
        out, alpha = torch.stack([v[0] for v in views]), torch.stack([v[1] for v in views])
    if background is not None and background.dim() == 2:
        background = background[:, None, None, :]
    image, depth = _finish(out, alpha, n_color, render_mode, background)
    meta = RenderMeta(proj.means2d, proj.radii, proj.depths, proj.visible, depth, name, width, height)
    return image, alpha, replace(meta.view(0), means2d=meta_means2d) if single else meta


def _screen_positions(means2d: Tensor, single: bool) -> tuple[Tensor, Tensor]:
    """The projected means ``(C, N, 2)`` the blend reads, and the tensor ``meta.means2d`` returns. For one camera that
    is its ``(N, 2)`` row taken before the blend, which reads it back as a batch of one: ``retain_grad()`` on a row
    taken after the blend would stay without a gradient."""
    if not single:
        return means2d, means2d
    row = means2d[0]
    return row[None], row


def sh_blocks(colors: Tensor | Sequence[Tensor]) -> tuple[Tensor, Tensor]:
    """The DC band ``(N, 1, 3)`` and the higher bands ``(N, K - 1, 3)`` of SH coefficients given as one tensor or as
    those two blocks."""
    return tuple(colors) if isinstance(colors, (tuple, list)) else (colors[:, :1], colors[:, 1:])


def sh_coefficients(colors: Tensor | Sequence[Tensor]) -> Tensor:
    """SH coefficients ``(N, K, 3)`` given as one tensor or as blocks along K (the DC band and the higher bands)."""
    return torch.cat(list(colors), dim=1) if isinstance(colors, (tuple, list)) else colors


def camera_position(viewmat: Tensor) -> Tensor:
    """World position ``(3,)`` of the camera of a rigid world→camera ``viewmat`` ``(4, 4)``; ``(C, 3)`` for
    ``(C, 4, 4)``."""
    if viewmat.dim() == 3:
        R, t = viewmat[:, :3, :3], viewmat[:, :3, 3]
        return (-R.mT @ t[..., None])[..., 0]
    R, t = viewmat[:3, :3], viewmat[:3, 3]
    return -R.T @ t


def _finish(out: Tensor, alpha: Tensor, n_color: int, render_mode: RenderMode, background):
    """Split the blended features ``(H, W, C [+ 1])`` into image and depth; normalise an expected depth; add the
    background."""
    image, depth = out[..., :n_color], None
    if render_mode != "RGB":
        depth = out[..., n_color:]
        if render_mode == "RGB+ED":
            depth = torch.where(alpha > 0, depth / alpha.clamp_min(1e-10), torch.zeros_like(depth))
    if background is not None:
        image = image + (1.0 - alpha) * background.to(image)
    return image, depth


GSPLAT_CHANNEL_CHUNK = 32
"""Channels per ``gsplat.rasterize_to_pixels`` call (``gsplat.rasterization``'s ``channel_chunk``)."""


def _rasterize_gsplat(
    means, quats, scales, opacities, colors, viewmats, Ks, width, height, *, single, sh_degree, background,
    render_mode, near, far, eps2d, tile_size,
):
    """``rasterize`` on gsplat's kernels: the steps of ``gsplat.rasterization`` (unpacked) for C cameras, which gsplat
    takes as its own batch, composed here so that ``meta.means2d`` is the tensor the rasterizer reads (of the one
    camera when ``single``: :func:`_screen_positions`). Conventions: docs/RENDERING.md, "gsplat conventions"."""
    gsplat = _import_gsplat()
    n_cameras = viewmats.shape[0]
    radii_c, means2d_c, depths_c, conics, _ = gsplat.fully_fused_projection(
        means, None, quats, scales, viewmats, Ks, width, height, eps2d=eps2d, near_plane=near, far_plane=far,
        opacities=opacities,
    )
    kept = (radii_c > 0).all(dim=-1)  # (C, N)
    # gsplat's CUDA projection leaves the rows of the Gaussians it culls unwritten (torch.empty): never read them.
    means2d, means2d_out = _screen_positions(torch.where(kept[..., None], means2d_c, torch.zeros_like(means2d_c)),
                                             single)
    z = (means @ viewmats[:, 2, :3].T + viewmats[:, 2, 3]).T
    depths = torch.where(kept, depths_c, z)
    if sh_degree is not None:
        coeffs = sh_coefficients(colors)
        dirs = means[None] - camera_position(viewmats)[:, None]
        sh = gsplat.spherical_harmonics(sh_degree, dirs, coeffs.expand(n_cameras, *coeffs.shape), masks=kept)
        colors = torch.clamp_min(sh + 0.5, 0.0)
    colors = colors.expand(n_cameras, *colors.shape) if colors.dim() == 2 else colors
    n_color = colors.shape[-1]
    feats = torch.cat([colors, depths[..., None]], dim=-1) if render_mode != "RGB" else colors
    tiles_x, tiles_y = math.ceil(width / tile_size), math.ceil(height / tile_size)
    _, isect_ids, flatten_ids = gsplat.isect_tiles(means2d, radii_c, depths, tile_size, tiles_x, tiles_y)
    isect_offsets = gsplat.isect_offset_encode(isect_ids, n_cameras, tiles_x, tiles_y).reshape(n_cameras, tiles_y, tiles_x)
    opacities_c = opacities.expand(n_cameras, *opacities.shape)
    chunks, alpha = [], None
    for chunk in feats.split(GSPLAT_CHANNEL_CHUNK, dim=-1):
        out_c, alpha_c = gsplat.rasterize_to_pixels(
            means2d, conics, chunk, opacities_c, width, height, tile_size, isect_offsets, flatten_ids,
        )
        chunks.append(out_c)
        alpha = alpha_c if alpha is None else alpha
    out = torch.cat(chunks, dim=-1)
    if background is not None and background.dim() == 2:
        background = background[:, None, None, :]
    image, depth = _finish(out, alpha, n_color, render_mode, background)
    # gsplat keeps a Gaussian when its integer, opacity-aware radius box overlaps the image; meta.visible and
    # meta.radii follow the other backends' rule (the float box of alpha ≥ 1/255, 3.33-sigma radii), so that the
    # densifier's statistics do not depend on the backend. The 2-D covariance is the inverse of the conic.
    with torch.no_grad():
        a, b, c = conics.detach().unbind(-1)
        det = a * c - b * b
        cov_diag = torch.where(kept[..., None], torch.stack([c / det, a / det], dim=-1), torch.zeros_like(conics[..., :2]))
        _, radii, visible = screen_bounds(means2d.detach(), cov_diag, opacities, kept, width, height)
    meta = RenderMeta(means2d, radii, depths, visible, depth, "gsplat", width, height)
    return image, alpha, replace(meta.view(0), means2d=means2d_out) if single else meta


def accumulate_weights(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    viewmat: Tensor,
    K: Tensor,
    pixel_weights: Tensor,
    *,
    backend: Backend = "auto",
    **kwargs,
) -> Tensor:
    """Per-Gaussian sums of blending weight × pixel weight (ABC-GS Eq. 2).

    ``w[i, j] = Σ_p α_i(p) T_i(p) M_j(p)`` for pixel weight maps ``pixel_weights`` ``(H, W, J)`` (e.g. one-hot
    content masks), returned as ``(N, J)``. It equals the gradient of ``Σ_p image(p)·M(p)`` with respect to
    per-Gaussian colours, so every backend computes it with its own backward pass and nothing of size
    N×H×W is ever built.
    """
    height, width, n_labels = pixel_weights.shape
    with torch.enable_grad():
        probe = torch.zeros(means.shape[0], n_labels, dtype=pixel_weights.dtype, device=means.device, requires_grad=True)
        image, _, _ = rasterize(
            means.detach(), quats.detach(), scales.detach(), opacities.detach(), probe, viewmat, K, width, height,
            backend=backend, **kwargs,
        )
        (grad,) = torch.autograd.grad((image * pixel_weights).sum(), probe)
    return grad
