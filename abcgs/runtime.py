"""Process-wide runtime settings: the device every stage computes on, and torch's thread count for a block of work.

The OpenMP wait policy, which must be set before torch loads, is set in :mod:`abcgs` itself (``abcgs/__init__.py``);
the C++ kernels' own thread count is :func:`abcgs.render.cpu.kernel_threads`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from pydantic import BaseModel, ConfigDict, Field

from abcgs.errors import InputError
from abcgs.types import Device


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
        torch.cuda.synchronize(device)


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run the block with ``torch.set_num_threads(n)`` (``n`` ≤ 0 or None: unchanged), restoring the old value."""
    if n is None or n <= 0:
        yield
        return
    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)
