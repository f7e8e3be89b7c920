"""Fast CPU backend: C++ kernels (``csrc/``) for the projection and the rasterizer, with hand-written backward passes.

The kernels are compiled when abcgs is installed (``setup.py``: ``make install``, or ``pip install
--no-build-isolation`` after torch), never at run time. On x86-64 the install builds the best variant the build
machine runs (AVX-512 or AVX2) and a portable one (SSE2), each a module ``abcgs.render._kernels_<variant>``
(:mod:`abcgs.render.kernel_variants`); :func:`load_extension` imports the best variant this CPU runs, in well
under a second. The build record ``_kernels_build.json`` next to the modules says what was built, against which
torch and from which sources. Where the install built no kernels (no torch or no compiler at build time), or the
build no longer fits (``csrc/`` changed after an editable install, another torch is running),
:func:`load_extension` raises :class:`BackendUnavailable` saying why and how to rebuild; ``rasterize(backend="auto")``
then falls back to the reference backend with that warning. A copy of the checkout that was not installed itself
(a benchmark's clean copy, a ``dvc exp`` temporary folder) uses the kernels of the installed abcgs while its
``csrc/`` is the same.

The same modules carry two similarity-search helpers of the style losses (``csrc/knn_cpu.cpp``: ``topk_columns``,
``pair_dots``; used by :mod:`abcgs.features.knn`, which has torch fallbacks for both) and the fit's fused L1 +
SSIM loss (``csrc/image_loss_cpu.cpp``: ``l1_ssim_forward``; used by :mod:`abcgs.fit.losses`, whose torch code is
its reference), so that they share the build and its threads.
"""

from __future__ import annotations

import contextlib
import importlib.machinery
import importlib.metadata
import importlib.util
import json
import platform
import sys
import threading
from pathlib import Path
from urllib.parse import unquote, urlparse

import torch
from torch import Tensor

from abcgs.render import kernel_variants
from abcgs.render.projection import Projected

_HERE = Path(__file__).resolve().parent
_CSRC = _HERE / "csrc"
_lock = threading.Lock()
_module = None
_error: str | None = None


class BackendUnavailable(RuntimeError):
    """The requested rasterizer backend cannot run here (reason in the message)."""


def kernel_dirs() -> list[Path]:
    """Folders that may hold the compiled kernels, in order: this module's, then that of the installed abcgs
    (site-packages, or the source tree of an editable install) when this module is a copy of the checkout."""
    dirs = [_HERE]
    try:
        dist = importlib.metadata.distribution("abcgs")
        dirs.append(Path(dist.locate_file("abcgs/render")))
        url = json.loads(dist.read_text("direct_url.json") or "{}").get("url", "")
        if url.startswith("file://"):
            dirs.append(Path(unquote(urlparse(url).path)) / "abcgs" / "render")
    except (importlib.metadata.PackageNotFoundError, ValueError, OSError):
        pass
    return list(dict.fromkeys(d.resolve() for d in dirs))


def read_build_record(folder: Path) -> dict | None:
    path = folder / kernel_variants.RECORD_NAME
    return json.loads(path.read_text()) if path.is_file() else None


def _import_kernels(verbose: bool):
    """The best variant of the first build record found (:func:`kernel_dirs`) that fits these sources, this torch
    and this CPU."""
    folder, record = _HERE, None
    for d in kernel_dirs():
        if (record := read_build_record(d)) is not None:
            folder = d
            break
    problem = kernel_variants.build_problem(record, _CSRC, torch.__version__)
    if problem is not None:
        raise BackendUnavailable(problem)
    capability, bf16 = kernel_variants.torch_cpu_features(torch)
    order = kernel_variants.runnable_variants(platform.machine(), capability, bf16)
    errors = []
    for variant in (v for v in order if v in record["variants"]):
        name = kernel_variants.MODULE_PREFIX + variant
        path = next((folder / (name + s) for s in importlib.machinery.EXTENSION_SUFFIXES
                     if (folder / (name + s)).is_file()), None)
        if path is None:
            errors.append(f"{variant}: no {name}*.so in {folder}")
            continue
        try:
            spec = importlib.util.spec_from_file_location(f"abcgs.render.{name}", path)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        except ImportError as exc:
            errors.append(f"{variant}: {exc}")
            continue
        sys.modules[spec.name] = module
        if verbose:
            print(f"abcgs C++ kernels: {path} (CPU capability {capability})")
        return module
    raise BackendUnavailable(
        f"no C++ kernel variant loads here (built: {record['variants']}; this CPU: {capability}"
        f"{', AVX512-BF16' if bf16 else ''}; {'; '.join(errors) or 'none of them runs on it'}); "
        f"{kernel_variants.REBUILD}."
    )


def load_extension(verbose: bool = False):
    """Import the C++ kernels built at install time (the best variant this CPU runs; ``verbose`` prints which);
    raise :class:`BackendUnavailable` with the reason and the fix where there are none. Nothing is compiled."""
    global _module, _error
    with _lock:
        if _module is not None:
            return _module
        if _error is not None:
            raise BackendUnavailable(_error)
        try:
            _module = _import_kernels(verbose)
        except BackendUnavailable as exc:
            _error = str(exc)
            raise
        return _module


def report() -> bool:
    """Print which kernels this process loads, or why none (``make install`` calls it); True when they load."""
    try:
        print(f"abcgs C++ kernels: {load_extension().__name__}")
        return True
    except BackendUnavailable as exc:
        print(f"warning: {exc}")
        return False


def set_kernel_threads(n: int) -> int:
    """Threads of the C++ kernels' own loops (0 = every hardware thread), independent of torch's intra-op
    setting; returns the previous setting. Results are bit-identical for any count (``csrc/parallel.h``)."""
    return int(load_extension().set_kernel_threads(int(n)))


@contextlib.contextmanager
def kernel_threads(n: int):
    """Run the block with :func:`set_kernel_threads` ``(n)``, restoring the previous setting; a no-op where
    the extension is unavailable (the reference backend has no threads of its own)."""
    try:
        old = set_kernel_threads(n)
    except BackendUnavailable:
        yield
        return
    try:
        yield
    finally:
        set_kernel_threads(old)


def extension_or_none():
    """The extension (:func:`load_extension`), or None where no usable build is installed; the reason stays in the
    :class:`BackendUnavailable` that :func:`load_extension` raises."""
    try:
        return load_extension()
    except BackendUnavailable:
        return None


def is_available() -> bool:
    return extension_or_none() is not None


_scratch_local = threading.local()


def _scratch(numel: int, dtype: torch.dtype) -> Tensor:
    """This thread's buffer for the backward pass's per-intersection gradient rows, grown to ``numel`` values and
    kept between calls: a 3 M-Gaussian view has about 8 M intersections, and a fresh buffer of that size per step
    costs its page faults (docs/SCALING.md, "Large splats")."""
    buf = getattr(_scratch_local, "buffer", None)
    if buf is None or buf.dtype != dtype or buf.numel() < numel:
        _scratch_local.buffer = None  # the old one goes before the new one is allocated
        buf = torch.empty(int(numel * 1.25) + 1024, dtype=dtype)
        _scratch_local.buffer = buf
    return buf


class _ProjectCPU(torch.autograd.Function):
    """Fused projection (C++); gradients flow to means, quats and scales (the camera is constant)."""

    @staticmethod
    def forward(ctx, means, quats, scales, opacities, viewmat, K, width, height, near, far, eps2d):
        ext = load_extension()
        dtype = means.dtype
        means, quats, scales = means.contiguous(), quats.contiguous().to(dtype), scales.contiguous().to(dtype)
        out = ext.project_forward(
            means, quats, scales, opacities.detach().contiguous().to(dtype), viewmat.detach(), K.detach(),
            width, height, near, far, eps2d,
        )
        ctx.save_for_backward(means, quats, scales, viewmat.detach(), K.detach())
        ctx.args = (width, height, near, far, eps2d)
        ctx.mark_non_differentiable(out[3], out[4], out[5])
        return tuple(out)

    @staticmethod
    def backward(ctx, v_means2d, v_conics, v_depths, _ve, _vr, _vv):
        ext = load_extension()
        means, quats, scales, viewmat, K = ctx.saved_tensors
        z = torch.zeros_like
        v_means2d = z(means[:, :2]) if v_means2d is None else v_means2d
        v_conics = z(means) if v_conics is None else v_conics
        v_depths = z(means[:, 0]) if v_depths is None else v_depths
        vm, vq, vs = ext.project_backward(means, quats, scales, viewmat, K, *ctx.args, v_means2d, v_conics, v_depths)
        return vm, vq, vs, None, None, None, None, None, None, None, None


def project_cpu(
    means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, viewmat: Tensor, K: Tensor,
    width: int, height: int, *, near: float = 0.01, far: float = 1e10, eps2d: float = 0.3,
) -> Projected:
    """Compiled twin of :func:`abcgs.render.projection.project_gaussians` (same arguments and outputs)."""
    means2d, conics, depths, extents, radii, visible = _ProjectCPU.apply(
        means, quats, scales, opacities, viewmat, K, width, height, near, far, eps2d
    )
    return Projected(means2d, conics, depths, extents, radii, visible)


class _SHColorsCPU(torch.autograd.Function):
    """Fused SH colours (C++): gradients to the DC band, the higher bands and the means, each only when needed."""

    @staticmethod
    def forward(ctx, sh0, shN, means, campos, mask, degree):
        ext = load_extension()
        dtype = sh0.dtype
        sh0, shN, means = sh0.contiguous(), shN.contiguous().to(dtype), means.contiguous().to(dtype)
        campos, mask = campos.detach().contiguous().to(dtype), mask.contiguous()
        colors = ext.sh_colors_forward(sh0, shN, means, campos, mask, degree)
        ctx.save_for_backward(sh0, shN, means, campos, mask)
        ctx.degree = degree
        return colors

    @staticmethod
    def backward(ctx, v_colors):
        ext = load_extension()
        sh0, shN, means, campos, mask = ctx.saved_tensors
        need_shN, need_means = ctx.needs_input_grad[1], ctx.needs_input_grad[2]
        v_sh0, v_shN, v_means = ext.sh_colors_backward(
            sh0, shN, means, campos, mask, ctx.degree, v_colors.contiguous().to(sh0.dtype), need_shN, need_means
        )
        return v_sh0, v_shN if need_shN else None, v_means if need_means else None, None, None, None


def sh_colors_cpu(degree: int, sh0: Tensor, shN: Tensor, means: Tensor, campos: Tensor, mask: Tensor) -> Tensor:
    """Compiled twin of :func:`abcgs.render.sh.sh_to_color` on the rows of ``mask`` ``(N,)`` bool (others: colour 0,
    gradient 0), taking the DC band ``sh0`` ``(N, 1, 3)`` and the higher bands ``shN`` ``(N, K - 1, 3)`` (K ≥
    (degree + 1)²; ``(N, 0, 3)`` for degree 0) as separate blocks; returns ``(N, 3)``."""
    return _SHColorsCPU.apply(sh0, shN, means, campos, mask, int(degree))


# ------------------------------------------------------------------------------------------------ batched cameras
# One forward and one backward call per batch: the loop over the C cameras runs in C++ (csrc/batch_cpu.cpp), each
# camera through the per-view kernels above, so every view equals its per-view render bit for bit; the gradients of
# per-Gaussian inputs are summed over the cameras in camera order.


class _ProjectBatchCPU(torch.autograd.Function):
    """Projection, and SH colours when ``degree >= 0``, into C cameras: outputs ``(C, N, ·)``; gradients to means,
    quats, scales and the SH blocks, summed over the cameras (the cameras are constant)."""

    @staticmethod
    def forward(ctx, means, quats, scales, opacities, sh0, shN, viewmats, Ks, width, height, near, far, eps2d, degree):
        ext = load_extension()
        dtype = means.dtype
        means, quats, scales = means.contiguous(), quats.contiguous().to(dtype), scales.contiguous().to(dtype)
        if degree >= 0:
            sh0, shN = sh0.contiguous().to(dtype), shN.contiguous().to(dtype)
        else:
            sh0 = shN = means.new_empty(0)
        viewmats, Ks = viewmats.detach().contiguous(), Ks.detach().contiguous()
        out = ext.project_batch_forward(
            means, quats, scales, opacities.detach().contiguous().to(dtype), viewmats, Ks, width, height, near, far,
            eps2d, sh0, shN, degree,
        )
        means2d, conics, depths, extents, radii, visible, colors, campos = out
        ctx.save_for_backward(means, quats, scales, viewmats, Ks, sh0, shN, campos, visible)
        ctx.args = (width, height, near, far, eps2d)
        ctx.degree = degree
        ctx.mark_non_differentiable(extents, radii, visible)
        if degree < 0:
            ctx.mark_non_differentiable(colors)
        return means2d, conics, depths, extents, radii, visible, colors

    @staticmethod
    def backward(ctx, v_means2d, v_conics, v_depths, _ve, _vr, _vv, v_colors):
        ext = load_extension()
        means, quats, scales, viewmats, Ks, sh0, shN, campos, visible = ctx.saved_tensors
        C, n = viewmats.shape[0], means.shape[0]
        zeros = lambda *shape: means.new_zeros(C, n, *shape)  # noqa: E731
        v_means2d = zeros(2) if v_means2d is None else v_means2d.contiguous()
        v_conics = zeros(3) if v_conics is None else v_conics.contiguous()
        v_depths = zeros() if v_depths is None else v_depths.contiguous()
        sh = ctx.degree >= 0 and v_colors is not None
        v_colors = v_colors.contiguous().to(sh0.dtype) if sh else means.new_empty(0)
        need_shN, need_means = ctx.needs_input_grad[5], ctx.needs_input_grad[0]
        vm, vq, vs, v_sh0, v_shN = ext.project_batch_backward(
            means, quats, scales, viewmats, Ks, *ctx.args, v_means2d, v_conics, v_depths, sh0, shN, campos, visible,
            ctx.degree, v_colors, need_shN, need_means,
        )
        v_sh0 = v_sh0 if sh else None
        v_shN = v_shN if sh and need_shN else None
        return vm, vq, vs, None, v_sh0, v_shN, None, None, None, None, None, None, None, None


def project_batch_cpu(
    means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, viewmats: Tensor, Ks: Tensor,
    width: int, height: int, *, near: float = 0.01, far: float = 1e10, eps2d: float = 0.3,
    sh_degree: int | None = None, sh0: Tensor | None = None, shN: Tensor | None = None,
) -> tuple[Projected, Tensor | None]:
    """:func:`project_cpu` (and, with ``sh_degree``, :func:`sh_colors_cpu` on each view's visible Gaussians) for C
    cameras ``viewmats`` ``(C, 4, 4)``, ``Ks`` ``(C, 3, 3)`` in one call: a :class:`Projected` of ``(C, N, ·)``
    fields and the colours ``(C, N, 3)`` (``None`` without ``sh_degree``)."""
    degree = -1 if sh_degree is None else int(sh_degree)
    means2d, conics, depths, extents, radii, visible, colors = _ProjectBatchCPU.apply(
        means, quats, scales, opacities, sh0, shN, viewmats, Ks, width, height, near, far, eps2d, degree
    )
    return Projected(means2d, conics, depths, extents, radii, visible), colors if degree >= 0 else None


class _RasterizeBatchCPU(torch.autograd.Function):
    """The blend of C views (the C++ ``rasterize_forward``/``rasterize_backward`` view by view, depth-sorted and
    tile-binned there in the reference backend's order): colours per view ``(C, N, F)`` or shared ``(N, F)``; with
    ``depth_channel`` each view's depths are blended as channel F (and get its gradient)."""

    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, depths, extents, width, height, tile_size, depth_channel):
        ext = load_extension()
        means2d, conics, colors = means2d.contiguous(), conics.contiguous(), colors.contiguous()
        opacities, extents = opacities.contiguous(), extents.detach().contiguous().to(colors.dtype)
        depths = depths.detach().contiguous().to(colors.dtype)
        save = any(ctx.needs_input_grad[:5])
        image, trans, last, *saved = ext.rasterize_batch_forward(
            means2d, conics, colors, opacities, depths, extents, width, height, tile_size, depth_channel, save
        )
        if save:
            ctx.save_for_backward(means2d, conics, colors, opacities, depths, extents, trans, last, *saved)
        ctx.dims = (width, height, tile_size, depth_channel)
        return image, 1.0 - trans

    @staticmethod
    def backward(ctx, v_image, v_alpha):
        ext = load_extension()
        width, height, tile_size, depth_channel = ctx.dims
        means2d, conics, colors, opacities, depths, extents, trans, last, *saved = ctx.saved_tensors
        C, F = means2d.shape[0], colors.shape[-1] + depth_channel
        if means2d.shape[1] == 0:  # no Gaussian: no gradient (the kernel would index the empty depth column)
            return (torch.zeros_like(means2d), torch.zeros_like(conics), torch.zeros_like(colors),
                    torch.zeros_like(opacities), torch.zeros_like(depths) if depth_channel else None,
                    None, None, None, None, None)
        if v_image is None:
            v_image = colors.new_zeros(C, height, width, F)
        if v_alpha is None:
            v_alpha = colors.new_zeros(C, height, width)
        rows = max(saved[8 * c + 1].numel() for c in range(C)) * (6 + F)
        vm, vc, vcol, vo, vd = ext.rasterize_batch_backward(
            means2d, conics, colors, opacities, depths, extents, trans, last, saved, v_image.contiguous(),
            v_alpha.contiguous(), width, height, tile_size, depth_channel, _scratch(rows, colors.dtype),
        )
        return vm, vc, vcol, vo, vd if depth_channel else None, None, None, None, None, None


def rasterize_batch_cpu(
    means2d: Tensor, conics: Tensor, colors: Tensor, opacities: Tensor, depths: Tensor, extents: Tensor,
    width: int, height: int, *, tile_size: int = 16, depth_channel: bool = False,
) -> tuple[Tensor, Tensor]:
    """The compiled twin of :func:`abcgs.render.reference.rasterize_reference`, for C views in one call: ``means2d``
    ``(C, N, 2)``, ``conics`` ``(C, N, 3)``, ``colors`` ``(C, N, F)`` or ``(N, F)`` (shared by the views),
    ``opacities`` ``(N,)``, ``depths`` ``(C, N)``, ``extents`` ``(C, N, 2)``. With ``depth_channel`` the depths are
    blended as one more channel (``RGB+D``). Returns image ``(C, H, W, F [+ 1])`` without background and alpha
    ``(C, H, W, 1)``."""
    image, alpha = _RasterizeBatchCPU.apply(
        means2d, conics, colors, opacities, depths, extents, width, height, tile_size, bool(depth_channel)
    )
    return image, alpha[..., None]
