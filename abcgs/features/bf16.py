"""bfloat16 products with a proven error bound, for the certified neighbour search (:mod:`abcgs.features.knn`):
whether the CPU multiplies bfloat16 natively, each vector's rounding residual, and the bound on a similarity's error
that follows from them."""

from __future__ import annotations

import functools

import torch

_BF16_ROUNDING = 2.0**-8
"""Unit roundoff of bfloat16 (8 significant bits, round to nearest)."""


@functools.lru_cache(maxsize=1)
def bf16_matmul_is_native() -> bool:
    """Whether this CPU has bfloat16 dot-product instructions (AVX512-BF16 or AMX) for oneDNN's bf16 products;
    without them oneDNN emulates bf16 and the product is no faster than float32."""
    probes = ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
    try:
        native = any(bool(getattr(torch.cpu, name)()) for name in probes if hasattr(torch.cpu, name))
        return native and torch.backends.mkldnn.is_available()
    except RuntimeError:
        return False


def bf16_with_residuals(x: torch.Tensor, dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``x`` rounded to bfloat16, and the norm of each vector's rounding residual ``‖x − bf16(x)‖`` along ``dim``."""
    low = x.to(torch.bfloat16)
    return low, (x - low.float()).norm(dim=dim)


def bf16_similarity_bound(e_self: torch.Tensor, e_other_max: float, channels: int) -> torch.Tensor:
    """Upper bound ``(N,)`` on ``|uᵀv − bf16 product(ũ, ṽ)|`` for unit ``u`` (rounding residuals ``e_self`` =
    ``‖u − ũ‖``) against every unit ``v`` with ``‖v − ṽ‖ ≤ e_other_max``.

    ``|uᵀv − ũᵀṽ| ≤ ‖u−ũ‖‖v‖ + ‖ũ‖‖v−ṽ‖`` with ``‖ũ‖ ≤ 1 + ‖u−ũ‖``; the float32 accumulation of ``C`` exact
    bf16 products adds at most ``C·2⁻²⁴·‖ũ‖‖ṽ‖``; rounding the result to bf16 at most ``2⁻⁸`` of its magnitude.
    """
    acc = channels * 2.0**-24
    mag = (1.0 + e_self) * (1.0 + e_other_max)
    return e_self + (1.0 + e_self) * e_other_max + acc * mag + _BF16_ROUNDING * mag * (1.0 + acc)
