"""FAST: feature alignment style transfer loss (paper Eq. 5–7, supplementary derivation).

For one matching group with rendered features ``F_r`` ``(C, N_r)`` (carrying grad) and style features
``F_s`` ``(C, N_s)``:

- ``A_ij = 1`` iff style ``j`` ∈ kNN_s(rendered ``i``) OR rendered ``i`` ∈ kNN_r(style ``j``), cosine
  similarity, ``k = 5`` (:func:`abcgs.features.knn.mutual_knn_pairs`, chunked, sparse index lists);
- ``U = A / ΣA`` (``ΣA = N_pair``), ``D_r = diag(row sums of U)``;
- ``P = (F_r D_r F_rᵀ + εI)⁻¹ F_r U F_sᵀ`` — the minimiser of ``Σ_ij A_ij ‖Pᵀ v_i − s_j‖²``
  (``ε = 1e-12``), solved by Cholesky (the system is symmetric positive semi-definite plus ``εI``), by LU
  where Cholesky finds it not positive definite (counted), and replaced by the identity on a failed solve
  or a non-finite ``P`` (counted in :class:`FastStats`);
- target ``F_rs = Pᵀ F_r`` computed without grad;
- loss = ``1 − cos(F_r, F_rs)`` averaged, groups summed. The cosine runs along one of two axes
  (:attr:`FastParams.cosine`):

  - ``"pixel"`` (default, the paper's Eq. 7 read per feature vector): for each rendered feature
    (pixel) ``i``, the cosine across channels of ``F_r[:, i]`` and ``F_rs[:, i]``, averaged over pixels —
    the same axis as NNFM's;
  - ``"channel"`` (the authors' code, ``abcgs/loss/fast_loss.py``: ``F.cosine_similarity(a, b, dim=1)``
    on ``(C, N)``): for each channel ``c``, the cosine across the group's pixels of ``F_r[c, :]`` and
    ``F_rs[c, :]``, averaged over channels. Each channel's spatial map is compared up to its scale.

``P`` is formed from the raw (un-normalised) features, the neighbours from cosine similarity. The
products ``F_r D_r F_rᵀ`` and ``F_r U F_sᵀ`` are accumulated in the features' dtype and solved in
``solve_dtype`` (float64 by default: with dead ReLU channels the system is singular up to ``ε`` and float32
loses the decoupling). No dense ``N_r × N_s`` matrix larger than ``max_block_elems``
is ever built. The style side may be passed as :class:`abcgs.features.knn.StyleFeatures`, prepared once per
run (unit columns and a row-major copy), so that a step prepares only the rendered side.

Small groups. A group with fewer features than channels (a region of compositional or semantic transfer smaller
than about a quarter of the view at C = 768) makes ``F_r D_r F_rᵀ`` singular: rank ``N_r < C``. The minimiser is
then still well defined — with linearly independent features, ``Pᵀ v_i`` equals the mean of feature ``i``'s paired
style features exactly, and the ``ε``-ridge solution converges to it — but float32 products leave the null
space's eigenvalues at ±1e-7·‖M‖ instead of 0, far above ``ε``, and the solve amplifies the right-hand side's
float32 rounding along them. Measured on real features (``eval/bench/fast_precision.py``, fern's colour-matched
start × Starry Night, 600-feature bands): float32 products put the target up to 259 % (median 1.6 %) away from the
same formula in float64, and 0.14 % still at ``N_r = 800``; at ``N_r = 1.25 C = 960`` the worst over three paintings
and 40 views each is 3.3·10⁻⁴ (whole views: 1.2·10⁻⁵). Groups with ``N_r < SMALL_GROUP_RATIO · C`` (1.25 C)
therefore form the statistics, the solve and the target in float64 (whatever ``solve_dtype``): ``N_r``-sized
products, cheap for groups this small. The authors' code (float32 products and solve) has the same instability.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import torch
import torch.nn.functional as F

from abcgs.errors import InputError, NumericalError
from abcgs.features import knn
from abcgs.features.knn import (
    StyleFeatures,
    as_style_features,
    check_feature_pair,
    mutual_knn_pairs,
    normalize_columns,
)
from abcgs.losses.params import SMALL_GROUP_RATIO, CosineAxis, FastParams


@dataclass
class FastStats:
    """Running counters of FAST solves (pass one in to see fallbacks)."""

    solves: int = 0
    lu_solves: int = 0
    """Systems Cholesky found not positive definite (numerically), solved by LU instead."""
    fallbacks: int = 0
    """Solves that failed or gave a non-finite ``P`` and used the identity instead."""
    last_pairs: int = 0
    """``N_pair`` of the most recent group."""
    pairs_total: int = 0
    fallback_reasons: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return asdict(self)


def cosine_distance_loss(
    f: torch.Tensor, target: torch.Tensor, eps: float = 1e-8, axis: CosineAxis = "pixel"
) -> torch.Tensor:
    """Mean of ``1 − cos`` between ``f`` and ``target``, both ``(C, N)`` → scalar.

    ``axis="pixel"``: per column (feature vector of one pixel, cosine across the ``C`` channels), mean
    over the ``N`` columns. ``axis="channel"``: per row (one channel's values across the ``N`` pixels),
    mean over the ``C`` rows. Norms get ``+ eps`` (ARF's convention), so zero vectors give distance 1
    with finite gradients (a zero vector's norm has gradient 0, as torch's ``norm``). ``target`` is treated as
    a constant (the losses detach it); the gradient w.r.t. ``f`` is written out in :class:`_CosineDistance`, which
    makes a few passes over the features where the autograd graph of the same formula
    (:func:`cosine_distance_loss_reference`) makes about twice as many.
    """
    if f.shape != target.shape:
        raise InputError(f"cosine_distance_loss: shapes differ {tuple(f.shape)} vs {tuple(target.shape)}")
    if axis not in ("pixel", "channel"):
        raise InputError(f"cosine axis must be 'pixel' or 'channel', got {axis!r}")
    return _CosineDistance.apply(f, target.detach(), 0 if axis == "pixel" else 1, eps)


class _CosineDistance(torch.autograd.Function):
    """``mean(1 − f·t / ((‖f‖ + ε)(‖t‖ + ε)))`` along ``dim``, with the gradient w.r.t. ``f`` only (``t`` constant):
    ``∂/∂f = −(1/n) (t / ((‖f‖ + ε)(‖t‖ + ε)) − cos · f / ((‖f‖ + ε) ‖f‖))``, the second term 0 where ``f = 0``."""

    @staticmethod
    def forward(ctx, f: torch.Tensor, t: torch.Tensor, dim: int, eps: float) -> torch.Tensor:
        f_norm = (f * f).sum(dim, keepdim=True).sqrt()
        t_norm = (t * t).sum(dim, keepdim=True).sqrt()
        denom = (f_norm + eps) * (t_norm + eps)
        cos = (f * t).sum(dim, keepdim=True) / denom
        ctx.save_for_backward(f, t, f_norm, denom, cos)
        ctx.eps = eps
        return (1.0 - cos).mean()

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        f, t, f_norm, denom, cos = ctx.saved_tensors
        scale = -grad / cos.numel()
        f_coef = torch.where(f_norm > 0, cos / ((f_norm + ctx.eps) * f_norm.clamp_min(1e-30)), torch.zeros_like(f_norm))
        grad_f = (t * (scale / denom)).sub_(f * (scale * f_coef))
        return grad_f, None, None, None


def cosine_distance_loss_reference(
    f: torch.Tensor, target: torch.Tensor, eps: float = 1e-8, axis: CosineAxis = "pixel"
) -> torch.Tensor:
    """:func:`cosine_distance_loss` written with torch ops and autograd (the reference its gradient is tested against)."""
    dim = 0 if axis == "pixel" else 1
    a = f / (f.norm(dim=dim, keepdim=True) + eps)
    b = target / (target.norm(dim=dim, keepdim=True) + eps)
    return (1.0 - (a * b).sum(dim=dim)).mean()


@torch.no_grad()
def pair_statistics(
    f_r: torch.Tensor, f_s: torch.Tensor | StyleFeatures, rows: torch.Tensor, cols: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """From sparse pairs, return ``(F_r D_r F_rᵀ, F_r U F_sᵀ)``, both ``(C, C)`` in ``f_r``'s dtype, with ``U = A / N_pair``.

    ``A`` is the 0/1 matrix with ones at ``(rows[p], cols[p])`` (pairs must be unique). ``U F_sᵀ``
    ``(N_r, C)`` is a sparse-times-dense product done by ``embedding_bag`` (sum over each rendered
    feature's paired style features) — nothing of size ``N_pair × C`` or ``N_r × N_s`` is built.
    """
    f_r = f_r.detach()
    counts, g = pair_sums(f_s, rows, cols, f_r.shape[1])
    n_pair = rows.numel()
    m = (f_r * (counts.to(f_r.dtype) / n_pair)) @ f_r.t()
    rhs = (f_r @ g.to(f_r.dtype)) / n_pair
    return m, rhs


@torch.no_grad()
def pair_sums(
    f_s: torch.Tensor | StyleFeatures, rows: torch.Tensor, cols: torch.Tensor, n_r: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """The sparse half of :func:`pair_statistics`: ``(counts, G)`` with ``counts`` ``(N_r,)`` int64 the row sums of
    ``A`` and ``G = A F_sᵀ`` ``(N_r, C)`` in ``F_s``'s dtype (each rendered feature's paired style features summed,
    by ``embedding_bag``)."""
    n_pair = rows.numel()
    if n_pair == 0 or cols.numel() != n_pair:
        raise InputError(f"FAST: need equally long, non-empty pair lists (got {n_pair} rows, {cols.numel()} cols)")
    style_rows = f_s.rows if isinstance(f_s, StyleFeatures) else f_s.detach().t().contiguous()  # (N_s, C)
    if n_pair > 1 and not bool((rows[1:] >= rows[:-1]).all()):
        order = torch.argsort(rows, stable=True)
        rows, cols = rows[order], cols[order]
    counts = torch.bincount(rows, minlength=n_r)
    offsets = torch.zeros(n_r, dtype=torch.long, device=rows.device)
    offsets[1:] = counts.cumsum(0)[:-1]
    return counts, F.embedding_bag(cols, style_rows, offsets, mode="sum")


@torch.no_grad()
def solve_alignment(
    m: torch.Tensor,
    rhs: torch.Tensor,
    *,
    eps: float = 1e-12,
    solve_dtype: torch.dtype = torch.float64,
    stats: FastStats | None = None,
) -> torch.Tensor:
    """``P = (m + εI)⁻¹ rhs`` ``(C, C)`` in ``solve_dtype``, returned in ``m``'s dtype; identity on failure.

    ``m`` is symmetric positive semi-definite (``F_r D_r F_rᵀ``), so Cholesky is tried first (a third of LU's
    factorisation work); a system it finds not positive definite in ``solve_dtype`` is solved by LU.
    """
    c = m.shape[0]
    eye = torch.eye(c, dtype=solve_dtype, device=m.device)
    reason = None
    try:
        a, b = m.to(solve_dtype) + eps * eye, rhs.to(solve_dtype)
        chol, info = torch.linalg.cholesky_ex(a)
        if int(info) == 0:
            p = torch.cholesky_solve(b, chol)
        else:
            if stats is not None:
                stats.lu_solves += 1
            p, info = torch.linalg.solve_ex(a, b)
        if int(info) != 0:
            reason = f"singular system (info={int(info)})"
        elif not bool(torch.isfinite(p).all()):
            reason = "non-finite solution"
    except RuntimeError as exc:  # e.g. non-finite input on some backends
        reason = f"solve error: {exc}"
    if stats is not None:
        stats.solves += 1
    if reason is not None:
        p = eye
        if stats is not None:
            stats.fallbacks += 1
            if len(stats.fallback_reasons) < 20:
                stats.fallback_reasons.append(reason)
    return p.to(m.dtype)


@torch.no_grad()
def alignment_matrix(
    f_r: torch.Tensor,
    f_s: torch.Tensor | StyleFeatures,
    params: FastParams | None = None,
    stats: FastStats | None = None,
) -> torch.Tensor:
    """The FAST alignment ``P`` ``(C, C)`` for one group (see module docstring)."""
    params = params or FastParams()
    style = as_style_features(f_s)
    check_feature_pair(f_r, style.raw, "FAST")
    rows, cols = mutual_knn_pairs(
        f_r, style, params.k, max_block_elems=params.max_block_elems, search=params.knn_search,
        projection=knn.projection_of(params),
    )
    if stats is not None:
        stats.last_pairs = rows.numel()
        stats.pairs_total += rows.numel()
    return alignment_from_pairs(f_r, style, rows, cols, params, stats)


@torch.no_grad()
def alignment_from_pairs(
    f_r: torch.Tensor,
    f_s: torch.Tensor | StyleFeatures,
    rows: torch.Tensor,
    cols: torch.Tensor,
    params: FastParams | None = None,
    stats: FastStats | None = None,
) -> torch.Tensor:
    """``P`` ``(C, C)`` from the affinity's pairs: :func:`pair_statistics` and :func:`solve_alignment`, in float64 for a
    small group (:func:`is_small_group`; ``P`` is then float64), else in ``f_r``'s dtype with ``params.solve_dtype``."""
    params = params or FastParams()
    if is_small_group(f_r):  # the whole algebra in float64 (module docstring, "Small groups")
        m, rhs = pair_statistics(f_r.double(), f_s, rows, cols)
        return solve_alignment(m, rhs, eps=params.eps, solve_dtype=torch.float64, stats=stats)
    m, rhs = pair_statistics(f_r, f_s, rows, cols)
    return solve_alignment(m, rhs, eps=params.eps, solve_dtype=getattr(torch, params.solve_dtype), stats=stats)


def apply_alignment(p: torch.Tensor, f_r: torch.Tensor) -> torch.Tensor:
    """``F_rs = Pᵀ F_r`` ``(C, N_r)`` in ``f_r``'s dtype, detached; formed in ``P``'s dtype (float64 for a small group,
    whose ``P`` may have large components that cancel in ``Pᵀ F_r``)."""
    return (p.t() @ f_r.detach().to(p.dtype)).to(f_r.dtype)


def is_small_group(f_r: torch.Tensor) -> bool:
    """Whether a group ``(C, N_r)`` has fewer than ``SMALL_GROUP_RATIO · C`` features: its FAST algebra (pair
    statistics, solve, target) runs in float64 (module docstring, "Small groups")."""
    return f_r.shape[1] < SMALL_GROUP_RATIO * f_r.shape[0]


@torch.no_grad()
def fast_target(
    f_r: torch.Tensor,
    f_s: torch.Tensor | StyleFeatures,
    params: FastParams | None = None,
    stats: FastStats | None = None,
) -> torch.Tensor:
    """Aligned features ``F_rs = Pᵀ F_r`` ``(C, N_r)`` in ``f_r``'s dtype, detached (:func:`apply_alignment`)."""
    return apply_alignment(alignment_matrix(f_r, f_s, params, stats), f_r)


def fast_loss_group(
    f_r: torch.Tensor,
    f_s: torch.Tensor | StyleFeatures,
    params: FastParams | None = None,
    stats: FastStats | None = None,
) -> torch.Tensor:
    """FAST loss of one group: ``1 − cos(F_r, F_rs)`` along ``params.cosine``, averaged; grad flows to ``F_r``."""
    if not bool(torch.isfinite(f_r).all()):
        raise NumericalError("FAST: rendered features contain NaN/Inf (the render or the optimiser diverged)")
    params = params or FastParams()
    target = fast_target(f_r, as_style_features(f_s), params, stats)  # the style side is checked when prepared
    return cosine_distance_loss(f_r, target, axis=params.cosine)


def fast_loss(
    groups: Sequence[tuple[torch.Tensor, torch.Tensor | StyleFeatures]],
    params: FastParams | None = None,
    stats: FastStats | None = None,
) -> torch.Tensor:
    """Sum over matching groups ``[(F_r^z (C, N_r^z), F_s^z (C, N_s^z) or StyleFeatures), …]`` of
    :func:`fast_loss_group`."""
    if len(groups) == 0:
        raise InputError("FAST: no matching groups")
    return torch.stack([fast_loss_group(f_r, f_s, params, stats) for f_r, f_s in groups]).sum()


# --------------------------------------------------------------------------- dense reference (tests)


@torch.no_grad()
def affinity_dense(f_r: torch.Tensor, f_s: torch.Tensor, k: int = 5) -> torch.Tensor:
    """Dense ``A`` ``(N_r, N_s)`` float (0/1), straight from the definition. Reference for tests only."""
    sim = normalize_columns(f_r.detach()).t() @ normalize_columns(f_s.detach())
    a = torch.zeros_like(sim)
    a.scatter_(1, sim.topk(min(k, sim.shape[1]), dim=1).indices, 1.0)
    b = torch.zeros_like(sim)
    b.scatter_(0, sim.topk(min(k, sim.shape[0]), dim=0).indices, 1.0)
    return torch.maximum(a, b)


def fast_loss_dense(
    f_r: torch.Tensor, f_s: torch.Tensor, k: int = 5, eps: float = 1e-12, cosine: CosineAxis = "pixel"
) -> torch.Tensor:
    """Dense FAST loss for one group, written directly from the formulas. Reference for tests only."""
    with torch.no_grad():
        a = affinity_dense(f_r, f_s, k)
        u = a / a.sum()
        fr = f_r.detach().double()
        d = torch.diag(u.sum(dim=1)).double()
        m = fr @ d @ fr.t() + eps * torch.eye(fr.shape[0], dtype=torch.float64, device=fr.device)
        p = torch.linalg.solve(m, fr @ u.double() @ f_s.detach().double().t())
        target = (p.t() @ fr).to(f_r.dtype)
    return cosine_distance_loss(f_r, target, axis=cosine)
