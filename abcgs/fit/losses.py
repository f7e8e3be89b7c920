"""Reconstruction losses of 3DGS (Kerbl et al. 2023): L1, SSIM and their mix.

Images are channels-last like the renderer's output: ``(H, W, C)`` or batched ``(B, H, W, C)``,
values nominally in ``[0, 1]``.

The 3DGS objective is ``L = (1 − λ)·L1 + λ·D-SSIM`` with λ = 0.2. The paper defines D-SSIM loosely; the
reference code (``train.py``) uses ``1 − SSIM`` (not ``(1 − SSIM)/2``). We follow the code:
:func:`reconstruction_loss` uses ``1 − SSIM``; :func:`dssim` gives the halved variant for reference.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import torch
import torch.nn.functional as F
from torch import Tensor

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


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


def reconstruction_loss(render: Tensor, target: Tensor, ssim_lambda: float = 0.2) -> LossTerms:
    """3DGS photometric loss ``(1 − λ)·L1 + λ·(1 − SSIM)`` (the reference code's D-SSIM term)."""
    term_l1 = l1(render, target)
    term_ssim = ssim(render, target)
    total = (1.0 - ssim_lambda) * term_l1 + ssim_lambda * (1.0 - term_ssim)
    return LossTerms(total, term_l1, term_ssim)
