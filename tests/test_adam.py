"""abcgs.fit.adam.Adam against torch.optim.Adam: the same parameters and state, bit for bit, in both modes."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from abcgs.errors import InputError
from abcgs.fit.adam import Adam
from abcgs.fit.strategy.ops import update_params
from abcgs.gaussians import GaussianModel


def _tensors(seed: int) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(shape, generator=g).requires_grad_(True) for shape in ((50, 3), (50,), (7, 1, 3))]


def _grads(params: list[torch.Tensor], step: int) -> None:
    g = torch.Generator().manual_seed(1000 + step)
    for i, p in enumerate(params):
        # step 3 leaves the second tensor without a gradient: its state must not advance
        p.grad = None if (step == 3 and i == 1) else torch.randn(p.shape, generator=g) * (10.0 ** (i - 1))


@pytest.mark.parametrize("mode", ["per_tensor", "fused"])
def test_adam_matches_torch_optim_adam_bit_for_bit(mode: str) -> None:
    ours_p, ref_p = _tensors(0), _tensors(0)
    lrs = (1e-2, 3e-4, 0.5)
    ours = Adam([{"params": [p], "lr": lr} for p, lr in zip(ours_p, lrs)], eps=1e-15, mode=mode)
    ref = torch.optim.Adam([{"params": [p], "lr": lr} for p, lr in zip(ref_p, lrs)], eps=1e-15,
                           fused=mode == "fused")
    for step in range(12):
        _grads(ours_p, step)
        _grads(ref_p, step)
        if step == 6:  # a schedule changes a group's rate between steps
            ours.param_groups[0]["lr"] = ref.param_groups[0]["lr"] = 2.5e-3
        ours.step()
        ref.step()
        ours.zero_grad(set_to_none=True)
        ref.zero_grad(set_to_none=True)
    for a, b in zip(ours_p, ref_p):
        assert torch.equal(a, b)
        sa, sb = ours.state[a], ref.state[b]
        assert set(sa) == set(sb) == {"step", "exp_avg", "exp_avg_sq"}
        for key in sa:
            assert sa[key].dtype == sb[key].dtype and sa[key].device == sb[key].device
            assert torch.equal(sa[key], sb[key]), key
    assert ours.state[ours_p[1]]["step"].item() == 11  # one step without a gradient


def test_adam_state_follows_densification_like_torch_optim() -> None:
    """update_params (clone / prune) remaps the state of this Adam as it does torch.optim's."""
    def model() -> GaussianModel:
        g = torch.Generator().manual_seed(3)
        n = 20
        return GaussianModel(means=torch.randn(n, 3, generator=g), quats=torch.randn(n, 4, generator=g),
                             log_scales=torch.randn(n, 3, generator=g) - 3, opacity_logits=torch.randn(n, generator=g),
                             sh0=torch.rand(n, 1, 3, generator=g), shN=torch.zeros(n, 0, 3))

    keep = torch.arange(20) % 3 != 0
    results = []
    for make in (lambda p: Adam([p], lr=1e-2, eps=1e-15), lambda p: torch.optim.Adam([p], lr=1e-2, eps=1e-15)):
        m = model()
        opts = {"means": make(m.means)}
        for step in range(3):
            m.means.grad = torch.full_like(m.means, 0.1 * (step + 1))
            opts["means"].step()
            opts["means"].zero_grad()
            if step == 1:
                update_params(m, opts, lambda _, p: torch.cat([p[keep], p[:2]]),
                              lambda _, v: torch.cat([v[keep], torch.zeros_like(v[:2])]), names=("means",))
        results.append((m.means.detach().clone(), {k: v.clone() for k, v in opts["means"].state[m.means].items()}))
    (a, sa), (b, sb) = results
    assert torch.equal(a, b)
    assert all(torch.equal(sa[k], sb[k]) for k in sb)


def test_adam_rejects_what_the_fused_kernel_cannot_take() -> None:
    with pytest.raises(InputError, match="fused Adam needs floating-point"):
        Adam([torch.zeros(3, dtype=torch.int64)], mode="fused")
    with pytest.raises(InputError, match="mode must be"):
        Adam([torch.zeros(3, requires_grad=True)], mode="foreach")


def test_an_adam_step_does_not_import_torch_compile() -> None:
    """The point of the module: a step in a fresh process leaves torch._dynamo unimported."""
    code = ("import sys, torch\nfrom abcgs.fit.adam import Adam\n"
            "p = torch.zeros(4, requires_grad=True)\nfor mode in ('per_tensor', 'fused'):\n"
            "    o = Adam([p], lr=0.1, mode=mode); p.grad = torch.ones(4); o.step(); o.zero_grad()\n"
            "print('torch._dynamo' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
