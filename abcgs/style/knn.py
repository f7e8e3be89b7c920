"""Chunked cosine-similarity k-nearest neighbours between two feature sets.

Features are column matrices: rendered ``F_r`` ``(C, N_r)`` and style ``F_s`` ``(C, N_s)``. The
``N_r × N_s`` similarity matrix is never materialised beyond ``max_block_elems`` entries: it is computed
in tiles (rows = rendered, columns = style) and running top-k lists are merged across tiles, in both
directions at once. Everything here runs without autograd.

The style side does not change during a stylization run: :class:`StyleFeatures` holds it once with its
unit-normalised columns and a row-major copy, so a step normalises and transposes only the rendered side.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from abcgs.errors import InputError

DEFAULT_MAX_BLOCK_ELEMS = 2**22
"""16 MiB of float32 similarities per tile. Below glibc's 32 MiB mmap ceiling, the tile's memory is reused
from the heap instead of being mapped and faulted in anew every step: on fern × Starry Night
(``eval/bench_stylize.py``, 30 steps) the FAST loss took 463 ms per step with 2**22, 511 ms with 2**24."""


def check_feature_pair(f_r: torch.Tensor, f_s: torch.Tensor, what: str = "features") -> None:
    """Raise :class:`InputError` unless ``f_r`` is ``(C, N_r)`` and ``f_s`` is ``(C, N_s)``, both non-empty."""
    if f_r.ndim != 2 or f_s.ndim != 2:
        raise InputError(
            f"{what}: expected (C, N) matrices, got rendered {tuple(f_r.shape)} and style {tuple(f_s.shape)}"
        )
    if f_r.shape[0] != f_s.shape[0]:
        raise InputError(f"{what}: channel counts differ (rendered C={f_r.shape[0]}, style C={f_s.shape[0]})")
    if f_r.shape[1] == 0 or f_s.shape[1] == 0:
        raise InputError(
            f"{what}: empty feature set (rendered N={f_r.shape[1]}, style N={f_s.shape[1]}); "
            "a matching group's mask covers no feature cell"
        )
    if not (f_r.is_floating_point() and f_s.is_floating_point()):
        raise InputError(f"{what}: features must be floating point")


def normalize_columns(f: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """``(C, N)`` → columns scaled to unit L2 norm (zero columns stay zero)."""
    return f / f.norm(dim=0, keepdim=True).clamp_min(eps)


@dataclass(frozen=True)
class StyleFeatures:
    """One matching group's style features, prepared once per run (they are fixed for the whole run).

    ``raw`` ``(C, N_s)`` float, detached; ``unit``: ``raw`` with unit-L2 columns (the cosine search);
    ``rows``: ``raw.T`` contiguous ``(N_s, C)`` (the sparse sums of FAST's pair statistics).
    """

    raw: torch.Tensor
    unit: torch.Tensor
    rows: torch.Tensor

    @classmethod
    def of(cls, f_s: torch.Tensor) -> StyleFeatures:
        """Prepare ``f_s`` ``(C, N_s)``."""
        if f_s.ndim != 2:
            raise InputError(f"style features: expected a (C, N) matrix, got shape {tuple(f_s.shape)}")
        raw = f_s.detach()
        if not bool(torch.isfinite(raw).all()):
            raise InputError("style features contain NaN/Inf (check the style image)")
        return cls(raw, normalize_columns(raw), raw.t().contiguous())

    @property
    def shape(self) -> torch.Size:
        return self.raw.shape


def as_style_features(f_s: torch.Tensor | StyleFeatures) -> StyleFeatures:
    """``f_s`` as :class:`StyleFeatures` (prepared now when a plain tensor is given)."""
    return f_s if isinstance(f_s, StyleFeatures) else StyleFeatures.of(f_s)


def _merge(v_a: torch.Tensor | None, i_a: torch.Tensor | None, v_b: torch.Tensor, i_b: torch.Tensor, k: int, dim: int):
    if v_a is None:
        return v_b, i_b
    v = torch.cat([v_a, v_b], dim=dim)
    i = torch.cat([i_a, i_b], dim=dim)
    top = v.topk(min(k, v.shape[dim]), dim=dim)
    return top.values, i.gather(dim, top.indices)


_COLUMN_BLOCK = 8
"""Rows per block of :func:`topk_rows_of_columns`'s pre-selection."""


def topk_rows_of_columns(sim: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``sim.topk(k, dim=0)`` ``(values, indices)``, each ``(k, n_cols)``, without a strided top-k over all rows.

    ``torch.topk`` along dim 0 of a row-major matrix walks memory with a stride of a whole row, and costs
    about four times the top-k along rows. Here rows are grouped in blocks of :data:`_COLUMN_BLOCK`; a
    contiguous max over each block gives, per column, the ``k`` best blocks, and only their rows are
    searched. Exact: a block holding one of a column's ``k`` largest values has its maximum at or above the
    ``k``-th largest, which no other block reaches (ties may pick another equal value).
    """
    n, m = sim.shape
    b = _COLUMN_BLOCK
    if n <= 4 * b * k:
        return sim.topk(k, dim=0)
    n_blocks = (n + b - 1) // b
    pad = n_blocks * b - n
    s = sim if pad == 0 else torch.cat([sim, sim.new_full((pad, m), float("-inf"))])
    block_max = s.view(n_blocks, b, m).amax(dim=1)  # (n_blocks, m)
    best_blocks = block_max.topk(k, dim=0).indices  # (k, m)
    rows = (best_blocks[:, None, :] * b + torch.arange(b, device=sim.device)[None, :, None]).reshape(k * b, m)
    top = s.gather(0, rows).topk(k, dim=0)
    return top.values, rows.gather(0, top.indices)


def _tiles(n_r: int, n_s: int, max_block_elems: int) -> tuple[int, int]:
    if max_block_elems < 1:
        raise InputError(f"max_block_elems must be >= 1, got {max_block_elems}")
    cols = min(n_s, max_block_elems)
    rows = max(1, min(n_r, max_block_elems // cols))
    return rows, cols


@torch.no_grad()
def cosine_topk(
    f_r: torch.Tensor,
    f_s: torch.Tensor | StyleFeatures,
    k_rs: int,
    k_sr: int,
    *,
    max_block_elems: int = DEFAULT_MAX_BLOCK_ELEMS,
    normalized: bool = False,
) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """k nearest neighbours by cosine similarity in both directions.

    Returns ``(nn_rs, nn_sr)``: ``nn_rs`` ``(N_r, min(k_rs, N_s))`` int64 — for each rendered feature the
    indices of its most similar style features (most similar first); ``nn_sr`` ``(min(k_sr, N_r), N_s)``
    int64 — for each style feature (column) the indices of its most similar rendered features. A
    direction with ``k = 0`` returns None. ``normalized=True`` skips normalising columns (already unit;
    a :class:`StyleFeatures` brings its own unit columns). At most ``max_block_elems`` similarities exist
    at a time.
    """
    if isinstance(f_s, StyleFeatures):
        check_feature_pair(f_r, f_s.raw, "cosine_topk")
        f_r = f_r.detach()
        f_r, f_s = (f_r if normalized else normalize_columns(f_r)), f_s.unit
    else:
        check_feature_pair(f_r, f_s, "cosine_topk")
        f_r = f_r.detach()
        f_s = f_s.detach()
        if not normalized:
            f_r, f_s = normalize_columns(f_r), normalize_columns(f_s)
    n_r, n_s = f_r.shape[1], f_s.shape[1]
    k_rs, k_sr = min(k_rs, n_s), min(k_sr, n_r)
    rows, cols = _tiles(n_r, n_s, max_block_elems)
    f_rt = f_r.t()  # (N_r, C)
    nn_rs = torch.empty(n_r, k_rs, dtype=torch.long, device=f_r.device) if k_rs > 0 else None
    col_starts = list(range(0, n_s, cols))
    best_sr_v: list[torch.Tensor | None] = [None] * len(col_starts)  # running top-k per style column tile
    best_sr_i: list[torch.Tensor | None] = [None] * len(col_starts)
    for r0 in range(0, n_r, rows):
        r1 = min(n_r, r0 + rows)
        v_rs = i_rs = None
        for t, c0 in enumerate(col_starts):
            c1 = min(n_s, c0 + cols)
            sim = f_rt[r0:r1] @ f_s[:, c0:c1]  # (rows, cols)
            if k_rs > 0:
                top = sim.topk(min(k_rs, c1 - c0), dim=1)
                v_rs, i_rs = _merge(v_rs, i_rs, top.values, top.indices + c0, k_rs, dim=1)
            if k_sr > 0:
                vals, idx = topk_rows_of_columns(sim, min(k_sr, r1 - r0))
                best_sr_v[t], best_sr_i[t] = _merge(best_sr_v[t], best_sr_i[t], vals, idx + r0, k_sr, 0)
        if nn_rs is not None:
            nn_rs[r0:r1] = i_rs
    nn_sr = torch.cat(best_sr_i, dim=1) if k_sr > 0 else None  # type: ignore[arg-type]
    return nn_rs, nn_sr


@torch.no_grad()
def mutual_knn_pairs(
    f_r: torch.Tensor,
    f_s: torch.Tensor | StyleFeatures,
    k: int = 5,
    *,
    max_block_elems: int = DEFAULT_MAX_BLOCK_ELEMS,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Nonzero entries of the FAST affinity ``A`` as index lists ``(rows, cols)``, each ``(N_pair,)`` int64.

    ``A_ij = 1`` iff style ``j`` is among rendered ``i``'s k nearest style features OR rendered ``i`` is
    among style ``j``'s k nearest rendered features (cosine similarity). Pairs found in both directions
    appear once; sorted by ``(i, j)``.
    """
    if k < 1:
        raise InputError(f"k must be >= 1, got {k}")
    nn_rs, nn_sr = cosine_topk(f_r, f_s, k, k, max_block_elems=max_block_elems)
    assert nn_rs is not None and nn_sr is not None
    n_r, n_s = f_r.shape[1], nn_sr.shape[1]
    dev = nn_rs.device
    keys_rs = (torch.arange(n_r, device=dev)[:, None] * n_s + nn_rs).reshape(-1)
    keys_sr = (nn_sr * n_s + torch.arange(n_s, device=dev)[None, :]).reshape(-1)
    keys = torch.unique(torch.cat([keys_rs, keys_sr]))
    return keys // n_s, keys % n_s
