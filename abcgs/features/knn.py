"""Chunked cosine-similarity k-nearest neighbours between two feature sets.

Features are column matrices: rendered ``F_r`` ``(C, N_r)`` and style ``F_s`` ``(C, N_s)``. The
``N_r × N_s`` similarity matrix is never materialised beyond ``max_block_elems`` entries: it is computed
in tiles (rows = rendered, columns = style) and running top-k lists are merged across tiles, in both
directions at once. Everything here runs without autograd.

The style side does not change during a stylization run: :class:`StyleFeatures` holds it once with its
unit-normalised columns and a row-major copy, so a step normalises and transposes only the rendered side.

Two searches give the same neighbour sets (``search``):

- ``exact``: float32 similarities, top-k of each tile merged across tiles;
- ``bf16``: a *certified* search. The similarities are computed in bfloat16 (oneDNN's bf16 GEMM, faster than
  the float32 product on a CPU with AVX512-BF16), with a proven bound ``δ`` on their error from the
  columns' own rounding residuals (``|uᵀv − ũᵀṽ| ≤ ‖u−ũ‖ + ‖ũ‖‖v−ṽ‖``, plus float32 accumulation and the
  bf16 rounding of the result). Each feature takes its ``K`` best approximate candidates; when the k-th
  and the (K+1)-th approximate similarities differ by more than ``2δ``, no feature outside the candidates
  can be among the true k best, and the candidates are re-ranked with exact float32 dot products
  (:func:`pair_dots`). Features that fail the test get the exact float32 search (their share on fern, and the
  speed of the bf16 product: ``docs/measurements/settings.yaml``, ``knn_bf16_certified_search``). The result equals the exact search's up to ties
  within float32 rounding (the re-ranking sums in another order than the float32 product).

``auto`` picks ``bf16`` on a CPU whose oneDNN runs bf16 natively and for at least :data:`BF16_MIN_ELEMS`
similarities, else ``exact``.

A third search is approximate and therefore a separate setting (:class:`Projection`, ``stylize.fast.projection_rank``),
not a value of ``search``: each feature's candidates come from the similarities of the features projected onto the
``rank`` principal directions of the painting's unit features (computed once per run), ``candidates`` per feature in
each direction, found from the ``N_r × N_s`` projected products without storing them
(``topk_dots_both`` in ``abcgs/render/csrc/knn_cpu.cpp``); the candidates are then re-ranked by their exact
similarities. A true neighbour is missed only when it falls outside the candidates; ``eval/bench/knn_recall.py``
measures how often on real stylization features (the recall is printed and recorded in docs/SCALING.md). The
projected products may be taken in bfloat16 (:attr:`Projection.products`; by default where the CPU has AVX512-BF16):
that changes which candidates are kept, never the exact re-ranking.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Literal

import torch

from abcgs.errors import InputError, NumericalError
from abcgs.features.bf16 import bf16_matmul_is_native, bf16_similarity_bound, bf16_with_residuals
from abcgs.features.params import DEFAULT_MAX_BLOCK_ELEMS
from abcgs.types import CandidateProducts, KnnSearch, ProjectionSettings

BF16_MIN_ELEMS = 2**22
"""``search="auto"`` uses the bf16 search from this many similarities (``N_r · N_s``) on: below it the float32
product is cheap and the certification's fixed costs do not pay (the tiny scene stays on the exact path)."""

BF16_CANDIDATES = 16
"""Candidates per feature of the bf16 search (K): the more, the more features are certified; the rest fall back to
the exact search (the share certified by K: ``docs/measurements/settings.yaml``, ``knn_bf16_certified_search``)."""


@functools.lru_cache(maxsize=1)
def bf16_dot_available() -> bool:
    """Whether the CPU kernels' extension here has the AVX512-BF16 candidate products (``topk_dots_both``'s
    ``bf16_products``: the ``x86_64_v4_bf16`` kernel variant, on a CPU with AVX512-BF16 and AVX512-VL)."""
    ext = _cpu_kernels()
    return ext is not None and bool(ext.bf16_dot_available())


@dataclass(frozen=True)
class Projection:
    """The approximate neighbour search (module docstring): candidates from ``rank``-dimensional projections onto the
    painting's principal feature directions, ``candidates`` per feature and direction, re-ranked exactly."""

    rank: int
    candidates: int = 16
    min_similarities: int = 0
    """Searches of fewer ``N_r · N_s`` similarities run exactly instead (cheap there)."""
    products: CandidateProducts = "float32"
    """The projected products that pick the candidates: ``float32``, ``bfloat16`` (the projected features rounded to
    bf16, products summed in float32: the AVX512-BF16 kernel, twice the multiply-adds per instruction; elsewhere the
    same rounding followed by a float32 product) or ``auto`` (bfloat16 where the kernel has it,
    :func:`bf16_dot_available`). Only the candidates depend on it: they are re-ranked by exact similarities."""

    def __post_init__(self) -> None:
        if self.rank < 1 or self.candidates < 1:
            raise InputError(f"projection search: rank and candidates must be >= 1, got {self.rank}, {self.candidates}")
        if self.products not in ("auto", "float32", "bfloat16"):
            raise InputError(f"projection search: products must be auto, float32 or bfloat16, got {self.products!r}")

    def bf16_products(self) -> bool:
        """Whether the candidates come from bf16 products here (``auto`` resolved on this machine)."""
        return self.products == "bfloat16" or (self.products == "auto" and bf16_dot_available())

    def applies(self, n_r: int, n_s: int, channels: int, device: torch.device) -> bool:
        """Whether the projected search runs for an ``n_r × n_s`` search over ``channels``-dimensional features on
        ``device``: on the CPU only (a GPU runs the exact product quickly; there the approximation buys nothing)."""
        return device.type == "cpu" and self.rank < channels and n_r * n_s >= self.min_similarities


def projection_of(params: ProjectionSettings) -> Projection | None:
    """The approximate search that ``stylize.fast`` asks for (``projection_rank > 0``), or None for the exact one."""
    if params.projection_rank == 0:
        return None
    return Projection(params.projection_rank, params.projection_candidates, params.projection_min_similarities,
                      params.projection_products)


def resolve_search(search: KnnSearch, n_r: int, n_s: int, device: torch.device) -> Literal["exact", "bf16"]:
    """The search ``search`` means for ``n_r × n_s`` similarities on ``device`` (see the module docstring)."""
    if search not in ("auto", "exact", "bf16"):
        raise InputError(f"knn search must be 'auto', 'exact' or 'bf16', got {search!r}")
    if search == "auto":
        native = device.type == "cpu" and bf16_matmul_is_native()
        return "bf16" if native and n_r * n_s >= BF16_MIN_ELEMS else "exact"
    return search


def pair_dots(a: torch.Tensor, b: torch.Tensor, ia: torch.Tensor, ib: torch.Tensor) -> torch.Tensor:
    """``out[p] = a[ia[p]] · b[ib[p]]`` for row-major float32 ``a`` ``(N_a, C)``, ``b`` ``(N_b, C)`` → ``(P,)``.

    The CPU kernels' extension computes it without gathering rows (``abcgs/render/csrc/knn_cpu.cpp``);
    elsewhere, or when the extension is unavailable, a chunked gather + batched product does.
    """
    if a.device.type == "cpu" and a.dtype == torch.float32 and b.dtype == torch.float32:
        ext = _cpu_kernels()
        if ext is not None:
            return ext.pair_dots(a, b, ia, ib)
    out = a.new_empty(ia.numel())
    step = 1 << 14
    for p0 in range(0, ia.numel(), step):
        x, y = a[ia[p0 : p0 + step]], b[ib[p0 : p0 + step]]
        out[p0 : p0 + step] = torch.bmm(x[:, None, :], y[:, :, None]).reshape(-1)
    return out


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
    _projections: dict = field(default_factory=dict, compare=False, repr=False)

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

    @functools.cached_property
    def unit_rows(self) -> torch.Tensor:
        """``unit.T`` contiguous ``(N_s, C)`` float32 (exact re-ranking of the bf16 and the projected searches)."""
        return self.unit.t().contiguous()

    def projection(self, rank: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``(basis (rank, C), projected rows (N_s, rank))``: the ``rank`` leading eigenvectors of ``unit unitᵀ`` (the
        directions that keep most of the unit features' energy, so that projected dot products approximate the
        cosine similarities best) and the unit features in that basis. Computed once per rank."""
        if rank not in self._projections:
            unit = self.unit.double()
            _, vecs = torch.linalg.eigh(unit @ unit.t())  # ascending eigenvalues
            basis = vecs[:, -rank:].flip(1).t().to(self.unit.dtype).contiguous()
            self._projections[rank] = (basis, (basis @ self.unit).t().contiguous())
        return self._projections[rank]

    @functools.cached_property
    def unit_bf16(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(unit`` in bfloat16 ``(C, N_s)``, each column's rounding residual ``‖u − bf16(u)‖`` ``(N_s,))``."""
        return bf16_with_residuals(self.unit, dim=0)


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


def _cpu_kernels():
    """The CPU kernels' extension when it is available here, else None (one cached load, no second attempt)."""
    from abcgs.render.cpu import extension_or_none

    return extension_or_none()


def topk_rows_of_columns(sim: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``sim.topk(k, dim=0)`` ``(values, indices)``, each ``(k, n_cols)``, without a strided top-k over all rows.

    ``torch.topk`` along dim 0 of a row-major matrix walks memory with a stride of a whole row, and costs
    about four times the top-k along rows. On the CPU the kernels' extension makes one pass over the rows in
    memory order, keeping each column's k best (``topk_columns`` in ``abcgs/render/csrc/knn_cpu.cpp``; float32
    values, also for a bfloat16 ``sim``). Elsewhere rows are grouped in blocks of :data:`_COLUMN_BLOCK`; a
    contiguous max over each block gives, per column, the ``k`` best blocks, and only their rows are
    searched. Exact: a block holding one of a column's ``k`` largest values has its maximum at or above the
    ``k``-th largest, which no other block reaches (ties may pick another equal value).
    """
    if sim.device.type == "cpu" and sim.dtype in (torch.float32, torch.bfloat16) and 1 <= k <= sim.shape[0]:
        ext = _cpu_kernels()
        if ext is not None:
            vals, idx = ext.topk_columns(sim, k)
            return vals.to(sim.dtype), idx
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


def _tiled_topk(a_rows: torch.Tensor, b: torch.Tensor, k_rs: int, k_sr: int, max_block_elems: int):
    """Top-k of ``S = a_rows @ b`` (``(N_r, C) @ (C, N_s)``) along both axes, tile by tile.

    Returns ``(v_rs, i_rs, v_sr, i_sr)``: ``(N_r, k_rs)`` values/indices of each row's largest entries and
    ``(k_sr, N_s)`` of each column's (None for a direction with k = 0), in ``S``'s dtype, largest first.
    """
    n_r, n_s = a_rows.shape[0], b.shape[1]
    rows, cols = _tiles(n_r, n_s, max_block_elems)
    col_starts = list(range(0, n_s, cols))
    rs_v: list[torch.Tensor] = []
    rs_i: list[torch.Tensor] = []
    best_sr_v: list[torch.Tensor | None] = [None] * len(col_starts)  # running top-k per style column tile
    best_sr_i: list[torch.Tensor | None] = [None] * len(col_starts)
    for r0 in range(0, n_r, rows):
        r1 = min(n_r, r0 + rows)
        v_rs = i_rs = None
        for t, c0 in enumerate(col_starts):
            c1 = min(n_s, c0 + cols)
            sim = a_rows[r0:r1] @ b[:, c0:c1]  # (rows, cols)
            if k_rs > 0:
                top = sim.topk(min(k_rs, c1 - c0), dim=1)
                v_rs, i_rs = _merge(v_rs, i_rs, top.values, top.indices + c0, k_rs, dim=1)
            if k_sr > 0:
                vals, idx = topk_rows_of_columns(sim, min(k_sr, r1 - r0))
                best_sr_v[t], best_sr_i[t] = _merge(best_sr_v[t], best_sr_i[t], vals, idx + r0, k_sr, 0)
        if k_rs > 0:
            rs_v.append(v_rs)
            rs_i.append(i_rs)
    if k_rs > 0:
        out_rs = (torch.cat(rs_v), torch.cat(rs_i))
    else:
        out_rs = (None, None)
    out_sr = (torch.cat(best_sr_v, dim=1), torch.cat(best_sr_i, dim=1)) if k_sr > 0 else (None, None)  # type: ignore[arg-type]
    return (*out_rs, *out_sr)


def _certified_topk(
    v: torch.Tensor,
    cand: torch.Tensor,
    delta: torch.Tensor,
    k: int,
    n_cand: int,
    own: torch.Tensor,
    other: torch.Tensor,
    exact_rows,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Resolve one direction of the bf16 search (one row per feature searched for).

    ``v`` ``(N, K')`` float32 approximate similarities of each feature's ``K'`` best candidates ``cand``
    (largest first; ``K' = n_cand + 1``, or every feature of the other side when it has no more), ``delta``
    ``(N,)`` the error bound. ``own`` ``(N, C)`` and ``other`` ``(M, C)``: the float32 unit rows of the two sides
    (the candidates are re-ranked by their exact products, :func:`_rerank`); ``exact_rows(idx)`` → the exact top-k
    indices ``(len(idx), k)`` of whole features. Returns
    ``(top-k indices (N, k), certified (N,))``; uncertified features got ``exact_rows``.
    """
    n, kk = cand.shape
    if kk > n_cand:  # a (K+1)-th candidate exists: the gap test applies
        certified = (v[:, k - 1] - v[:, kk - 1]) > 2.0 * delta
        cand = cand[:, : kk - 1]
    else:  # every feature of the other side is a candidate: nothing outside them to miss
        certified = torch.ones(n, dtype=torch.bool, device=v.device)
    out = _rerank(own, other, cand.contiguous(), k)
    bad = (~certified).nonzero()[:, 0]
    if bad.numel() > 0:
        out[bad] = exact_rows(bad)
    return out, certified


def _bf16_topk(u_r: torch.Tensor, style: StyleFeatures, k_rs: int, k_sr: int, max_block_elems: int):
    """The certified bf16 search (module docstring) on unit ``u_r`` ``(C, N_r)`` and ``style``'s unit columns."""
    n_r, n_s = u_r.shape[1], style.shape[1]
    c = u_r.shape[0]
    u_s = style.unit
    s_low, e_s = style.unit_bf16
    ur_rows = u_r.t().contiguous()  # (N_r, C) float32
    r_low, e_r = bf16_with_residuals(ur_rows, dim=1)
    kc_rs, kc_sr = max(BF16_CANDIDATES, k_rs), max(BF16_CANDIDATES, k_sr)
    v_rs, i_rs, v_sr, i_sr = _tiled_topk(
        r_low, s_low, min(kc_rs + 1, n_s) if k_rs > 0 else 0, min(kc_sr + 1, n_r) if k_sr > 0 else 0, max_block_elems
    )
    s_rows = style.unit_rows
    nn_rs = nn_sr = None
    if k_rs > 0:
        nn_rs, _ = _certified_topk(
            v_rs.float(), i_rs, bf16_similarity_bound(e_r, float(e_s.max()), c), k_rs, kc_rs,
            ur_rows, s_rows, lambda idx: _tiled_topk(ur_rows[idx], u_s, k_rs, 0, max_block_elems)[1],
        )  # fmt: skip
    if k_sr > 0:
        nn_sr_t, _ = _certified_topk(
            v_sr.float().t(), i_sr.t(), bf16_similarity_bound(e_s, float(e_r.max()), c), k_sr, kc_sr,
            s_rows, ur_rows, lambda idx: _tiled_topk(s_rows[idx], u_r, k_sr, 0, max_block_elems)[1],
        )  # fmt: skip
        nn_sr = nn_sr_t.t().contiguous()
    return nn_rs, nn_sr


def _rerank(own: torch.Tensor, other: torch.Tensor, cand: torch.Tensor, k: int) -> torch.Tensor:
    """Of each row's candidates ``cand`` ``(N, K)`` (rows of ``other`` ``(M, C)``), the ``k`` with the largest exact
    dot products with ``own`` ``(N, C)``: ``(N, k)``, largest first (the kernels' ``rerank_topk``, else torch)."""
    if bool((cand < 0).any()):
        raise NumericalError("neighbour search: a feature found no candidates (non-finite features?)")
    ext = _cpu_kernels() if own.device.type == "cpu" and own.dtype == torch.float32 else None
    if ext is not None:
        return ext.rerank_topk(own, other, cand, k)
    rows = torch.arange(cand.shape[0], device=cand.device)[:, None].expand_as(cand).reshape(-1)
    exact = pair_dots(own, other, rows, cand.reshape(-1)).view(cand.shape)
    return cand.gather(1, exact.topk(k, dim=1).indices)


def _projected_topk(f_r: torch.Tensor, style: StyleFeatures, k_rs: int, k_sr: int, projection: Projection):
    """The approximate search (module docstring) on ``f_r`` ``(C, N_r)`` (any scale):
    ``(nn_rs (N_r, k_rs), nn_sr (N_s, k_sr))``, None for a direction with k = 0."""
    n_r, n_s = f_r.shape[1], style.shape[1]
    basis, s_proj = style.projection(projection.rank)
    ur_rows = f_r.t().contiguous()  # (N_r, C), scaled to unit rows in place (zero rows stay zero)
    ur_rows.mul_((ur_rows * ur_rows).sum(dim=1, keepdim=True).sqrt_().clamp_min_(1e-8).reciprocal_())
    r_proj = ur_rows @ basis.t()  # (N_r, rank)
    kc_rs = min(max(projection.candidates, k_rs), n_s) if k_rs > 0 else 0
    kc_sr = min(max(projection.candidates, k_sr), n_r) if k_sr > 0 else 0
    ext = _cpu_kernels() if f_r.device.type == "cpu" and f_r.dtype == torch.float32 else None
    bf16 = projection.bf16_products()
    if ext is not None and (not bf16 or bf16_dot_available()):
        cand_rs, _, cand_sr, _ = ext.topk_dots_both(r_proj, s_proj, kc_rs, kc_sr, bf16)
    else:  # torch: bf16 products as the kernel's, the rounded features multiplied in float32 (another summation order)
        if bf16:
            r_proj, s_proj = r_proj.bfloat16().float(), s_proj.bfloat16().float()
        _, cand_rs, _, cand_sr_t = _tiled_topk(r_proj, s_proj.t(), kc_rs, kc_sr, DEFAULT_MAX_BLOCK_ELEMS)
        cand_sr = cand_sr_t.t() if cand_sr_t is not None else None
    nn_rs = _rerank(ur_rows, style.unit_rows, cand_rs, k_rs) if k_rs > 0 else None
    nn_sr = _rerank(style.unit_rows, ur_rows, cand_sr, k_sr) if k_sr > 0 else None
    return nn_rs, nn_sr


@torch.no_grad()
def cosine_topk(
    f_r: torch.Tensor,
    f_s: torch.Tensor | StyleFeatures,
    k_rs: int,
    k_sr: int,
    *,
    max_block_elems: int = DEFAULT_MAX_BLOCK_ELEMS,
    normalized: bool = False,
    search: KnnSearch = "exact",
    projection: Projection | None = None,
) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """k nearest neighbours by cosine similarity in both directions.

    Returns ``(nn_rs, nn_sr)``: ``nn_rs`` ``(N_r, min(k_rs, N_s))`` int64 — for each rendered feature the
    indices of its most similar style features (most similar first); ``nn_sr`` ``(min(k_sr, N_r), N_s)``
    int64 — for each style feature (column) the indices of its most similar rendered features. A
    direction with ``k = 0`` returns None. ``normalized=True`` skips normalising columns (already unit;
    a :class:`StyleFeatures` brings its own unit columns). At most ``max_block_elems`` similarities exist
    at a time. ``search``: ``exact``, ``bf16`` (certified, same sets) or ``auto`` (module docstring).
    ``projection``: the approximate search instead (module docstring; ``search`` is then unused) on the CPU, where it
    has fewer dimensions than the features and the search is large enough (:meth:`Projection.applies`).
    """
    style = f_s if isinstance(f_s, StyleFeatures) else None
    check_feature_pair(f_r, style.raw if style is not None else f_s, "cosine_topk")
    f_r = f_r.detach()
    n_r, n_s = f_r.shape[1], f_s.shape[1]
    k_rs, k_sr = min(k_rs, n_s), min(k_sr, n_r)
    if projection is not None and projection.applies(n_r, n_s, f_r.shape[0], f_r.device):  # normalises rows itself
        style = style if style is not None else StyleFeatures.of(f_s)
        nn_rs, nn_sr = _projected_topk(f_r, style, k_rs, k_sr, projection)
        return nn_rs, (nn_sr.t().contiguous() if nn_sr is not None else None)
    if not normalized:
        f_r = normalize_columns(f_r)
    if resolve_search(search, n_r, n_s, f_r.device) == "bf16" and f_r.dtype == torch.float32:
        if style is None:
            style = StyleFeatures.of(f_s)
        return _bf16_topk(f_r, style, k_rs, k_sr, max_block_elems)
    if style is not None:
        u_s = style.unit
    else:
        u_s = f_s.detach() if normalized else normalize_columns(f_s.detach())
    _, i_rs, _, i_sr = _tiled_topk(f_r.t(), u_s, k_rs, k_sr, max_block_elems)
    return i_rs, i_sr


@torch.no_grad()
def mutual_knn_pairs(
    f_r: torch.Tensor,
    f_s: torch.Tensor | StyleFeatures,
    k: int = 5,
    *,
    max_block_elems: int = DEFAULT_MAX_BLOCK_ELEMS,
    search: KnnSearch = "exact",
    projection: Projection | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Nonzero entries of the FAST affinity ``A`` as index lists ``(rows, cols)``, each ``(N_pair,)`` int64.

    ``A_ij = 1`` iff style ``j`` is among rendered ``i``'s k nearest style features OR rendered ``i`` is
    among style ``j``'s k nearest rendered features (cosine similarity). Pairs found in both directions
    appear once; sorted by ``(i, j)``. ``search``, ``projection``: see :func:`cosine_topk`.
    """
    if k < 1:
        raise InputError(f"k must be >= 1, got {k}")
    nn_rs, nn_sr = cosine_topk(f_r, f_s, k, k, max_block_elems=max_block_elems, search=search, projection=projection)
    assert nn_rs is not None and nn_sr is not None
    n_r, n_s = f_r.shape[1], nn_sr.shape[1]
    dev = nn_rs.device
    keys_rs = (torch.arange(n_r, device=dev)[:, None] * n_s + nn_rs).reshape(-1)
    keys_sr = (nn_sr * n_s + torch.arange(n_s, device=dev)[None, :]).reshape(-1)
    keys = torch.unique(torch.cat([keys_rs, keys_sr]))
    return keys // n_s, keys % n_s
