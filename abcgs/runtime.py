"""Process-wide runtime settings: torch's thread count for a block of work.

The OpenMP wait policy, which must be set before torch loads, is set in :mod:`abcgs` itself (``abcgs/__init__.py``);
the C++ kernels' own thread count is :func:`abcgs.render.cpu.kernel_threads`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch


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
