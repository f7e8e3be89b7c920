"""Process-wide runtime settings: :func:`setup`, which every entry point calls before it imports torch; the device
every stage computes on; torch's thread count for a block of work.

Importing abcgs changes nothing in the process; the entry points (``stages/*.py``, ``eval/``, ``python -m abcgs…``,
the test session) call :func:`setup` first. The C++ kernels' own thread count is
:func:`abcgs.render.cpu.kernel_threads`. This module loads torch only inside the functions that use it, so that
importing it to call :func:`setup` loads nothing that reads OpenMP's settings.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys
from collections.abc import Iterator
from typing import TYPE_CHECKING

from pydantic import BaseModel, ConfigDict, Field

from abcgs.errors import InputError
from abcgs.types import Device

if TYPE_CHECKING:
    import torch


def available_cores() -> int:
    """Cores this process may run on: its affinity mask where the OS has one (a Slurm allocation, ``taskset``), else
    ``os.cpu_count()``."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def setup(threads: int | None = None) -> bool:
    """The process-wide settings of an abcgs program; call it before anything imports torch.

    - OpenMP's wait policy: ``OMP_WAIT_POLICY=PASSIVE`` unless the variable is set (a value set by the user always
      wins). The CPU path alternates torch's OpenMP regions (VGG, Adam, small tensor ops) with the C++ kernels' own
      threads (:mod:`abcgs.render.cpu`); under GNU OpenMP's default policy torch's idle workers spin after each
      region and take cores from those threads, and passive waiting makes the fit and the stylization faster with
      identical results (docs/SCALING.md "One machine: the queue", "Threads and `-j`"). libgomp reads the variable
      when it loads, at torch's first import, so once torch is loaded the environment is left alone.
    - OpenCV is loaded before pycolmap can be: pycolmap's bundled zlib otherwise captures libz's internal calls and
      the next ``cv2.imencode`` of a PNG aborts with "double free or corruption".
    - glibc's allocator keeps large blocks (:func:`keep_large_allocations`).
    - ``threads`` (> 0): torch's intra-op thread count (``torch.set_num_threads``); None leaves torch's default.

    Returns whether torch was still unloaded, i.e. whether the wait policy takes effect in this process.
    """
    before_torch = "torch" not in sys.modules
    if before_torch:
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    importlib.import_module("cv2")  # before pycolmap: see above
    keep_large_allocations()

    if threads is not None and threads > 0:
        import torch

        torch.set_num_threads(threads)
    return before_torch


MMAP_THRESHOLD_BYTES = 256 * 2**20
"""Blocks below this come from glibc's heap instead of their own ``mmap`` (glibc's default threshold is at most
32 MiB)."""
TRIM_THRESHOLD_BYTES = 2**30
"""Free memory at the top of glibc's heap kept for the next allocations instead of given back (default 128 KiB)."""
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # mallopt's parameter numbers (glibc's malloc.h)


def keep_large_allocations() -> bool:
    """Have glibc's ``malloc`` serve blocks up to :data:`MMAP_THRESHOLD_BYTES` from its heap and keep up to
    :data:`TRIM_THRESHOLD_BYTES` of freed heap: a step on a few million Gaussians allocates and frees tens of tensors
    of 10–50 MB, which by default are each a fresh ``mmap`` whose every page faults in zeroed on first touch (a
    quarter of a 3 M-Gaussian stylization step: docs/SCALING.md "Large splats"); kept, they are reused. Peak
    memory is the working set's either way. A no-op (False) off glibc or where ``MALLOC_MMAP_THRESHOLD_`` or
    ``MALLOC_TRIM_THRESHOLD_`` is set (the user's choice wins)."""
    if sys.platform != "linux" or any(k in os.environ for k in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")):
        return False
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl)
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))


def release_free_memory() -> bool:
    """Give the free memory :func:`keep_large_allocations` keeps back to the system (glibc's ``malloc_trim``): called
    where a loop of large steps ends, so that what follows starts from the memory it uses. False off glibc."""
    if sys.platform != "linux":
        return False
    import ctypes

    try:
        return bool(ctypes.CDLL("libc.so.6").malloc_trim(0))
    except (OSError, AttributeError):
        return False


class RuntimeParams(BaseModel):
    """``runtime:``: how every stage runs, not what it computes (:mod:`abcgs.runtime`)."""

    model_config = ConfigDict(extra="forbid")

    device: Device = Field(
        "auto", description="auto | cpu | cuda: where every stage keeps its tensors (scenes, images, VGG, losses, "
                            "metrics); the renders follow (gsplat on CUDA, the C++ kernels on the CPU)")


def resolve_device(setting: Device | str = "auto") -> torch.device:
    """``runtime.device`` as a :class:`torch.device`: ``auto`` is CUDA when torch sees a GPU, else the CPU.

    Raises :class:`InputError` for ``cuda`` on a machine where torch sees no GPU (a CPU build of torch, no driver).
    """
    import torch

    if setting == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if setting == "cuda" and not torch.cuda.is_available():
        raise InputError("runtime.device is 'cuda' but torch sees no CUDA GPU (a CPU build of torch, or no driver); "
                         "set runtime.device: auto or cpu")
    if setting not in ("cpu", "cuda"):
        raise InputError(f"runtime.device must be auto, cpu or cuda, got {setting!r}")
    return torch.device(setting)


def synchronize(device: torch.device) -> None:
    """Wait for the device's queued work (CUDA runs asynchronously), so that a wall-clock split of a step is honest;
    a no-op on the CPU."""
    if device.type == "cuda":
        import torch

        torch.cuda.synchronize(device)


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run the block with ``torch.set_num_threads(n)`` (``n`` ≤ 0 or None: unchanged), restoring the old value."""
    if n is None or n <= 0:
        yield
        return
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)
