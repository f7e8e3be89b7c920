"""Neighbour search: the certified bf16 search equals the exact one, its error bound holds, the CPU kernels'
column top-k and pair dot products equal their torch definitions."""

from __future__ import annotations

import pytest
import torch
from pydantic import ValidationError

from abcgs.errors import InputError
from abcgs.features import knn
from abcgs.losses import fast
from abcgs.losses import terms as losses
from abcgs.losses.params import FastParams
from abcgs.render import cpu as cpu_kernels

needs_kernels = pytest.mark.skipif(
    not cpu_kernels.is_available(), reason="the CPU kernels' extension did not build here (make install builds it)"
)


def _feats(c: int, n_r: int, n_s: int, seed: int = 0, near_ties: bool = False):
    """float32 ReLU-like features with a shared component (as VGG's); ``near_ties``: style columns come in
    nearly equal pairs, so many similarities differ by less than the bf16 error bound."""
    g = torch.Generator().manual_seed(seed)
    f_r = (torch.randn(c, n_r, generator=g) + 0.5).relu()
    f_s = (torch.randn(c, n_s, generator=g) + 0.5).relu() * 2.0
    if near_ties:
        half = f_s[:, : n_s // 2]
        f_s[:, n_s // 2 : n_s // 2 * 2] = half + 1e-4 * torch.rand(half.shape, generator=g)
    return f_r, f_s


def _same_sets(a: torch.Tensor, b: torch.Tensor, dim: int) -> bool:
    return torch.equal(a.sort(dim=dim).values, b.sort(dim=dim).values)


@pytest.mark.parametrize("candidates", [16, 6])
@pytest.mark.parametrize("k_rs, k_sr", [(5, 5), (1, 0), (0, 3), (20, 20)])
@pytest.mark.parametrize("near_ties", [False, True])
def test_bf16_search_gives_the_exact_neighbour_sets(monkeypatch, candidates, k_rs, k_sr, near_ties):
    monkeypatch.setattr(knn, "BF16_CANDIDATES", candidates)
    certified: list[float] = []
    original = knn._certified_topk

    def spy(*args, **kwargs):
        out = original(*args, **kwargs)
        certified.append(float(out[1].float().mean()))
        return out

    monkeypatch.setattr(knn, "_certified_topk", spy)
    f_r, f_s = _feats(96, 300, 500, seed=candidates + k_rs, near_ties=near_ties)
    for budget in (2**22, 5000):
        a_rs, a_sr = knn.cosine_topk(f_r, f_s, k_rs, k_sr, search="bf16", max_block_elems=budget)
        b_rs, b_sr = knn.cosine_topk(f_r, f_s, k_rs, k_sr, search="exact", max_block_elems=budget)
        assert (a_rs is None) == (b_rs is None) and (a_sr is None) == (b_sr is None)
        if b_rs is not None:
            assert a_rs.shape == b_rs.shape and _same_sets(a_rs, b_rs, 1)
        if b_sr is not None:
            assert a_sr.shape == b_sr.shape and _same_sets(a_sr, b_sr, 0)
    if near_ties and candidates == 6 and k_rs == 5:
        # the pairs of nearly equal style columns defeat the gap test for some features: the exact
        # fallback ran, and the sets still agree
        assert min(certified) < 1.0


def test_bf16_search_with_fewer_features_than_candidates():
    """Every feature of the other side is a candidate: nothing to certify, still the exact sets."""
    f_r, f_s = _feats(32, 7, 11, seed=1)
    a_rs, a_sr = knn.cosine_topk(f_r, f_s, 5, 5, search="bf16")
    b_rs, b_sr = knn.cosine_topk(f_r, f_s, 5, 5, search="exact")
    assert _same_sets(a_rs, b_rs, 1) and _same_sets(a_sr, b_sr, 0)


def test_bf16_similarity_bound_holds():
    """The proven bound covers the actual error of oneDNN's bf16 product (and is not vacuous)."""
    f_r, f_s = _feats(768, 400, 600, seed=4)
    u_r, u_s = knn.normalize_columns(f_r), knn.normalize_columns(f_s)
    lo_r, lo_s = u_r.bfloat16(), u_s.bfloat16()
    e_r = (u_r - lo_r.float()).norm(dim=0)
    e_s = (u_s - lo_s.float()).norm(dim=0)
    err = ((lo_r.t() @ lo_s).float() - u_r.t() @ u_s).abs()
    bound = knn.bf16_similarity_bound(e_r, float(e_s.max()), 768)
    assert bool((err <= bound[:, None]).all())
    assert float(bound.max()) < 0.02  # tight enough to certify most features


def test_fast_loss_is_the_same_with_either_search():
    f_r, f_s = _feats(64, 400, 700, seed=5)
    style = knn.StyleFeatures.of(f_s)
    exact = fast.fast_loss([(f_r, style)], FastParams(knn_search="exact", projection_rank=0))
    low = fast.fast_loss([(f_r, style)], FastParams(knn_search="bf16", projection_rank=0))
    assert torch.equal(exact, low)
    nn_exact = losses.style_loss("nnfm", [(f_r, style)], fast_params=FastParams(knn_search="exact", projection_rank=0))
    nn_low = losses.style_loss("nnfm", [(f_r, style)], fast_params=FastParams(knn_search="bf16", projection_rank=0))
    assert torch.equal(nn_exact, nn_low)


def test_search_choice_and_errors():
    cpu = torch.device("cpu")
    assert knn.resolve_search("exact", 10**4, 10**4, cpu) == "exact"
    assert knn.resolve_search("bf16", 3, 3, cpu) == "bf16"
    assert knn.resolve_search("auto", 10, 10, cpu) == "exact"  # small: the float32 product is cheap
    expected = "bf16" if knn.bf16_matmul_is_native() else "exact"
    assert knn.resolve_search("auto", 4096, 4096, cpu) == expected
    with pytest.raises(InputError, match="knn search"):
        knn.resolve_search("fast", 10, 10, cpu)
    with pytest.raises(ValidationError):
        FastParams(knn_search="approximate")


@needs_kernels
@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
@pytest.mark.parametrize("n_rows, k", [(1000, 5), (161, 17), (17, 17), (40, 1)])
def test_kernel_column_topk_matches_torch_topk(dtype, n_rows, k):
    g = torch.Generator().manual_seed(n_rows + k)
    sim = (torch.rand(n_rows, 203, generator=g) * 2 - 1).to(dtype)
    vals, idx = knn.topk_rows_of_columns(sim, k)
    ref = sim.topk(k, dim=0)
    assert vals.dtype == dtype and idx.shape == (k, 203)
    assert torch.equal(vals, ref.values) and torch.equal(sim.gather(0, idx), vals)
    if dtype == torch.float32:  # distinct values: the indices are defined (bf16 rounding makes ties)
        assert torch.equal(idx, ref.indices)


@needs_kernels
def test_kernel_column_topk_is_the_same_for_any_thread_count():
    sim = torch.rand(500, 1001, generator=torch.Generator().manual_seed(0))
    with cpu_kernels.kernel_threads(1):
        one = knn.topk_rows_of_columns(sim, 9)
    with cpu_kernels.kernel_threads(2):
        two = knn.topk_rows_of_columns(sim, 9)
    assert torch.equal(one[0], two[0]) and torch.equal(one[1], two[1])


@pytest.mark.parametrize("use_kernels", [True, False])
def test_pair_dots_equal_row_dot_products(monkeypatch, use_kernels):
    if use_kernels and not cpu_kernels.is_available():
        pytest.skip("the CPU kernels' extension did not build here (make install builds it)")
    if not use_kernels:
        monkeypatch.setattr(knn, "_cpu_kernels", lambda: None)
    g = torch.Generator().manual_seed(2)
    a, b = torch.randn(50, 37, generator=g), torch.randn(80, 37, generator=g)
    ia, ib = torch.randint(0, 50, (999,), generator=g), torch.randint(0, 80, (999,), generator=g)
    got = knn.pair_dots(a, b, ia, ib)
    ref = (a.double()[ia] * b.double()[ib]).sum(1)
    assert got.shape == (999,) and torch.allclose(got.double(), ref, atol=1e-5)


def _rank_topk(s: torch.Tensor, k: int, dim: int) -> torch.Tensor:
    """Indices of the k largest along ``dim``, ties to the lower index (the kernel's order), largest first."""
    n = s.shape[dim]
    pos = torch.arange(n, dtype=torch.float64).view(*([-1, 1] if dim == 0 else [1, -1]))
    key = s.double() - pos * 1e-12  # values here differ by far more than 1e-12 unless equal
    return key.topk(k, dim=dim).indices


@needs_kernels
@pytest.mark.parametrize("n_a, n_b, r, ka, kb", [(301, 517, 24, 5, 7), (6, 16, 8, 16, 6), (7, 40, 3, 1, 0),
                                                 (50, 9, 130, 0, 4), (1, 1, 5, 1, 1)])
def test_kernel_topk_dots_both_matches_torch_topk(n_a, n_b, r, ka, kb):
    g = torch.Generator().manual_seed(n_a + r)
    a, b = torch.randn(n_a, r, generator=g), torch.randn(n_b, r, generator=g)
    a_idx, a_val, b_idx, b_val = cpu_kernels.load_extension().topk_dots_both(a, b, ka, kb)
    s = a.double() @ b.double().t()
    assert a_idx.shape == (n_a, ka) and b_idx.shape == (n_b, kb)
    if ka:
        assert torch.equal(a_idx, s.topk(ka, dim=1).indices)
        assert torch.allclose(a_val.double(), s.gather(1, a_idx), atol=1e-5)
    if kb:
        assert torch.equal(b_idx, s.topk(kb, dim=0).indices.t())
        assert torch.allclose(b_val.double(), s.t().gather(1, b_idx), atol=1e-5)


@needs_kernels
def test_kernel_topk_dots_both_ties_and_thread_counts():
    """Ties keep the lower index in both directions, and any thread count gives the same lists."""
    g = torch.Generator().manual_seed(5)
    a = torch.randint(-2, 3, (400, 6), generator=g).float()  # small integers: many exactly equal products
    b = torch.randint(-2, 3, (700, 6), generator=g).float()
    ext = cpu_kernels.load_extension()
    outs = []
    for threads in (1, 2, 3):
        with cpu_kernels.kernel_threads(threads):
            outs.append(ext.topk_dots_both(a, b, 9, 11))
    for other in outs[1:]:
        assert all(torch.equal(x, y) for x, y in zip(outs[0], other))
    s = a @ b.t()  # exact in float32 (small integers)
    assert torch.equal(outs[0][0], _rank_topk(s, 9, 1))
    assert torch.equal(outs[0][2], _rank_topk(s, 11, 0).t())


needs_bf16_dot = pytest.mark.skipif(
    not (cpu_kernels.is_available() and knn.bf16_dot_available()),
    reason="this CPU has no AVX512-BF16 (the bf16 candidate products are built only where it has; the torch path "
    "with the same rounding is tested on every CPU)",
)


@needs_bf16_dot
@pytest.mark.parametrize("n_a, n_b, r, ka, kb", [(301, 517, 24, 5, 7), (6, 16, 8, 16, 6), (7, 40, 3, 1, 0),
                                                 (50, 9, 130, 0, 4), (1, 1, 5, 1, 1), (40, 70, 129, 3, 3)])
def test_kernel_bf16_products_are_the_rounded_features_products(n_a, n_b, r, ka, kb):
    """bf16_products: the lists of the products of a and b rounded to bfloat16 (odd R too: the pair is zero-padded),
    for any thread count."""
    g = torch.Generator().manual_seed(n_a + r)
    a, b = torch.randn(n_a, r, generator=g), torch.randn(n_b, r, generator=g)
    ext = cpu_kernels.load_extension()
    outs = []
    for threads in (1, 2, 3):
        with cpu_kernels.kernel_threads(threads):
            outs.append(ext.topk_dots_both(a, b, ka, kb, True))
    for other in outs[1:]:
        assert all(torch.equal(x, y) for x, y in zip(outs[0], other))
    a_idx, a_val, b_idx, b_val = outs[0]
    s = a.bfloat16().double() @ b.bfloat16().double().t()  # bf16 x bf16 is exact in float32; sums in float32
    if ka:
        assert torch.equal(a_idx, s.topk(ka, dim=1).indices)
        assert torch.allclose(a_val.double(), s.gather(1, a_idx), atol=1e-5)
    if kb:
        assert torch.equal(b_idx, s.topk(kb, dim=0).indices.t())
        assert torch.allclose(b_val.double(), s.t().gather(1, b_idx), atol=1e-5)
    exact = ext.topk_dots_both(a, b, max(ka, 1), 0, False)[1]  # the rounding is visible: not the float32 values
    if r > 8:
        assert not torch.equal(exact, ext.topk_dots_both(a, b, max(ka, 1), 0, True)[1])


@needs_kernels
def test_kernel_topk_dots_both_rejects_bad_input():
    ext = cpu_kernels.load_extension()
    a, b = torch.randn(5, 4), torch.randn(6, 4)
    with pytest.raises(RuntimeError, match="need 0 <= ka <= Nb"):
        ext.topk_dots_both(a, b, 7, 1)
    with pytest.raises(RuntimeError, match="not both 0"):
        ext.topk_dots_both(a, b, 0, 0)
    with pytest.raises(RuntimeError, match="a \\(Na, R\\), b \\(Nb, R\\)"):
        ext.topk_dots_both(a, torch.randn(6, 3), 1, 1)
    if not ext.bf16_dot_available():
        with pytest.raises(RuntimeError, match="AVX512-BF16"):
            ext.topk_dots_both(a, b, 1, 1, True)


@pytest.mark.parametrize("products", ["float32", "bfloat16"])
@pytest.mark.parametrize("use_kernels", [True, False])
def test_projected_search_is_exact_where_the_projection_loses_nothing(monkeypatch, use_kernels, products):
    """Features in a 12-dimensional subspace: a rank-12 projection keeps every similarity, so the projected search
    returns the exact neighbour sets (the candidates hold the true neighbours, the exact re-ranking orders them), also
    when the candidates come from bf16 products (their rounding reorders candidates, not the exact re-ranking)."""
    if use_kernels and not cpu_kernels.is_available():
        pytest.skip("the CPU kernels' extension did not build here (make install builds it)")
    if not use_kernels:
        monkeypatch.setattr(knn, "_cpu_kernels", lambda: None)
    g = torch.Generator().manual_seed(3)
    basis = torch.randn(64, 12, generator=g)
    f_r = (basis @ torch.randn(12, 250, generator=g)).relu() + 1e-3
    f_s = (basis @ torch.randn(12, 400, generator=g)).relu() + 1e-3
    style = knn.StyleFeatures.of(f_s)
    f_r = basis @ torch.linalg.lstsq(basis, f_r).solution  # back into the subspace after the ReLU
    style = knn.StyleFeatures.of(basis @ torch.linalg.lstsq(basis, style.raw).solution)
    proj = knn.Projection(rank=12, candidates=8, products=products)
    for k_rs, k_sr in [(5, 5), (1, 0), (0, 3)]:
        a_rs, a_sr = knn.cosine_topk(f_r, style, k_rs, k_sr, projection=proj)
        b_rs, b_sr = knn.cosine_topk(f_r, style, k_rs, k_sr, search="exact")
        assert (a_rs is None) == (b_rs is None) and (a_sr is None) == (b_sr is None)
        if b_rs is not None:
            assert _same_sets(a_rs, b_rs, 1)
        if b_sr is not None:
            assert a_sr.shape == b_sr.shape and _same_sets(a_sr, b_sr, 0)


def test_projected_search_in_the_losses():
    """FAST, NNFM and KNNFM take the projected search from FastParams: with candidates covering every feature the
    result equals the exact search's (how close it is otherwise depends on the features: eval/bench/knn_recall.py)."""
    f_r, f_s = _feats(96, 300, 120, seed=7)
    style = knn.StyleFeatures.of(f_s)
    exact = FastParams(knn_search="exact", projection_rank=0)
    # every feature is a candidate both ways, and the size threshold is off
    full = FastParams(projection_rank=8, projection_candidates=300, projection_min_similarities=0)
    assert knn.projection_of(full) == knn.Projection(8, 300, 0, "auto") and knn.projection_of(exact) is None
    for method in ("fast", "nnfm", "knnfm"):
        a = losses.style_loss(method, [(f_r, style)], fast_params=exact)
        b = losses.style_loss(method, [(f_r, style)], fast_params=full)
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-7), method
    with pytest.raises(ValidationError):
        FastParams(projection_rank=-1)
    with pytest.raises(InputError, match="projection search"):
        knn.Projection(rank=0)
    with pytest.raises(InputError, match="auto, float32 or bfloat16"):
        knn.Projection(rank=8, products="float16")
    with pytest.raises(ValidationError):
        FastParams(projection_products="bf16")
    assert knn.projection_of(FastParams()).products == "auto"
    assert knn.Projection(8, products="auto").bf16_products() == knn.bf16_dot_available()
    assert knn.Projection(8, products="bfloat16").bf16_products() and not knn.Projection(8).bf16_products()


def test_projected_search_runs_only_where_it_applies(monkeypatch):
    """The default FastParams ask for the projected search, but below ``projection_min_similarities`` (the tiny scene's
    searches), at a rank not below the channel count and on a GPU the exact search runs."""
    proj = knn.projection_of(FastParams())
    assert proj is not None and proj.rank == 128 and proj.min_similarities == 2**22
    cpu, gpu = torch.device("cpu"), torch.device("cuda")
    assert proj.applies(2852, 6528, 768, cpu) and not proj.applies(300, 1000, 768, cpu)
    assert not proj.applies(2852, 6528, 96, cpu) and not proj.applies(2852, 6528, 768, gpu)
    calls = []
    monkeypatch.setattr(knn, "_projected_topk", lambda *a: calls.append(a) or (None, None))
    f_r, f_s = _feats(96, 300, 500, seed=1)
    nn_default, _ = knn.cosine_topk(f_r, f_s, 5, 0, projection=proj)
    nn_exact, _ = knn.cosine_topk(f_r, f_s, 5, 0, search="exact")
    assert not calls and torch.equal(nn_default, nn_exact)
    knn.cosine_topk(f_r, f_s, 5, 0, projection=knn.Projection(16, 8, 0))
    assert len(calls) == 1
