"""Reconstruction losses of 3DGS (Kerbl et al. 2023): L1, SSIM and their mix.

Images are channels-last like the renderer's output: ``(H, W, C)`` or batched ``(B, H, W, C)``,
values nominally in ``[0, 1]``.

The 3DGS objective is ``L = (1 − λ)·L1 + λ·D-SSIM`` with λ = 0.2. The paper defines D-SSIM loosely; the
reference code (``train.py``) uses ``1 − SSIM`` (not ``(1 − SSIM)/2``). We follow the code:
:func:`reconstruction_loss` uses ``1 − SSIM``; :func:`dssim` gives the halved variant for reference.

On CPU tensors :func:`reconstruction_loss` computes L1 and SSIM and their gradients with respect to the render
in one fused C++ kernel (``abcgs/render/csrc/image_loss_cpu.cpp``, two passes over the image on the CPU
kernels' threads) instead of ~20 torch ops and four depthwise convolutions: on fern (497×373) 59 ms → ~5 ms of
a fit step with one torch thread. The torch functions below are its reference (``tests/test_fit_losses.py``
checks values and gradients against them, and the fused gradient against finite differences).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from functools import lru_cache

import torch
import torch.nn.functional as F
from torch import Tensor

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2
log = logging.getLogger(__name__)


@lru_cache(maxsize=16)
def _gauss_1d(size: int, sigma: float, dtype: torch.dtype, device: torch.device) -> Tensor:
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2.0
    g = torch.exp(-(x**2) / (2.0 * sigma**2))
    return (g / g.sum()).to(dtype=dtype, device=device)


def _to_bchw(img: Tensor) -> Tensor:
    if img.dim() == 3:
        img = img[None]
    if img.dim() != 4:
        raise ValueError(f"expected an (H, W, C) or (B, H, W, C) image, got shape {tuple(img.shape)}")
    return img.permute(0, 3, 1, 2)


def _blur(x: Tensor, size: int, sigma: float) -> Tensor:
    """Separable Gaussian filter of ``(B, C, H, W)`` with zero padding (= 3DGS's 2-D ``conv2d``, ``padding=size//2``)."""
    c = x.shape[1]
    g = _gauss_1d(size, sigma, x.dtype, x.device)
    x = F.conv2d(x, g.view(1, 1, size, 1).expand(c, 1, size, 1), padding=(size // 2, 0), groups=c)
    return F.conv2d(x, g.view(1, 1, 1, size).expand(c, 1, 1, size), padding=(0, size // 2), groups=c)


def ssim_map(img1: Tensor, img2: Tensor, *, window: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> Tensor:
    """Per-pixel SSIM ``(B, C, H, W)`` of two channels-last images (3DGS's ``ssim`` before the mean).

    Local statistics use an ``window``×``window`` Gaussian window of std ``sigma`` px with zero padding,
    C1 = 0.01², C2 = 0.03² (data range 1). Differentiable in both inputs.
    """
    if img1.shape != img2.shape:
        raise ValueError(f"SSIM needs images of equal shape, got {tuple(img1.shape)} and {tuple(img2.shape)}")
    x, y = _to_bchw(img1), _to_bchw(img2)
    c = x.shape[1]
    stats = _blur(torch.cat([x, y, x * x, y * y, x * y], dim=1), window, sigma)
    mu1, mu2, e11, e22, e12 = stats.split(c, dim=1)
    mu1_sq, mu2_sq, mu12 = mu1 * mu1, mu2 * mu2, mu1 * mu2
    s1, s2, s12 = e11 - mu1_sq, e22 - mu2_sq, e12 - mu12
    return ((2 * mu12 + SSIM_C1) * (2 * s12 + SSIM_C2)) / ((mu1_sq + mu2_sq + SSIM_C1) * (s1 + s2 + SSIM_C2))


def ssim(img1: Tensor, img2: Tensor, *, window: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> Tensor:
    """Mean SSIM (scalar tensor, differentiable); 1 for identical images."""
    return ssim_map(img1, img2, window=window, sigma=sigma).mean()


def dssim(img1: Tensor, img2: Tensor) -> Tensor:
    """Structural dissimilarity ``(1 − SSIM) / 2`` in ``[0, 1]`` (textbook form; 3DGS trains with ``1 − SSIM``)."""
    return (1.0 - ssim(img1, img2)) / 2.0


def l1(img1: Tensor, img2: Tensor) -> Tensor:
    """Mean absolute error (scalar)."""
    return (img1 - img2).abs().mean()


@dataclass
class LossTerms:
    """The reconstruction loss and its parts (0-d tensors; ``total`` carries the graph)."""

    total: Tensor
    l1: Tensor
    ssim: Tensor

    def items(self) -> dict[str, Tensor]:
        return {"l1": self.l1, "ssim": self.ssim, "total": self.total}

    def plus(self, term: Tensor) -> LossTerms:
        """The same terms with ``term`` added to :attr:`total`."""
        return replace(self, total=self.total + term)


class _FusedL1Ssim(torch.autograd.Function):
    """``(mean L1, mean SSIM)`` of a render against a constant target, both differentiable in the render.

    The C++ kernel returns both values and both gradients (``d L1/d render``, ``d SSIM/d render``, shaped like
    the render) in one call; backward only scales the saved gradients. Values are 0-d tensors of the render's
    dtype (summed in float64 in the kernel).
    """

    @staticmethod
    def forward(ctx, render: Tensor, target: Tensor):
        from abcgs.render.cpu import load_extension

        window = _gauss_1d(SSIM_WINDOW, SSIM_SIGMA, render.dtype, render.device)
        l1_value, ssim_value, grad_l1, grad_ssim = load_extension().l1_ssim_forward(
            render.detach(), target.detach(), window, SSIM_C1, SSIM_C2
        )
        ctx.save_for_backward(grad_l1, grad_ssim)
        return l1_value.to(render.dtype), ssim_value.to(render.dtype)

    @staticmethod
    def backward(ctx, g_l1: Tensor, g_ssim: Tensor):
        grad_l1, grad_ssim = ctx.saved_tensors
        return g_l1 * grad_l1 + g_ssim * grad_ssim, None


_fused_unavailable_logged = False


def fused_l1_ssim_available(render: Tensor, target: Tensor) -> bool:
    """Whether :func:`l1_ssim` can use the fused CPU kernel for these tensors.

    Needs CPU float32/float64 images of one shape and dtype, a target that needs no gradient, and the C++
    extension (built on first use; where it cannot be built the torch code runs, with one log line).
    """
    global _fused_unavailable_logged
    if not (render.device.type == "cpu" and target.device.type == "cpu" and render.shape == target.shape):
        return False
    if render.dtype not in (torch.float32, torch.float64) or target.dtype != render.dtype:
        return False
    if target.requires_grad or render.dim() not in (3, 4):
        return False
    from abcgs.render.cpu import BackendUnavailable, load_extension

    try:
        load_extension()
    except BackendUnavailable as exc:
        if not _fused_unavailable_logged:
            log.info("fused L1 + SSIM kernel unavailable, using torch ops: %s", exc)
            _fused_unavailable_logged = True
        return False
    return True


def l1_ssim(render: Tensor, target: Tensor, *, fused: bool | None = None) -> tuple[Tensor, Tensor]:
    """Mean L1 and mean SSIM (3DGS window) of ``render`` against ``target``, channels-last images.

    ``fused=None`` uses the fused CPU kernel where :func:`fused_l1_ssim_available` says it can run and the torch
    ops otherwise; ``True`` requires the kernel (``ValueError`` where it cannot run); ``False`` forces torch.
    Both paths give the same values and gradients up to float rounding (~1e-7 relative in float32).
    """
    if fused is None:
        fused = fused_l1_ssim_available(render, target)
    elif fused and not fused_l1_ssim_available(render, target):
        raise ValueError(
            "the fused L1 + SSIM kernel needs CPU float32/float64 (H, W, C) or (B, H, W, C) images of one shape and "
            f"dtype, a target without gradient and the C++ extension; got {tuple(render.shape)} {render.dtype} on "
            f"{render.device} and {tuple(target.shape)} {target.dtype} on {target.device}"
        )
    if fused:
        return _FusedL1Ssim.apply(render, target)
    return l1(render, target), ssim(render, target)


def reconstruction_loss(
    render: Tensor, target: Tensor, ssim_lambda: float = 0.2, *, fused: bool | None = None
) -> LossTerms:
    """3DGS photometric loss ``(1 − λ)·L1 + λ·(1 − SSIM)`` (the reference code's D-SSIM term).

    ``fused``: as in :func:`l1_ssim` (default: the fused CPU kernel where it can run).
    """
    term_l1, term_ssim = l1_ssim(render, target, fused=fused)
    total = (1.0 - ssim_lambda) * term_l1 + ssim_lambda * (1.0 - term_ssim)
    return LossTerms(total, term_l1, term_ssim)
