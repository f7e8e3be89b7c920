"""FAST loss: chunked == dense, P == least squares, loss decreases, gradients, fallbacks, errors."""

from __future__ import annotations

import pytest
import torch
from pydantic import ValidationError

from abcgs.errors import InputError, NumericalError
from abcgs.features import knn
from abcgs.losses import fast
from abcgs.losses import terms as losses
from abcgs.losses.params import FastParams


def _feats(c: int, n_r: int, n_s: int, seed: int = 0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    # ReLU-like, non-negative features with a shared component, as VGG's are
    f_r = (torch.randn(c, n_r, generator=g, dtype=dtype) + 0.5).relu()
    f_s = (torch.randn(c, n_s, generator=g, dtype=dtype) + 0.5).relu() * 2.0
    return f_r, f_s


def _dense_from_pairs(rows, cols, n_r, n_s):
    a = torch.zeros(n_r, n_s, dtype=torch.float64)
    a[rows, cols] = 1.0
    return a


@pytest.mark.parametrize("budget", [2**30, 10_000, 257, 41, 7, 1])
@pytest.mark.parametrize("shape", [(16, 50, 37), (8, 9, 120), (8, 120, 3)])
def test_chunked_affinity_equals_dense(budget, shape):
    c, n_r, n_s = shape
    f_r, f_s = _feats(c, n_r, n_s, seed=n_r)
    rows, cols = knn.mutual_knn_pairs(f_r, f_s, 5, max_block_elems=budget)
    a = _dense_from_pairs(rows, cols, n_r, n_s)
    assert torch.equal(a, fast.affinity_dense(f_r, f_s, 5))
    # pairs are unique and sorted
    keys = rows * n_s + cols
    assert torch.equal(keys, torch.unique(keys))


@pytest.mark.parametrize("budget", [2**30, 333, 50, 5])
def test_cosine_topk_both_directions(budget):
    f_r, f_s = _feats(12, 40, 31, seed=3)
    nn_rs, nn_sr = knn.cosine_topk(f_r, f_s, 4, 3, max_block_elems=budget)
    sim = knn.normalize_columns(f_r).t() @ knn.normalize_columns(f_s)
    assert torch.equal(nn_rs, sim.topk(4, dim=1).indices)
    assert torch.equal(nn_sr, sim.topk(3, dim=0).indices)


@pytest.mark.parametrize("budget", [2**30, 500, 13, 1])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_chunked_loss_equals_dense(budget, dtype):
    f_r, f_s = _feats(24, 60, 45, seed=7, dtype=dtype)
    params = FastParams(max_block_elems=budget)
    got = fast.fast_loss([(f_r, f_s)], params)
    ref = fast.fast_loss_dense(f_r, f_s)
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    assert abs(float(got) - float(ref)) < tol


def test_alignment_equals_weighted_least_squares():
    """P minimises Σ A_ij ||Pᵀ v_i − s_j||²: compare with lstsq on the stacked pair system."""
    f_r, f_s = _feats(10, 70, 55, seed=11)
    p = fast.alignment_matrix(f_r, f_s, FastParams(eps=0.0, max_block_elems=64))
    rows, cols = knn.mutual_knn_pairs(f_r, f_s, 5)
    v = f_r[:, rows].t()  # (N_pair, C): one equation block per pair, weight A_ij = 1
    s = f_s[:, cols].t()
    p_ls = torch.linalg.lstsq(v, s, driver="gelsd").solution
    assert torch.allclose(p, p_ls, atol=1e-9, rtol=1e-9)
    # and with the authors' eps the difference is negligible
    p_eps = fast.alignment_matrix(f_r, f_s)
    assert torch.allclose(p_eps, p_ls, atol=1e-8)


def test_loss_decreases_along_gradient():
    f_r0, f_s = _feats(16, 80, 60, seed=5, dtype=torch.float32)
    f_r = f_r0.clone().requires_grad_(True)
    opt = torch.optim.SGD([f_r], lr=200.0)
    losses = []
    for _ in range(10):
        opt.zero_grad()
        loss = fast.fast_loss([(f_r, f_s)])  # target re-aligned every step, as in training
        loss.backward()
        losses.append(float(loss.detach()))
        opt.step()
    assert all(b < a for a, b in zip(losses, losses[1:])), losses
    assert losses[-1] < 0.3 * losses[0]
    # moving straight to the aligned target gives zero loss for that target
    target = fast.fast_target(f_r0, f_s)
    assert float(fast.cosine_distance_loss(target, target)) < 1e-6


def test_gradient_only_through_rendered_features():
    f_r, f_s = _feats(8, 20, 15, seed=2)
    f_r.requires_grad_(True)
    f_s.requires_grad_(True)
    fast.fast_loss([(f_r, f_s)]).backward()
    assert f_s.grad is None
    target = fast.fast_target(f_r, f_s)
    assert not target.requires_grad
    f_r2 = f_r.detach().clone().requires_grad_(True)
    fast.cosine_distance_loss(f_r2, target).backward()
    assert torch.allclose(f_r.grad, f_r2.grad)


@pytest.mark.parametrize("axis", ["pixel", "channel"])
def test_cosine_distance_gradcheck(axis):
    """The hand-written gradient of the cosine distance against finite differences (float64)."""
    f_r, f_s = _feats(5, 7, 6, seed=1)
    target = fast.fast_target(f_r, f_s)
    x = f_r.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t: fast.cosine_distance_loss(t, target, axis=axis), (x,))


@pytest.mark.parametrize("axis", ["pixel", "channel"])
def test_cosine_distance_matches_its_autograd_reference(axis):
    """Value and gradient equal the torch-ops formula with autograd, including zero vectors (distance 1, finite
    gradient) and float32 features of a realistic size."""
    g = torch.Generator().manual_seed(4)
    for dtype, c, n in ((torch.float64, 9, 13), (torch.float32, 768, 300)):
        f = (torch.randn(c, n, generator=g, dtype=dtype) + 0.3).relu()
        t = (torch.randn(c, n, generator=g, dtype=dtype) + 0.3).relu()
        f[:, 2] = 0.0
        f[3, :] = 0.0
        t[:, 5] = 0.0
        grads, values = [], []
        for fn in (fast.cosine_distance_loss, fast.cosine_distance_loss_reference):
            x = f.clone().requires_grad_(True)
            value = fn(x, t, axis=axis)
            value.backward()
            values.append(value.detach())
            grads.append(x.grad)
        tol = 1e-12 if dtype == torch.float64 else 1e-6
        assert torch.allclose(values[0], values[1], atol=tol, rtol=tol)
        assert torch.isfinite(grads[0]).all()
        assert torch.allclose(grads[0], grads[1], atol=tol * float(grads[1].abs().max()), rtol=1e-5)


def test_groups_are_summed():
    g1 = _feats(8, 20, 15, seed=1)
    g2 = _feats(8, 30, 25, seed=2)
    total = fast.fast_loss([g1, g2])
    assert torch.allclose(total, fast.fast_loss([g1]) + fast.fast_loss([g2]))


def test_singular_solve_falls_back_to_identity_and_counts():
    f_r, f_s = _feats(6, 20, 15, seed=4)
    f_r[2] = 0.0  # dead channel: singular without the ridge
    stats = fast.FastStats()
    p = fast.alignment_matrix(f_r, f_s, FastParams(eps=0.0), stats)
    assert stats.fallbacks == 1 and stats.solves == 1 and stats.fallback_reasons
    assert torch.equal(p, torch.eye(6, dtype=p.dtype))
    # with the default ridge the dead channel decouples and the solve succeeds
    stats2 = fast.FastStats()
    p2 = fast.alignment_matrix(f_r, f_s, FastParams(), stats2)
    assert stats2.fallbacks == 0 and torch.isfinite(p2).all() and stats2.last_pairs > 0
    assert torch.all(p2[2] == 0)


def test_fewer_features_than_channels_is_stable():
    f_r, f_s = _feats(64, 10, 12, seed=9, dtype=torch.float32)
    stats = fast.FastStats()
    loss = fast.fast_loss([(f_r, f_s)], stats=stats)
    assert torch.isfinite(loss) and stats.fallbacks == 0


def _decaying_spectrum(c: int, n: int, g: torch.Generator) -> torch.Tensor:
    """Features whose singular values fall from ~3e3 to ~0.5, as real relu3 features' do (float32)."""
    q, _ = torch.linalg.qr(torch.randn(c, c, generator=g, dtype=torch.float64))
    s = torch.logspace(0, -4, c, dtype=torch.float64) * 3e3
    return ((q * s) @ torch.randn(c, n, generator=g, dtype=torch.float64) / c**0.5).float()


def test_small_group_target_is_the_mean_of_the_paired_style_features():
    """With N_r < C independent features the least-squares target is exact: each rendered feature's aligned feature
    is the mean of its paired style features. float32 products miss it on ill-conditioned features (the null space's
    eigenvalues become ±1e-7·‖M‖ ≫ ε); the small-group path (float64) finds it."""
    c, n_r, n_s = 64, 48, 80
    float32_errors = []
    for seed in range(3):
        g = torch.Generator().manual_seed(seed)
        f_r, f_s = _decaying_spectrum(c, n_r, g), _decaying_spectrum(c, n_s, g)
        assert fast.is_small_group(f_r)
        rows, cols = knn.mutual_knn_pairs(f_r, f_s, 5)
        counts, sums = fast.pair_sums(f_s.double(), rows, cols, n_r)
        mean_paired = (sums / counts[:, None]).t()
        target = fast.fast_target(f_r, f_s)
        assert target.dtype == torch.float32
        assert float((target.double() - mean_paired).norm() / mean_paired.norm()) < 1e-6
        m, rhs = fast.pair_statistics(f_r, f_s, rows, cols)  # the float32 statistics a large group uses
        p = fast.solve_alignment(m, rhs)
        float32_errors.append(float(((p.t() @ f_r).double() - mean_paired).norm() / mean_paired.norm()))
    assert max(float32_errors) > 1e-2  # the case is hard: float32 products alone are off by percent


def test_groups_of_at_least_1_25_c_features_keep_the_float32_algebra():
    c = 16
    f_r, f_s = _feats(c, 20, 40, seed=3, dtype=torch.float32)
    assert not fast.is_small_group(f_r) and fast.is_small_group(f_r[:, :19])
    rows, cols = knn.mutual_knn_pairs(f_r, f_s, 5)
    m, rhs = fast.pair_statistics(f_r, f_s, rows, cols)
    assert m.dtype == torch.float32
    assert torch.equal(fast.fast_target(f_r, f_s), fast.solve_alignment(m, rhs).t() @ f_r)


def test_bad_inputs():
    f_r, f_s = _feats(8, 10, 10)
    with pytest.raises(InputError, match="channel"):
        fast.fast_loss([(f_r, f_s[:7])])
    with pytest.raises(InputError, match="empty"):
        fast.fast_loss([(f_r[:, :0], f_s)])
    with pytest.raises(InputError, match="no matching groups"):
        fast.fast_loss([])
    with pytest.raises(InputError, match=r"\(C, N\)"):
        fast.fast_loss([(f_r[None], f_s)])
    bad = f_r.clone()
    bad[0, 0] = float("nan")
    with pytest.raises(NumericalError):
        fast.fast_loss([(bad, f_s)])
    with pytest.raises(InputError):
        knn.mutual_knn_pairs(f_r, f_s, 0)
    with pytest.raises(ValidationError, match="bogus"):
        FastParams(k=5, bogus=1)


# --------------------------------------------------------------------------- both cosine axes, pinned


def _dense_fast_rederived(cf: torch.Tensor, sf: torch.Tensor, k: int, cosine_dim: int) -> torch.Tensor:
    """FAST re-derived densely, step by step as the authors' ``FASTLoss`` (vpx-ecnu/ABC-GS
    ``abcgs/loss/fast_loss.py``) computes it: dense affinity by two ``topk`` + ``scatter_``, ``U = A / ΣA``,
    ``D1 = diag(U 1)``, ``P = solve(cf D1 cfᵀ + 1e-12 I, cf U sfᵀ)``, target ``Pᵀ cf`` without grad, then
    ``1 − F.cosine_similarity(cf, target, dim=cosine_dim)`` averaged. ``cosine_dim = 1`` is their per-channel
    loss; ``cosine_dim = 0`` the per-pixel reading of the paper's Eq. 7. Independent of the library."""
    with torch.no_grad():
        cf_d, sf_d = cf.detach(), sf.detach()
        dist = torch.nn.functional.normalize(cf_d, 2, 0).t() @ torch.nn.functional.normalize(sf_d, 2, 0)
        u = torch.zeros_like(dist)
        u.scatter_(0, torch.topk(dist, k, 0)[1], torch.ones(k, dist.shape[1], dtype=dist.dtype))
        u.scatter_(1, torch.topk(dist, k, 1)[1], torch.ones(dist.shape[0], k, dtype=dist.dtype))
        u = u / u.sum()
        d1 = torch.diag(u.sum(dim=1))
        a = cf_d @ d1 @ cf_d.t() + torch.eye(cf_d.shape[0], dtype=cf_d.dtype) * 1e-12
        p = torch.linalg.solve(a, cf_d @ u @ sf_d.t())
        target = p.t() @ cf_d
    return (1.0 - torch.nn.functional.cosine_similarity(cf, target, dim=cosine_dim)).mean()


@pytest.mark.parametrize("cosine, dim", [("pixel", 0), ("channel", 1)])
@pytest.mark.parametrize("shape", [(16, 50, 37), (12, 9, 80), (24, 120, 30)])
def test_both_cosine_axes_equal_dense_rederivation(cosine, dim, shape):
    """Value and gradient of each FAST variant equal the dense float64 re-derivation (budget forces chunking)."""
    c, n_r, n_s = shape
    f_r0, f_s = _feats(c, n_r, n_s, seed=c + n_r)
    f_r = f_r0.clone().requires_grad_(True)
    got = fast.fast_loss([(f_r, f_s)], FastParams(cosine=cosine, max_block_elems=97))
    (g_got,) = torch.autograd.grad(got, f_r)
    f_r2 = f_r0.clone().requires_grad_(True)
    ref = _dense_fast_rederived(f_r2, f_s, 5, dim)
    (g_ref,) = torch.autograd.grad(ref, f_r2)
    # tolerance: only the cosine's eps convention differs (ours adds 1e-8 to each norm, torch clamps the product)
    assert abs(got.item() - ref.item()) < 1e-7
    assert float((g_got - g_ref).abs().max()) < 1e-6 * float(g_ref.abs().max())
    # and the library's own dense reference agrees on the axis
    assert abs(fast.fast_loss_dense(f_r0, f_s, cosine=cosine).item() - ref.item()) < 1e-7


def test_cosine_axes_differ_and_channel_axis_is_per_row():
    f_r, f_s = _feats(8, 40, 30, seed=21)
    pix = fast.fast_loss([(f_r, f_s)], FastParams(cosine="pixel"))
    ch = fast.fast_loss([(f_r, f_s)], FastParams(cosine="channel"))
    assert abs(float(pix) - float(ch)) > 1e-4
    # channel axis: scaling one channel's row leaves that row's cosine unchanged; pixel axis: a column's
    t = fast.fast_target(f_r, f_s)
    scaled = f_r.clone()
    scaled[3] *= 7.0
    t_scaled = t.clone()
    t_scaled[3] *= 7.0
    assert torch.allclose(fast.cosine_distance_loss(scaled, t_scaled, axis="channel"),
                          fast.cosine_distance_loss(f_r, t, axis="channel"))
    col = f_r.clone()
    col[:, 5] *= 7.0
    assert torch.allclose(fast.cosine_distance_loss(col, t, axis="pixel"), fast.cosine_distance_loss(f_r, t, axis="pixel"))
    with pytest.raises(InputError, match="axis"):
        fast.cosine_distance_loss(f_r, t, axis="row")
    with pytest.raises(ValidationError):
        FastParams(cosine="row")


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("n_rows, k", [(1000, 5), (1003, 3), (161, 5), (40, 5)])
def test_topk_rows_of_columns_matches_torch_topk(n_rows, k, dtype):
    """Exactly torch.topk along dim 0: float32 through the CPU kernels' one-pass column top-k (where built), float64
    through the block pre-selection (padding and the small-matrix path too)."""
    g = torch.Generator().manual_seed(n_rows)
    sim = (torch.rand(n_rows, 37, generator=g, dtype=torch.float64) * 2 - 1).to(dtype)
    vals, idx = knn.topk_rows_of_columns(sim, k)
    ref = sim.topk(k, dim=0)
    assert torch.equal(vals, ref.values) and torch.equal(idx, ref.indices)


def test_prepared_style_features_give_the_same_loss_and_gradient():
    """StyleFeatures (prepared once per run) is only a cache: loss and gradient equal the plain-tensor path."""
    g = torch.Generator().manual_seed(3)
    f_s = (torch.randn(24, 90, generator=g) + 0.2).relu()
    f_r1 = (torch.randn(24, 70, generator=g) + 0.2).relu().requires_grad_(True)
    f_r2 = f_r1.detach().clone().requires_grad_(True)
    style = knn.StyleFeatures.of(f_s)
    for method in ("fast", "nnfm", "knnfm", "gram"):
        a = losses.style_loss(method, [(f_r1, f_s)])
        b = losses.style_loss(method, [(f_r2, style)])
        ga, = torch.autograd.grad(a, f_r1)
        gb, = torch.autograd.grad(b, f_r2)
        assert torch.equal(a, b) and torch.equal(ga, gb), method
    with pytest.raises(InputError, match="NaN/Inf"):
        knn.StyleFeatures.of(torch.full((4, 5), float("nan")))


def test_solve_alignment_falls_back_to_lu_when_cholesky_fails():
    """An indefinite system (not a Gram matrix) is not Cholesky-factorable: LU solves it, and it is counted."""
    m = torch.tensor([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues 3 and -1
    rhs = torch.tensor([[1.0, 0.0], [0.0, 1.0]])
    stats = fast.FastStats()
    p = fast.solve_alignment(m, rhs, eps=0.0, stats=stats)
    assert torch.allclose(p, torch.linalg.inv(m), atol=1e-6)
    assert stats.lu_solves == 1 and stats.fallbacks == 0
