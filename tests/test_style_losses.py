"""Baseline style losses (NNFM, KNNFM, Gram), content, TV and the dispatcher."""

from __future__ import annotations

import pytest
import torch

from abcgs.errors import InputError
from abcgs.losses import terms as losses
from abcgs.losses.fast import FastStats, fast_loss
from abcgs.losses.params import FastParams


def _feats(c=12, n_r=40, n_s=33, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    return (
        (torch.randn(c, n_r, generator=g, dtype=dtype) + 0.3).relu(),
        (torch.randn(c, n_s, generator=g, dtype=dtype) + 0.3).relu(),
    )


def _cos(a, b):
    return (a / (a.norm(dim=0) + 1e-8)).t() @ (b / (b.norm(dim=0) + 1e-8))


@pytest.mark.parametrize("budget", [2**30, 100, 3])
def test_nnfm_is_one_minus_max_cosine(budget):
    f_r, f_s = _feats()
    ref = (1.0 - _cos(f_r, f_s).max(dim=1).values).mean()
    got = losses.nnfm_loss([(f_r, f_s)], max_block_elems=budget)
    assert torch.allclose(got, ref, atol=1e-10)


@pytest.mark.parametrize("budget", [2**30, 100, 3])
def test_knnfm_matches_brute_force(budget):
    f_r, f_s = _feats(seed=1)
    idx = _cos(f_r, f_s).topk(4, dim=1).indices  # (N_r, k)
    target = f_s[:, idx].mean(dim=2)
    a = f_r / (f_r.norm(dim=0) + 1e-8)
    b = target / (target.norm(dim=0) + 1e-8)
    ref = (1.0 - (a * b).sum(0)).mean()
    got = losses.knnfm_loss([(f_r, f_s)], k=4, max_block_elems=budget)
    assert torch.allclose(got, ref, atol=1e-10)


def test_gram_content_tv_values():
    f_r, f_s = _feats(c=5, n_r=8, n_s=6)
    g_r = f_r @ f_r.t() / (5 * 8)
    g_s = f_s @ f_s.t() / (5 * 6)
    assert torch.allclose(losses.gram_loss([(f_r, f_s)]), ((g_r - g_s) ** 2).mean())
    assert float(losses.gram_loss([(f_s, f_s)])) == 0.0
    x = torch.arange(12.0).view(1, 1, 3, 4)  # dx = 1, dy = 4
    assert float(losses.tv_loss(x)) == pytest.approx(1.0 + 16.0)
    a, b = torch.zeros(2, 3, 4, 4), torch.ones(2, 3, 4, 4)
    assert float(losses.content_loss(a, b)) == 1.0


@pytest.mark.parametrize("name", ["nnfm", "knnfm", "gram"])
def test_style_loss_gradcheck(name):
    f_r, f_s = _feats(c=4, n_r=6, n_s=5, seed=2)
    x = f_r.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t: losses.style_loss(name, [(t, f_s)], k=2), (x,))


def test_content_tv_gradcheck():
    g = torch.Generator().manual_seed(0)
    img = torch.rand(1, 3, 5, 6, generator=g, dtype=torch.float64, requires_grad=True)
    ref = torch.rand(1, 3, 5, 6, generator=g, dtype=torch.float64)
    assert torch.autograd.gradcheck(losses.tv_loss, (img,))
    assert torch.autograd.gradcheck(lambda t: losses.content_loss(t, ref), (img,))


def test_dispatcher_and_groups():
    g1, g2 = _feats(seed=3), _feats(seed=4, n_r=20, n_s=50)
    stats = FastStats()
    got = losses.style_loss("fast", [g1, g2], stats=stats)
    assert torch.allclose(got, fast_loss([g1, g2]))
    assert stats.solves == 2
    assert torch.allclose(losses.style_loss("fast", [g1], fast_params=FastParams(max_block_elems=7)), fast_loss([g1]))
    for name in ("nnfm", "knnfm", "gram"):
        both = losses.style_loss(name, [g1, g2])
        assert torch.allclose(both, losses.style_loss(name, [g1]) + losses.style_loss(name, [g2]))
    with pytest.raises(InputError, match="unknown style loss"):
        losses.style_loss("adain", [g1])  # type: ignore[arg-type]


def test_bad_inputs():
    f_r, f_s = _feats()
    with pytest.raises(InputError):
        losses.nnfm_loss([(f_r, f_s[:5])])
    with pytest.raises(InputError):
        losses.knnfm_loss([(f_r, f_s)], k=0)
    with pytest.raises(InputError):
        losses.gram_loss([])
    with pytest.raises(InputError, match="shapes differ"):
        losses.content_loss(torch.zeros(1, 3, 4, 4), torch.zeros(1, 3, 4, 5))
    with pytest.raises(InputError):
        losses.tv_loss(torch.zeros(3, 4, 4))


def test_group_features_equal_boolean_indexing_values_and_gradients():
    """A mask covering every cell gives a view of all columns (no copy), a partial one the masked columns; both equal
    ``feats[:, mask]`` in value and gradient, and the full mask's result shares the features' storage."""
    from abcgs.stylize.targets import group_features

    g = torch.Generator().manual_seed(0)
    base = torch.randn(6, 4, 5, generator=g)
    for mask in (torch.ones(4, 5, dtype=torch.bool), torch.rand(4, 5, generator=g) > 0.5):
        a, b = base.clone().requires_grad_(True), base.clone().requires_grad_(True)
        fa, fb = group_features(a, mask), b[:, mask]
        assert torch.equal(fa, fb)
        w = torch.randn(fa.shape, generator=g)
        (fa * w).sum().backward()
        (fb * w).sum().backward()
        assert torch.equal(a.grad, b.grad)
        if bool(mask.all()):
            assert fa.data_ptr() == a.data_ptr()
