"""Adam (Kingma and Ba 2015), the optimiser of 3DGS fitting and of the stylization, without ``torch.optim``.

The update, per parameter tensor ``p`` with gradient ``g`` at step ``t`` (1, 2, …), as ``torch.optim.Adam`` computes
it (no weight decay, no AMSGrad)::

    m ← m + (1 − β₁)(g − m)            (exp_avg.lerp_)
    v ← β₂ v + (1 − β₂) g²
    p ← p − lr / (1 − β₁ᵗ) · m / (√v / √(1 − β₂ᵗ) + ε)

Two modes, each the same arithmetic as ``torch.optim.Adam`` with the same setting, bit for bit
(``tests/test_adam.py`` runs both side by side, through learning-rate changes and densification's state surgery):

- ``"per_tensor"``: ``torch.optim.Adam(fused=False)`` on CPU tensors (its ``_single_tensor_adam``), the ops in its order;
- ``"fused"``: ``torch.optim.Adam(fused=True)``: ATen's fused kernel ``torch._fused_adam_``, one pass over each tensor.

Why not ``torch.optim.Adam`` itself: its ``step`` and ``add_param_group`` import ``torch._dynamo`` (torch.compile's
tracer) on first use, only to exempt themselves from compilation, which abcgs never uses. That import takes 1.1 s on
the 2-core machine, in every stage process that optimises (``fit``, ``colormatch``, ``stylize``: 7 of the 20 stages of
``make run``). The state layout is ``torch.optim``'s (``state[p]`` holds ``step``, ``exp_avg``, ``exp_avg_sq``;
``param_groups[i]["lr"]``), which :func:`abcgs.fit.strategy.ops.update_params` remaps when Gaussians are added or
removed.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, Literal

import torch
from torch import Tensor

from abcgs.errors import InputError

AdamMode = Literal["per_tensor", "fused"]


class Adam:
    """Adam over parameter groups (``[{"params": [tensor, …], "lr": float}, …]``, or a list of tensors sharing
    ``lr``); ``betas`` and ``eps`` are shared by all groups. ``step()`` updates every parameter with a gradient;
    parameters without one keep their state untouched, as in ``torch.optim``."""

    def __init__(self, params: Iterable[Tensor] | Iterable[dict[str, Any]], lr: float = 1e-3,
                 betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8, mode: AdamMode = "per_tensor") -> None:
        groups = list(params)
        if groups and not isinstance(groups[0], dict):
            groups = [{"params": groups}]
        if mode not in ("per_tensor", "fused"):
            raise InputError(f"Adam mode must be 'per_tensor' or 'fused', got {mode!r}")
        self.param_groups: list[dict[str, Any]] = [{**g, "params": list(g["params"]), "lr": g.get("lr", lr)}
                                                   for g in groups]
        self.state: dict[Tensor, dict[str, Tensor]] = {}
        self.betas, self.eps, self.mode = (float(betas[0]), float(betas[1])), float(eps), mode
        if mode == "fused":
            for p in self._params():
                if not (p.is_floating_point() and p.device.type in ("cpu", "cuda")):
                    raise InputError(f"fused Adam needs floating-point CPU or CUDA tensors, got {p.dtype} on {p.device}")

    def _params(self) -> Iterable[Tensor]:
        return (p for g in self.param_groups for p in g["params"])

    def zero_grad(self, set_to_none: bool = True) -> None:
        """Drop (or zero) every parameter's gradient."""
        for p in self._params():
            if p.grad is None:
                continue
            if set_to_none:
                p.grad = None
            else:
                p.grad.detach_().zero_()

    def _state_of(self, p: Tensor) -> dict[str, Tensor]:
        st = self.state.get(p)
        if not st:  # torch.optim's initial state: the step a float32 scalar (on the device for the fused kernel)
            device = p.device if self.mode == "fused" else torch.device("cpu")
            st = self.state[p] = {"step": torch.zeros((), dtype=torch.float32, device=device),
                                  "exp_avg": torch.zeros_like(p, memory_format=torch.preserve_format),
                                  "exp_avg_sq": torch.zeros_like(p, memory_format=torch.preserve_format)}
        return st

    @torch.no_grad()
    def step(self) -> None:
        """One Adam update of every parameter that has a gradient."""
        for group in self.param_groups:
            params = [p for p in group["params"] if p.grad is not None]
            if not params:
                continue
            states = [self._state_of(p) for p in params]
            if self.mode == "fused":
                self._fused_step(params, states, float(group["lr"]))
            else:
                for p, st in zip(params, states):
                    self._tensor_step(p, st, float(group["lr"]))

    def _tensor_step(self, p: Tensor, st: dict[str, Tensor], lr: float) -> None:
        """``torch.optim.adam._single_tensor_adam``'s ops for one tensor (no weight decay, no AMSGrad)."""
        beta1, beta2 = self.betas
        grad = p.grad
        st["step"] += 1
        st["exp_avg"].lerp_(grad, 1 - beta1)
        st["exp_avg_sq"].mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
        t = st["step"].item()
        bias_correction1 = 1 - beta1**t
        bias_correction2 = 1 - beta2**t
        step_size = lr / bias_correction1
        denom = (st["exp_avg_sq"].sqrt() / bias_correction2**0.5).add_(self.eps)
        p.addcdiv_(st["exp_avg"], denom, value=-step_size)

    def _fused_step(self, params: list[Tensor], states: list[dict[str, Tensor]], lr: float) -> None:
        """``torch.optim.adam._fused_adam``: the steps advanced together, then ATen's fused kernel, per device and
        dtype."""
        by_kind: dict[tuple[torch.device, torch.dtype], list[int]] = {}
        for i, p in enumerate(params):
            by_kind.setdefault((p.device, p.dtype), []).append(i)
        for index in by_kind.values():
            steps = [states[i]["step"] for i in index]
            torch._foreach_add_(steps, 1)
            torch._fused_adam_(
                [params[i] for i in index], [params[i].grad for i in index], [states[i]["exp_avg"] for i in index],
                [states[i]["exp_avg_sq"] for i in index], [], steps, amsgrad=False, lr=lr, beta1=self.betas[0],
                beta2=self.betas[1], weight_decay=0.0, eps=self.eps, maximize=False, grad_scale=None, found_inf=None)
