"""Fast CPU backend: a C++ torch extension (``csrc/rasterize_cpu.cpp``) with a hand-written backward pass.

The extension is compiled on first use with ``torch.utils.cpp_extension.load`` (needs a C++17 compiler
and ninja, both installed by ``make``) and cached under ``$ABCGS_CACHE`` (default ``~/.cache/abcgs``)
in a folder keyed by the source hash, the torch version and the compiler flags, so later processes load it
in well under a second, from any checkout with the same sources (:func:`staged_sources`). If the build fails, :func:`load_extension` raises :class:`BackendUnavailable` with
the compiler's message; ``rasterize(backend="auto")`` then falls back to the reference backend with a
warning. The same extension carries two similarity-search helpers of the style losses (``csrc/knn_cpu.cpp``:
``topk_columns``, ``pair_dots``; used by :mod:`abcgs.style.knn`, which has torch fallbacks for both) and the
fit's fused L1 + SSIM loss (``csrc/image_loss_cpu.cpp``: ``l1_ssim_forward``; used by :mod:`abcgs.fit.losses`,
whose torch code is its reference), so that they share its build and its threads.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import platform
import sys
import threading
import time
from pathlib import Path

import torch
from torch import Tensor

from abcgs.render.projection import Projected

_SOURCES = [
    Path(__file__).parent / "csrc" / n
    for n in ("rasterize_cpu.cpp", "projection_cpu.cpp", "knn_cpu.cpp", "image_loss_cpu.cpp")
]
_HEADERS = [Path(__file__).parent / "csrc" / n for n in ("parallel.h", "vec_width.h")]
# -fno-trapping-math: lets GCC if-convert float compares (the rasterizer's per-row alpha loop only vectorises with
# it); FP exception flags are never read here, and values are unchanged (no reassociation, no contraction).
_FLAGS = ["-O3", "-march=native", "-ffp-contract=off", "-fno-trapping-math", "-std=c++17"]
log = logging.getLogger(__name__)
_lock = threading.Lock()
_module = None
_error: str | None = None


class BackendUnavailable(RuntimeError):
    """The requested rasterizer backend cannot run here (reason in the message)."""


def cache_dir() -> Path:
    return Path(os.environ.get("ABCGS_CACHE", Path.home() / ".cache" / "abcgs"))


def _build_dir() -> Path:
    key = hashlib.sha256()
    for src in _SOURCES + _HEADERS:
        key.update(src.read_bytes())
    key.update(" ".join(_FLAGS).encode())
    key.update(torch.__version__.encode())
    key.update(platform.machine().encode())
    key.update(platform.processor().encode())
    key.update(sys.version.encode())
    return cache_dir() / "ext" / f"rasterize_cpu_{key.hexdigest()[:16]}"


def staged_sources(build: Path) -> list[Path]:
    """The extension's sources (and header) copied into its content-keyed build folder; the build compiles these.

    ``torch.utils.cpp_extension.load`` writes the sources' paths into the build's ``build.ninja``, and ninja
    rebuilds everything when a command's paths change. Compiled from the checkout itself, every other checkout
    with the same sources (a benchmark's or a test's clean copy, a ``dvc exp run --queue`` temporary folder) would
    recompile the extension (about two minutes and 1.5 GiB on 2 cores), and the next process in the first checkout
    again. The copies' paths depend only on the content key, so all of them share one build. A copy is written
    only when missing (a rewrite would give it a new mtime, which ninja also rebuilds for).
    """
    src_dir = build / "src"
    src_dir.mkdir(parents=True, exist_ok=True)
    staged = []
    for src in _SOURCES + _HEADERS:
        dst = src_dir / src.name
        if not dst.exists():
            tmp = dst.with_name(f".{dst.name}.{os.getpid()}.tmp")
            tmp.write_bytes(src.read_bytes())
            os.replace(tmp, dst)
        if src in _SOURCES:
            staged.append(dst)
    return staged


STALE_BUILD_LOCK_S = 600.0
"""A build lock older than this is left by a process killed while compiling (a build takes about a minute)."""


def _clear_stale_build_lock(build: Path, *, stale_s: float = STALE_BUILD_LOCK_S, poll_s: float = 2.0) -> None:
    """Wait while another process holds the build lock; remove the lock once it is older than ``stale_s``.

    ``torch.utils.cpp_extension.load`` guards a build with a ``lock`` file that only its holder deletes, and
    waits for it without a time limit: after a stage was killed mid-compile (Ctrl-C in ``dvc repro``), every
    later process would hang there.
    """
    lock = build / "lock"
    warned = False
    while lock.exists():
        try:
            age = time.time() - lock.stat().st_mtime
        except FileNotFoundError:
            return
        if age > stale_s:
            log.warning("removing a stale build lock %s (%.0f s old: a compile was interrupted)", lock, age)
            lock.unlink(missing_ok=True)
            return
        if not warned:
            log.info("waiting for another process compiling the rasterizer (%s)", lock)
            warned = True
        time.sleep(poll_s)


def load_extension(verbose: bool = False):
    """Compile (first time) and import the C++ extension; raise :class:`BackendUnavailable` on failure."""
    global _module, _error
    with _lock:
        if _module is not None:
            return _module
        if _error is not None:
            raise BackendUnavailable(_error)
        try:
            import ninja  # noqa: F401  (the ninja wheel ships the build tool)

            bin_dir = Path(ninja.BIN_DIR)
            if str(bin_dir) not in os.environ.get("PATH", ""):
                os.environ["PATH"] = f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}"
        except ImportError:
            pass
        try:
            from torch.utils.cpp_extension import load

            build = _build_dir()
            build.mkdir(parents=True, exist_ok=True)
            _clear_stale_build_lock(build)
            _module = load(
                name="abcgs_rasterize_cpu",
                sources=[str(s) for s in staged_sources(build)],
                extra_cflags=_FLAGS,
                build_directory=str(build),
                verbose=verbose,
            )
        except Exception as exc:  # compiler missing, ninja missing, build error
            _error = (
                f"the fast CPU rasterizer could not be built ({type(exc).__name__}: {str(exc).strip()[:2000]}). "
                "It needs a C++17 compiler (g++) and ninja (`pip install ninja`); `make install` sets both up."
            )
            raise BackendUnavailable(_error) from exc
        return _module


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
    """The extension (:func:`load_extension`), or None where it cannot be built here; the reason stays in the
    :class:`BackendUnavailable` that :func:`load_extension` raises."""
    try:
        return load_extension()
    except BackendUnavailable:
        return None


def is_available() -> bool:
    return extension_or_none() is not None


def rasterize_cpu(
    means2d: Tensor, conics: Tensor, colors: Tensor, opacities: Tensor, depths: Tensor, extents: Tensor,
    width: int, height: int, *, tile_size: int = 16,
) -> tuple[Tensor, Tensor]:
    """Fast-backend twin of :func:`abcgs.render.reference.rasterize_reference` (same arguments and outputs)."""
    image, alpha = _RasterizeCPU.apply(means2d, conics, colors, opacities, depths, extents, width, height, tile_size)
    return image, alpha[..., None]


class _RasterizeCPU(torch.autograd.Function):
    """Forward returns (image, alpha); backward passes both output gradients to the C++ kernel."""

    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, depths, extents, width, height, tile_size):
        ext = load_extension()
        means2d, conics, colors = means2d.contiguous(), conics.contiguous(), colors.contiguous()
        opacities, extents = opacities.contiguous(), extents.detach().contiguous().to(colors.dtype)
        depths = depths.detach().contiguous().to(colors.dtype)
        # depth sort (stable radix) and tile binning happen in C++, same order/boxes as the reference backend
        image, trans, last, *binning = ext.rasterize_forward(
            means2d, conics, colors, opacities, depths, extents, width, height, tile_size
        )
        ctx.save_for_backward(means2d, conics, colors, opacities, extents, trans, last, *binning)
        ctx.dims = (width, height, tile_size)
        return image, 1.0 - trans

    @staticmethod
    def backward(ctx, v_image, v_alpha):
        ext = load_extension()
        width, height, tile_size = ctx.dims
        (means2d, conics, colors, opacities, extents, trans, last, *binning) = ctx.saved_tensors
        if v_image is None:
            v_image = torch.zeros(height, width, colors.shape[1], dtype=colors.dtype)
        if v_alpha is None:
            v_alpha = torch.zeros(height, width, dtype=colors.dtype)
        vm, vc, vcol, vo = ext.rasterize_backward(
            means2d, conics, colors, opacities, extents, trans, last, *binning,
            v_image.contiguous(), v_alpha.contiguous(), width, height, tile_size,
        )
        return vm, vc, vcol, vo, None, None, None, None, None


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
