"""Timing helper shared by the micro-benchmarks in ``eval/``."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import torch


def repeat_seconds(fn: Callable[[], object], repeats: int) -> list[float]:
    """Wall seconds of ``repeats`` calls of ``fn`` after one untimed warm-up call (allocator, kernels, caches).

    CUDA work is synchronised before and after each call, so the times cover the device's work too.
    """

    def sync() -> None:
        if torch.cuda.is_available():
            torch.cuda.synchronize()

    fn()
    times = []
    for _ in range(repeats):
        sync()
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    return times


def median_ms(fn: Callable[[], object], repeats: int) -> float:
    """Median milliseconds of ``repeats`` timed calls of ``fn`` (:func:`repeat_seconds`: one warm-up call first)."""
    return 1000.0 * statistics.median(repeat_seconds(fn, repeats))
