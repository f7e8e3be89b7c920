"""Image-quality metrics for held-out views: PSNR and SSIM (no gradients, renders clamped to ``[0, 1]``).

SSIM is the same 11×11, σ = 1.5 Gaussian-window formulation the 3DGS evaluation script uses
(:func:`abcgs.fit.losses.ssim`). LPIPS needs torchvision-based packages that are not in the core
environment; it belongs to the optional ``eval`` extra.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from abcgs.fit.losses import ssim as _ssim


def _as_tensor(img: Tensor | np.ndarray) -> Tensor:
    t = torch.as_tensor(img)
    if t.dtype == torch.uint8:
        t = t.float() / 255.0
    return t.float().clamp(0.0, 1.0)


@torch.no_grad()
def psnr(img: Tensor | np.ndarray, ref: Tensor | np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB for images in ``[0, 1]`` (``inf`` for identical images)."""
    a, b = _as_tensor(img), _as_tensor(ref)
    if a.shape != b.shape:
        raise ValueError(f"PSNR needs images of equal shape, got {tuple(a.shape)} and {tuple(b.shape)}")
    mse = float(((a - b) ** 2).mean())
    return math.inf if mse == 0.0 else -10.0 * math.log10(mse)


@torch.no_grad()
def ssim(img: Tensor | np.ndarray, ref: Tensor | np.ndarray) -> float:
    """Mean SSIM of two ``(H, W, C)`` images in ``[0, 1]``."""
    return float(_ssim(_as_tensor(img), _as_tensor(ref)))


def psnr_from_mse(mse: float) -> float:
    return math.inf if mse <= 0.0 else -10.0 * math.log10(mse)
