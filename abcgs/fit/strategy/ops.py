"""Operations on a model and its optimisers that add, remove or reset Gaussians (gsplat's ``strategy/ops.py``).

Each replaces the model's tensors (``setattr`` of new ``nn.Parameter`` s) and keeps every optimiser's
per-parameter state (Adam's ``exp_avg``/``exp_avg_sq``), the model's per-Gaussian attributes (copied to clones and
split children, dropped with the pruned) and the strategy's per-Gaussian statistics the same length as the
parameters: :func:`duplicate` (clone), :func:`split`, :func:`remove` (prune) and
:func:`reset_opacity`, all built on :func:`update_params`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from abcgs.fit.adam import Adam
from abcgs.gaussians import PARAM_NAMES, GaussianModel
from abcgs.render import quat_to_rotmat

Optimizers = dict[str, Adam]
"""One optimiser per parameter name (:data:`abcgs.gaussians.PARAM_NAMES`); missing names are frozen."""

State = dict[str, Any]
"""A strategy's running statistics; per-Gaussian tensors in it are kept in step with the model."""


@torch.no_grad()
def update_params(
    model: GaussianModel,
    optimizers: Optimizers,
    param_fn: Callable[[str, Tensor], Tensor],
    optimizer_fn: Callable[[str, Tensor], Tensor],
    names: tuple[str, ...] = PARAM_NAMES,
    attributes: bool = True,
) -> None:
    """Replace ``model.<name>`` by ``Parameter(param_fn(name, old))`` and remap the optimiser state.

    Every per-parameter optimiser state tensor shaped like the parameter (Adam's ``exp_avg``,
    ``exp_avg_sq``) becomes ``optimizer_fn(key, old_state)``; scalars such as Adam's ``step`` are kept. With
    ``attributes``, every per-Gaussian attribute (``model.attributes``) becomes ``param_fn(name, old)`` too, so
    that it follows its Gaussians through a clone, split or prune.
    """
    for name in names:
        old = getattr(model, name)
        new = torch.nn.Parameter(param_fn(name, old.detach()).contiguous(), requires_grad=old.requires_grad)
        opt = optimizers.get(name)
        if opt is not None:
            for group in opt.param_groups:
                for i, p in enumerate(group["params"]):
                    if p is old:
                        group["params"][i] = new
                        st = opt.state.pop(p, None)
                        if st is not None:
                            opt.state[new] = {
                                k: optimizer_fn(k, v) if isinstance(v, Tensor) and v.shape == old.shape else v
                                for k, v in st.items()
                            }
        setattr(model, name, new)
    if attributes:
        model.attributes = {name: param_fn(name, value) for name, value in model.attributes.items()}


def _extend_state(state: State, n_old: int, keep: Tensor | None, n_new: int) -> None:
    """Per-Gaussian state tensors: rows ``keep`` (all if None), then ``n_new`` zero rows."""
    for k, v in state.items():
        if isinstance(v, Tensor) and v.dim() > 0 and v.shape[0] == n_old:
            base = v if keep is None else v[keep]
            state[k] = torch.cat([base, v.new_zeros((n_new, *v.shape[1:]))])


@torch.no_grad()
def duplicate(model: GaussianModel, optimizers: Optimizers, state: State, mask: Tensor) -> int:
    """Clone the Gaussians in ``mask`` ``(N,)`` bool; copies are appended at the end. Returns the count.

    The copies start with zero optimiser moments (3DGS's ``densification_postfix``).
    """
    sel = torch.where(mask)[0]
    n_old = model.num_gaussians
    update_params(
        model, optimizers,
        lambda _, p: torch.cat([p, p[sel]]),
        lambda _, v: torch.cat([v, v.new_zeros((len(sel), *v.shape[1:]))]),
    )
    _extend_state(state, n_old, None, len(sel))
    return len(sel)


@torch.no_grad()
def split(
    model: GaussianModel,
    optimizers: Optimizers,
    state: State,
    mask: Tensor,
    *,
    samples: int = 2,
    generator: torch.Generator | None = None,
) -> int:
    """Replace each Gaussian in ``mask`` by ``samples`` children drawn from it. Returns the number split.

    Child means are samples of the parent's 3-D Gaussian ``N(μ, R S² Rᵀ)`` (so the children's mean
    equals the parent's in expectation); child scales are the parent's divided by 0.8·samples
    (1.6 for two); rotation, opacity and colour are copied. Survivors keep their order and optimiser
    state; the children are appended with zero moments.
    """
    sel = torch.where(mask)[0]
    rest = torch.where(~mask)[0]
    n_old = model.num_gaussians
    scales = torch.exp(model.log_scales[sel])
    rot = quat_to_rotmat(model.quats[sel])
    noise = torch.randn((samples, len(sel), 3), generator=generator, dtype=scales.dtype, device=scales.device)
    offsets = torch.einsum("nij,bnj->bni", rot, scales * noise)  # (samples, S, 3)
    divisor = 0.8 * samples

    def param_fn(name: str, p: Tensor) -> Tensor:
        if name == "means":
            children = (p[sel] + offsets).reshape(-1, 3)
        elif name == "log_scales":
            children = torch.log(scales / divisor).repeat(samples, 1)
        else:
            children = p[sel].repeat(samples, *([1] * (p.dim() - 1)))
        return torch.cat([p[rest], children])

    update_params(
        model, optimizers, param_fn,
        lambda _, v: torch.cat([v[rest], v.new_zeros((samples * len(sel), *v.shape[1:]))]),
    )
    _extend_state(state, n_old, rest, samples * len(sel))
    return len(sel)


@torch.no_grad()
def remove(model: GaussianModel, optimizers: Optimizers, state: State, mask: Tensor) -> int:
    """Delete the Gaussians in ``mask`` ``(N,)`` bool (parameters, optimiser moments, state rows)."""
    keep = torch.where(~mask)[0]
    n_old = model.num_gaussians
    update_params(model, optimizers, lambda _, p: p[keep], lambda _, v: v[keep])
    _extend_state(state, n_old, keep, 0)
    return n_old - len(keep)


@torch.no_grad()
def reset_opacity(model: GaussianModel, optimizers: Optimizers, value: float, *, keep: Tensor | None = None) -> None:
    """Clamp every opacity to at most ``value`` and zero the opacity optimiser moments (3DGS reset); the ``keep``
    ``(N,)`` bool Gaussians keep their opacity."""
    cap = math.log(value / (1.0 - value))

    def clamp(_, p: Tensor) -> Tensor:
        return p.clamp_max(cap) if keep is None else torch.where(keep, p, p.clamp_max(cap))

    update_params(model, optimizers, clamp, lambda _, v: torch.zeros_like(v), names=("opacity_logits",),
                  attributes=False)
