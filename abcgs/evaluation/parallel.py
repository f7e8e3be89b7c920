"""Per-image-pair metrics on several threads, with the same numbers as one thread.

The evaluation's slow part is the perceptual distance of ~50 independent image pairs (content pairs and
consistency pairs; the per-view Gram distances go the same way), VGG-16 forwards that run on ``evaluate.num_threads`` torch threads (1 by default: torch's
intra-op threads spin-wait, and on a shared 2-core machine that makes ops 5–15× slower). Here the pairs are
spread over ``evaluate.workers`` Python threads instead: each runs its ops on the torch thread count the
stage set (torch hands that setting to new threads), so every pair is computed exactly as it would be
alone and the results do not depend on the number of workers. Torch releases the GIL inside its ops, so
the workers use the cores; and they never spin, so on a shared machine they share it like processes do.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import torch

from abcgs.errors import InputError
from abcgs.runtime import available_cores

T = TypeVar("T")
R = TypeVar("R")


def resolve_workers(requested: int) -> int:
    """Threads for per-pair metrics: ``requested`` (≥ 1), or for 0 one per core that torch's intra-op threads
    leave (``cores // torch.get_num_threads()``, at least 1)."""
    if requested < 0:
        raise InputError(f"evaluate.workers must be >= 0 (0 = one per core), got {requested}")
    if requested > 0:
        return requested
    return max(1, available_cores() // max(1, torch.get_num_threads()))


def ordered_map(fn: Callable[[T], R], items: Iterable[T], workers: int) -> list[R]:
    """``[fn(x) for x in items]`` on up to ``workers`` threads, results in ``items``' order; the first
    exception raised by a call is raised here. ``fn`` must be safe to call concurrently."""
    items = list(items)
    if workers <= 1 or len(items) <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(max_workers=min(workers, len(items)), thread_name_prefix="abcgs-eval") as pool:
        return list(pool.map(fn, items))
