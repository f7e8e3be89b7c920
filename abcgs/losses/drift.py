"""Eq. 8's geometry terms: how far the Gaussians' scales and opacities drift from the start of stylization.

- :func:`scale_drift` — ``mean_i ‖exp(l_i) − exp(l0_i)‖`` of log-scales ``l`` ``(N, 3)`` (scales in world units)
  against the start's ``l0`` ``(N, 3)``;
- :func:`opacity_drift` — ``mean_i |σ(z_i) − σ(z0_i)|`` of opacity logits ``z`` ``(N,)`` against the start's ``z0``
  ``(N,)``.

The start is passed in the same parametrisation as the trained values, and both are activated by the same code: a
Gaussian that has not moved has a drift of exactly 0, hence a zero gradient (the norm and ``|·|`` have a kink there,
where torch's backward gives 0).

Both are dense over every Gaussian, every step. On CPU tensors they run as one fused C++ pass each
(``abcgs/render/csrc/drift_cpu.cpp``: value and gradient together, the gradient applied in backward), where the torch
formulas (:func:`scale_drift_reference`, :func:`opacity_drift_reference`, their reference in
``tests/test_drift.py``) make about twenty passes over the Gaussians.
"""

from __future__ import annotations

import torch
from torch import Tensor


def scale_drift_reference(log_scales: Tensor, start_log_scales: Tensor) -> Tensor:
    """``mean_i ‖exp(l_i) − exp(l0_i)‖`` written with torch ops and autograd."""
    return (log_scales.exp() - start_log_scales.detach().exp()).norm(dim=-1).mean()


def opacity_drift_reference(logits: Tensor, start_logits: Tensor) -> Tensor:
    """``mean_i |σ(z_i) − σ(z0_i)|`` written with torch ops and autograd."""
    return (torch.sigmoid(logits) - torch.sigmoid(start_logits.detach())).abs().mean()


class _FusedDrift(torch.autograd.Function):
    """A drift term from the C++ kernel ``name`` (``scale_drift`` / ``opacity_drift``): its forward returns the value
    and the gradient w.r.t. the first input, which backward scales by the incoming gradient."""

    @staticmethod
    def forward(ctx, name: str, x: Tensor, start: Tensor) -> Tensor:
        from abcgs.render.cpu import load_extension

        value, grad = getattr(load_extension(), name)(x.detach(), start.detach().to(x.dtype))
        ctx.save_for_backward(grad)
        return value.to(x.dtype)

    @staticmethod
    def backward(ctx, grad_out: Tensor):
        (grad,) = ctx.saved_tensors
        return None, grad * grad_out.to(grad.dtype), None


def _fused(x: Tensor) -> bool:
    """Whether the fused kernel runs for ``x``: a CPU floating tensor, and the extension loads."""
    if x.device.type != "cpu" or x.dtype not in (torch.float32, torch.float64):
        return False
    from abcgs.render.cpu import extension_or_none

    return extension_or_none() is not None


def _drift(kernel: str, reference, x: Tensor, start: Tensor, fused: bool | None) -> Tensor:
    """One drift term: the C++ ``kernel`` where it runs (``fused=None``) or is asked for, else ``reference``. No
    Gaussians drift 0 on both paths (torch's mean over nothing would be NaN)."""
    if x.shape[0] == 0:
        return x.sum()
    if fused if fused is not None else _fused(x):
        return _FusedDrift.apply(kernel, x, start)
    return reference(x, start)


def scale_drift(log_scales: Tensor, start_log_scales: Tensor, *, fused: bool | None = None) -> Tensor:
    """Mean scale drift (0-d, differentiable in ``log_scales``); ``fused=None``: the C++ pass where it runs."""
    return _drift("scale_drift", scale_drift_reference, log_scales, start_log_scales, fused)


def opacity_drift(logits: Tensor, start_logits: Tensor, *, fused: bool | None = None) -> Tensor:
    """Mean opacity drift (0-d, differentiable in ``logits``); ``fused=None``: the C++ pass where it runs."""
    return _drift("opacity_drift", opacity_drift_reference, logits, start_logits, fused)
