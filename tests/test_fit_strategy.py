"""Densification: clone / split / prune / opacity reset keep parameters and Adam state consistent."""

from __future__ import annotations

import math

import pytest
import torch

from abcgs.fit.data import scene_extent
from abcgs.fit.params import FitParams, StrategyParams
from abcgs.fit.strategy import DefaultStrategy, NoDensification
from abcgs.fit.strategy.ops import duplicate, remove, reset_opacity, split
from abcgs.fit.training import make_optimizers
from abcgs.gaussians import FROZEN, PARAM_NAMES, GaussianModel, freeze_gaussians
from abcgs.render import RenderMeta, quat_to_rotmat


def make_model(n: int, degree: int = 1, seed: int = 0) -> GaussianModel:
    g = torch.Generator().manual_seed(seed)
    return GaussianModel(
        means=torch.randn(n, 3, generator=g),
        quats=torch.randn(n, 4, generator=g),
        log_scales=torch.log(0.05 + 0.1 * torch.rand(n, 3, generator=g)),
        opacity_logits=torch.randn(n, generator=g),
        sh0=torch.randn(n, 1, 3, generator=g),
        shN=torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g),
    ).as_parameters()


def warm_optimizers(model: GaussianModel):
    """Adam with non-zero moments for every parameter (one step on a loss touching all of them)."""
    opts = make_optimizers(model, FitParams(), extent=1.0)
    loss = sum((t * torch.arange(t.numel()).reshape(t.shape).float().sin()).sum() for _, t in model.items())
    loss.backward()
    for o in opts.values():
        o.step()
        o.zero_grad(set_to_none=True)
    return opts


def assert_consistent(model: GaussianModel, opts, state=None):
    n = model.num_gaussians
    for name in PARAM_NAMES:
        p = getattr(model, name)
        assert p.shape[0] == n and p.requires_grad and p.is_leaf, name
        group_params = opts[name].param_groups[0]["params"]
        assert len(group_params) == 1 and group_params[0] is p, name
        st = opts[name].state[p]
        assert st["exp_avg"].shape == p.shape and st["exp_avg_sq"].shape == p.shape, name
    for k, v in (state or {}).items():
        assert v.shape[0] == n, k


def fake_meta(grad: torch.Tensor, visible: torch.Tensor, radii: torch.Tensor | None = None, w=40, h=30) -> RenderMeta:
    n = grad.shape[0]
    means2d = torch.zeros(n, 2, requires_grad=True)
    means2d.grad = grad.clone()
    radii = torch.full((n, 2), 3, dtype=torch.int32) if radii is None else radii
    return RenderMeta(means2d, radii, torch.ones(n), visible, None, "cpu", w, h)


def test_duplicate_split_remove_keep_optimizer_state_consistent():
    model = make_model(10)
    opts = warm_optimizers(model)
    before = {name: (getattr(model, name).detach().clone(), opts[name].state[getattr(model, name)]["exp_avg"].clone())
              for name in PARAM_NAMES}
    state = {"grad2d": torch.arange(10.0), "count": torch.ones(10)}

    mask = torch.zeros(10, dtype=torch.bool)
    mask[[1, 4]] = True
    assert duplicate(model, opts, state, mask) == 2
    assert model.num_gaussians == 12
    assert_consistent(model, opts, state)
    for name in PARAM_NAMES:
        p = getattr(model, name)
        assert torch.equal(p[:10], before[name][0]) and torch.equal(p[10:], before[name][0][[1, 4]])
        ea = opts[name].state[p]["exp_avg"]
        assert torch.equal(ea[:10], before[name][1]) and torch.all(ea[10:] == 0)

    smask = torch.zeros(12, dtype=torch.bool)
    smask[[0, 11]] = True
    assert split(model, opts, state, smask, generator=torch.Generator().manual_seed(0)) == 2
    assert model.num_gaussians == 14  # 12 - 2 parents + 4 children
    assert_consistent(model, opts, state)
    # survivors keep their order (old #1..#9, then the clone of #1); children follow
    old_op = before["opacity_logits"][0]
    assert torch.equal(model.opacity_logits[:10], torch.cat([old_op[1:10], old_op[[1]]]))
    assert torch.equal(model.opacity_logits[10:], torch.cat([old_op[[0, 4]], old_op[[0, 4]]]))  # #11 = clone of #4
    assert torch.all(opts["means"].state[model.means]["exp_avg"][10:] == 0)

    rmask = torch.zeros(14, dtype=torch.bool)
    rmask[[2, 3, 13]] = True
    kept_means = model.means[~rmask].detach().clone()
    kept_state = opts["sh0"].state[model.sh0]["exp_avg_sq"][~rmask].clone()
    assert remove(model, opts, state, rmask) == 3
    assert model.num_gaussians == 11
    assert_consistent(model, opts, state)
    assert torch.equal(model.means, kept_means)
    assert torch.equal(opts["sh0"].state[model.sh0]["exp_avg_sq"], kept_state)

    # the optimisers still step with the new tensors
    sum(t.sum() for _, t in model.items()).backward()
    for o in opts.values():
        o.step()


def test_split_children_preserve_parent_in_expectation():
    n = 20000
    quat = torch.tensor([0.9, 0.2, -0.3, 0.25])
    scales = torch.tensor([0.5, 0.1, 0.02])
    model = GaussianModel(
        means=torch.tensor([1.0, -2.0, 3.0]).repeat(n, 1),
        quats=quat.repeat(n, 1),
        log_scales=scales.log().repeat(n, 1),
        opacity_logits=torch.zeros(n),
        sh0=torch.zeros(n, 1, 3),
        shN=torch.zeros(n, 0, 3),
    ).as_parameters()
    opts = make_optimizers(model, FitParams(), 1.0)
    split(model, opts, {}, torch.ones(n, dtype=torch.bool), generator=torch.Generator().manual_seed(0))
    assert model.num_gaussians == 2 * n
    children = model.means.detach().double()
    # mean within ~4 standard errors of the parent's mean along the widest axis
    assert torch.allclose(children.mean(0), torch.tensor([1.0, -2.0, 3.0], dtype=torch.float64), atol=4 * 0.5 / math.sqrt(2 * n))
    # the children are distributed like the parent Gaussian
    R = quat_to_rotmat(quat[None])[0].double()
    cov = R @ torch.diag(scales.double() ** 2) @ R.T
    assert torch.allclose(torch.cov(children.T), cov, atol=0.01)
    assert torch.allclose(model.log_scales.detach().exp(), (scales / 1.6).expand(2 * n, 3), rtol=1e-5)


def test_prune_removes_exactly_low_opacity():
    model = make_model(8)
    opac = torch.tensor([0.5, 0.004, 0.2, 0.001, 0.0051, 0.9, 0.0049, 0.3])
    with torch.no_grad():
        model.opacity_logits.copy_(torch.logit(opac))
    opts = warm_optimizers(model)
    with torch.no_grad():
        model.opacity_logits.copy_(torch.logit(opac))  # undo the warm-up step
    params = StrategyParams(refine_start=0, refine_every=1, reset_every=1000, refine_stop=100, grow_grad2d=1e9)
    strat = DefaultStrategy(params, scene_extent=1.0)
    state = strat.initialize_state(model)
    keep_means = model.means.detach()[opac >= 0.005]
    report = strat.step_post_backward(model, opts, state, 1, fake_meta(torch.zeros(8, 2), torch.ones(8, dtype=torch.bool)))
    assert report.n_pruned == 3 and report.n_duplicated == 0 and report.n_split == 0
    assert torch.equal(model.means.detach(), keep_means)
    assert_consistent(model, opts, state)


def test_prune_large_only_after_first_reset():
    model = make_model(4)
    with torch.no_grad():
        model.opacity_logits.fill_(2.0)
        model.log_scales.fill_(math.log(0.05))
        model.log_scales[0] = math.log(0.5)  # world-size too big for extent 1 (> 0.1)
    opts = warm_optimizers(model)
    params = StrategyParams(refine_start=0, refine_every=1, reset_every=10, refine_stop=100, grow_grad2d=1e9)
    strat = DefaultStrategy(params, scene_extent=1.0)
    state = strat.initialize_state(model)
    radii = torch.tensor([[2, 2], [25, 3], [3, 3], [3, 3]], dtype=torch.int32)  # #1 too big on screen (> 20 px)
    meta = lambda: fake_meta(torch.zeros(model.num_gaussians, 2), torch.ones(model.num_gaussians, dtype=torch.bool), radii)  # noqa: E731
    assert strat.step_post_backward(model, opts, state, 5, meta()).n_pruned == 0  # before the first reset
    assert strat.step_post_backward(model, opts, state, 11, meta()).n_pruned == 2  # after: world and screen size
    assert model.num_gaussians == 2


def test_grow_clones_small_splits_large_and_respects_cap():
    n = 6

    def sized_model() -> GaussianModel:
        model = make_model(n)
        with torch.no_grad():
            model.log_scales.fill_(math.log(0.005))  # #0-#2 small (<= 0.01 × extent 1)
            model.log_scales[3:] = math.log(0.2)  # #3-#5 large
            model.opacity_logits.fill_(2.0)
        return model

    model = sized_model()
    opts = warm_optimizers(model)
    params = StrategyParams(refine_start=0, refine_every=2, reset_every=1000, refine_stop=100)
    # high gradients (NDC units: px-gradient × W/2) for #0, #1 (small) and #3 (large); #5 is high but invisible
    g_ndc = torch.tensor([1e-3, 5e-4, 1e-5, 3e-3, 1e-5, 1.0])
    grad = torch.stack([g_ndc / 20.0, torch.zeros(n)], -1)  # W = 40 → × 20
    visible = torch.tensor([True, True, True, True, True, False])

    strat = DefaultStrategy(params, scene_extent=1.0)
    state = strat.initialize_state(model)
    assert strat.step_post_backward(model, opts, state, 1, fake_meta(grad, visible)) is None  # statistics only
    assert torch.allclose(state["grad2d"], torch.where(visible, g_ndc, torch.zeros(n)), rtol=1e-5)
    assert torch.equal(state["count"], visible.float())
    report = strat.step_post_backward(model, opts, state, 2, fake_meta(grad, visible))
    assert (report.n_duplicated, report.n_split, report.n_pruned) == (2, 1, 0)
    assert model.num_gaussians == n + 2 + 1
    assert_consistent(model, opts, state)
    assert torch.all(state["grad2d"] == 0)  # statistics restart after a refinement

    # cap: only one Gaussian may be added → the highest-gradient candidate (#3, split) wins
    model2 = sized_model()
    opts2 = warm_optimizers(model2)
    strat2 = DefaultStrategy(params, scene_extent=1.0, max_gaussians=n + 1)
    state2 = strat2.initialize_state(model2)
    strat2.step_post_backward(model2, opts2, state2, 1, fake_meta(grad, visible))
    report2 = strat2.step_post_backward(model2, opts2, state2, 2, fake_meta(grad, visible))
    assert (report2.n_duplicated, report2.n_split, report2.capped) == (0, 1, True)
    assert model2.num_gaussians == n + 1


def test_opacity_reset():
    model = make_model(5)
    opts = warm_optimizers(model)
    logits_before = model.opacity_logits.detach().clone()
    reset_opacity(model, opts, 0.01)
    op = torch.sigmoid(model.opacity_logits.detach())
    assert torch.all(op <= 0.01 + 1e-7)
    low = torch.sigmoid(logits_before) < 0.01
    assert torch.equal(model.opacity_logits.detach()[low], logits_before[low])
    st = opts["opacity_logits"].state[model.opacity_logits]
    assert torch.all(st["exp_avg"] == 0) and torch.all(st["exp_avg_sq"] == 0)
    assert_consistent(model, opts)

    # through the strategy: at multiples of reset_every
    strat = DefaultStrategy(StrategyParams(refine_start=1000, reset_every=3, refine_stop=100), scene_extent=1.0)
    model = make_model(5)
    with torch.no_grad():
        model.opacity_logits.fill_(3.0)
    opts = warm_optimizers(model)
    state = strat.initialize_state(model)
    meta = lambda: fake_meta(torch.zeros(5, 2), torch.ones(5, dtype=torch.bool))  # noqa: E731
    assert strat.step_post_backward(model, opts, state, 2, meta()) is None
    assert strat.step_post_backward(model, opts, state, 3, meta()).opacity_reset
    assert torch.all(torch.sigmoid(model.opacity_logits) <= 0.0100001)


def test_no_densification_and_refine_stop():
    model = make_model(4)
    opts = warm_optimizers(model)
    nd = NoDensification()
    state = nd.initialize_state(model)
    assert nd.step_post_backward(model, opts, state, 100, None) is None
    strat = DefaultStrategy(StrategyParams(refine_start=0, refine_every=1, refine_stop=10, reset_every=1), 1.0)
    state = strat.initialize_state(model)
    # past refine_stop nothing happens, even without a gradient on means2d
    meta = RenderMeta(torch.zeros(4, 2), torch.zeros(4, 2, dtype=torch.int32), torch.ones(4), torch.ones(4, dtype=torch.bool), None, "cpu", 4, 4)
    assert strat.step_post_backward(model, opts, state, 10, meta) is None
    assert model.num_gaussians == 4


def test_schedule_resolution_and_validation():
    p = StrategyParams().resolved(300)
    assert (p.refine_start, p.refine_stop, p.refine_every, p.reset_every) == (30, 150, 10, 3000)
    with pytest.raises(ValueError):
        StrategyParams(unknown=1)
    with pytest.raises(ValueError):
        StrategyParams(prune_opacity=0.02, reset_opacity=0.01)
    assert scene_extent(torch.tensor([[0.0, 0, 0], [2.0, 0, 0]])) == pytest.approx(1.1)
    assert scene_extent(torch.zeros(1, 3), torch.tensor([[0.0, 0, 0], [0, 4.0, 0]])) == pytest.approx(2.2)


def test_per_gaussian_attributes_follow_their_gaussians_through_1000_densification_steps():
    model = make_model(300, degree=1, seed=3)
    n = model.num_gaussians
    labels = torch.arange(n) % 11
    with torch.no_grad():
        model.sh0[:, 0, 0] = labels.float()  # clones and split children copy sh0 unchanged: the label's witness
    model.attributes = {"label": labels.clone(), "mask": (labels % 2 == 0)[:, None].repeat(1, 2)}
    opts = warm_optimizers(model)
    g = torch.Generator().manual_seed(0)
    counts = {"duplicate": 0, "split": 0, "remove": 0}
    for step in range(1000):
        n = model.num_gaussians
        mask = torch.rand(n, generator=g) < 0.02
        op = ("duplicate", "split", "remove")[int(torch.randint(0, 3, (), generator=g))]
        if op == "remove" and n < 150 or op != "remove" and n > 3000:
            op = "duplicate" if op == "remove" else "remove"
        if op == "duplicate":
            counts[op] += duplicate(model, opts, {}, mask)
        elif op == "split":
            counts[op] += split(model, opts, {}, mask, generator=g)
        else:
            counts[op] += remove(model, opts, {}, mask)
        if step % 97 == 0:
            reset_opacity(model, opts, 0.01)
        label, pair = model.attributes["label"], model.attributes["mask"]
        assert label.shape == (model.num_gaussians,) and pair.shape == (model.num_gaussians, 2)
        assert torch.equal(label, model.sh0[:, 0, 0].detach().round().long()), step
        assert torch.equal(pair, (label % 2 == 0)[:, None].repeat(1, 2)), step
    assert all(c > 500 for c in counts.values()), counts
    assert_consistent(model, opts)
    # selections and copies carry them too
    sub = model.index(model.attributes["label"] == 3)
    assert bool((sub.attributes["label"] == 3).all()) and sub.num_gaussians == int((model.attributes["label"] == 3).sum())
    assert torch.equal(model.detach().attributes["label"], model.attributes["label"])


def test_frozen_gaussians_are_never_grown_pruned_or_reset():
    """Rows marked FROZEN keep their opacity through a reset, and the strategy neither grows nor prunes them, though
    every Gaussian has a gradient over the threshold and half of them an opacity under the pruning one."""
    model = make_model(40, seed=5)
    n = model.num_gaussians
    frozen = torch.arange(n) % 2 == 0
    with torch.no_grad():
        model.opacity_logits[: n // 2] = -8.0  # under prune_opacity
        model.opacity_logits[n // 2:] = 4.0  # over reset_opacity
    model.attributes = {FROZEN: frozen.clone()}
    opts = warm_optimizers(model)
    before = model.opacity_logits.detach().clone()
    strategy = DefaultStrategy(StrategyParams(refine_start=0, refine_every=1, refine_stop=10, reset_every=2))
    state = strategy.initialize_state(model)
    state["grad2d"][:] = 1.0
    state["count"][:] = 1.0
    strategy._grow(model, opts, state)
    assert int(model.attributes[FROZEN].sum()) == int(frozen.sum())  # none cloned or split
    assert int((~model.attributes[FROZEN]).sum()) == 2 * int((~frozen).sum())  # each other one was
    strategy._prune(model, opts, state, step=1)
    kept = model.attributes[FROZEN]
    assert int(kept.sum()) == int(frozen.sum())  # none pruned, though half are under prune_opacity
    assert float(torch.sigmoid(model.opacity_logits.detach()[~kept]).min()) >= 0.005  # the others were
    assert torch.equal(model.opacity_logits.detach()[kept], before[frozen])
    reset_opacity(model, opts, 0.01, keep=model.attributes[FROZEN])
    assert torch.equal(model.opacity_logits.detach()[kept], before[frozen])
    assert float(model.opacity_logits.detach()[~kept].max()) <= math.log(0.01 / 0.99) + 1e-6


def test_freezing_again_after_a_reset_hooks_only_the_tensor_it_replaced():
    """The fit calls freeze_gaussians after every refinement: a tensor the step kept keeps its one hook, the opacity
    tensor a reset replaced gets one, and the frozen rows take no gradient in any field."""
    model = make_model(12, seed=2)
    model.attributes = {FROZEN: torch.arange(12) < 5}
    opts = warm_optimizers(model)
    freeze_gaussians(model)
    kept = {name: t for name, t in model.items()}
    reset_opacity(model, opts, 0.01)
    freeze_gaussians(model)
    for name, t in model.items():
        assert (t is kept[name]) == (name != "opacity_logits")  # only the reset's tensor is new
        assert len(t._backward_hooks) == 1, name  # noqa: SLF001  (one hook each, not one per call)
    sum((t * t).sum() for _, t in model.items()).backward()
    for name, t in model.items():
        assert not t.grad[:5].any() and t.grad[5:].any(), name


def test_an_attribute_of_another_length_is_refused():
    from abcgs.errors import InputError

    model = make_model(10).detach()
    with pytest.raises(InputError, match="attribute 'label'"):
        GaussianModel(**model.params(), attributes={"label": torch.zeros(9)})


def test_batched_meta_counts_each_view():
    """A step that renders C views (meta with a leading camera axis) adds each view's NDC gradient norm and counts
    each view a Gaussian is visible in; the largest radius over the views is kept. One view batched as (1, N, 2)
    gives the statistics of the unbatched meta."""
    strategy = DefaultStrategy(StrategyParams())
    model = make_model(4)
    grad = torch.tensor([[[1.0, 0.0], [0.0, 2.0], [3.0, 4.0], [1.0, 1.0]],
                         [[0.5, 0.0], [0.0, 0.0], [1.0, 0.0], [2.0, 2.0]]])
    visible = torch.tensor([[True, True, False, True], [True, False, True, False]])
    radii = torch.tensor([[[2, 1], [4, 4], [9, 9], [1, 1]], [[5, 3], [1, 1], [7, 2], [8, 8]]], dtype=torch.int32)
    means2d = torch.zeros(2, 4, 2, requires_grad=True)
    means2d.grad = grad.clone()
    meta = RenderMeta(means2d, radii, torch.ones(2, 4), visible, None, "cpu", 40, 30)
    state = strategy.initialize_state(model)
    strategy._update_state(state, meta, 4)
    ndc = torch.tensor([20.0, 15.0])
    expected = torch.zeros(4)
    for c in range(2):
        expected += torch.where(visible[c], (grad[c] * ndc).norm(dim=-1), torch.zeros(4))
    torch.testing.assert_close(state["grad2d"], expected)
    assert state["count"].tolist() == [2.0, 1.0, 1.0, 1.0]
    assert state["max_radii"].tolist() == [5.0, 4.0, 7.0, 1.0]

    one, batched = strategy.initialize_state(model), strategy.initialize_state(model)
    strategy._update_state(one, fake_meta(grad[0], visible[0], radii[0]), 4)
    m1 = torch.zeros(1, 4, 2, requires_grad=True)
    m1.grad = grad[:1].clone()
    strategy._update_state(batched, RenderMeta(m1, radii[:1], torch.ones(1, 4), visible[:1], None, "cpu", 40, 30), 4)
    assert all(torch.equal(one[k], batched[k]) for k in one)
