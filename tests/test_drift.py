"""The fused drift terms (abcgs.losses.drift, csrc/drift_cpu.cpp) against their torch reference and finite differences."""

from __future__ import annotations

import pytest
import torch

from abcgs.losses.drift import opacity_drift, opacity_drift_reference, scale_drift, scale_drift_reference
from abcgs.render import cpu as cpu_backend
from abcgs.render.cpu import kernel_threads

pytestmark = pytest.mark.skipif(not cpu_backend.is_available(), reason="C++ extension not built")


def _inputs(n: int, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(n)
    log_scales = torch.randn(n, 3, generator=g, dtype=dtype) - 3.0
    start = log_scales + 0.1 * torch.randn(n, 3, generator=g, dtype=dtype)
    start[::7] = log_scales[::7]  # Gaussians that have not moved: the norm's kink at 0
    logits = torch.randn(n, generator=g, dtype=dtype)
    start_logits = logits + 0.2 * torch.randn(n, generator=g, dtype=dtype)
    start_logits[::5] = logits[::5]
    return log_scales, start, logits, start_logits


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("which", ["scale", "opacity"])
def test_fused_drift_matches_the_reference(dtype: torch.dtype, which: str) -> None:
    """Against the torch formula in float64 on the same inputs: float64 to rounding; float32 (exp_fast, ~1e-7) to
    float32's own precision, where a Gaussian that barely moved has a drift direction only as exact as the
    difference of two nearly equal scales (the same holds for the torch formula in float32)."""
    log_scales, start, logits, start_o = _inputs(50_001, dtype)
    x, s0 = (log_scales, start) if which == "scale" else (logits, start_o)
    fused, reference = (scale_drift, scale_drift_reference) if which == "scale" else (opacity_drift, opacity_drift_reference)
    results = []
    for fn, inputs in ((lambda a, b: fused(a, b, fused=True), (x, s0)), (reference, (x.double(), s0.double()))):
        xg = inputs[0].clone().requires_grad_()
        value = fn(xg, inputs[1])
        (3.0 * value).backward()
        results.append((value.detach(), xg.grad))
    (value, grad), (value64, grad64) = results
    assert value.dtype == grad.dtype == dtype
    if dtype == torch.float64:
        torch.testing.assert_close(value, value64, rtol=1e-12, atol=0)
        torch.testing.assert_close(grad, grad64, rtol=1e-10, atol=1e-18)
    else:
        torch.testing.assert_close(value.double(), value64, rtol=1e-6, atol=0)
        torch.testing.assert_close(grad.double(), grad64, rtol=1e-4, atol=1e-3 * float(grad64.abs().max()))
    assert bool((grad[::7 if which == "scale" else 5] == 0).all())  # not moved: zero gradient, as torch's


def test_fused_drift_takes_std_exp_outside_the_fast_range() -> None:
    """Inputs beyond exp_fast's clamp, and NaN, give what the torch formula gives (inf and NaN are not hidden)."""
    log_scales, start, logits, start_o = _inputs(5_000, torch.float32)
    log_scales[10, 1], logits[20] = 95.0, -95.0  # e^95 overflows float32: the drift is inf, as torch's
    assert torch.isinf(scale_drift(log_scales, start, fused=True))
    torch.testing.assert_close(opacity_drift(logits, start_o, fused=True),
                               opacity_drift_reference(logits.double(), start_o.double()).float(), rtol=1e-6, atol=0)
    log_scales[10, 1] = float("nan")
    assert torch.isnan(scale_drift(log_scales, start, fused=True))


@pytest.mark.parametrize("which", ["scale", "opacity"])
def test_fused_drift_gradient_matches_finite_differences(which: str) -> None:
    log_scales, start, logits, start_o = _inputs(40, torch.float64)
    x, s0, fn = (log_scales, start, scale_drift) if which == "scale" else (logits, start_o, opacity_drift)
    x = x + 0.05  # away from the kinks, where finite differences are not defined
    assert torch.autograd.gradcheck(lambda a: fn(a, s0, fused=True), (x.clone().requires_grad_(),), eps=1e-6,
                                    atol=1e-8)


def test_fused_drift_is_the_same_for_any_thread_count() -> None:
    log_scales, start, _, _ = _inputs(200_003, torch.float32)
    results = []
    for threads in (1, 2, 3):
        with kernel_threads(threads):
            x = log_scales.clone().requires_grad_()
            value = scale_drift(x, start, fused=True)
            value.backward()
            results.append((value.detach(), x.grad))
    for value, grad in results[1:]:
        assert torch.equal(value, results[0][0]) and torch.equal(grad, results[0][1])


@pytest.mark.parametrize("fused", [True, False])
def test_no_gaussians_drift_zero_on_both_paths(fused: bool) -> None:
    """A model with no Gaussians has drifted by 0, not NaN (torch's mean over nothing), with an empty gradient."""
    log_scales = torch.zeros(0, 3, requires_grad=True)
    logits = torch.zeros(0, requires_grad=True)
    total = scale_drift(log_scales, torch.zeros(0, 3), fused=fused) + opacity_drift(logits, torch.zeros(0), fused=fused)
    assert total.item() == 0.0
    total.backward()
    assert log_scales.grad.shape == (0, 3) and logits.grad.shape == (0,)
