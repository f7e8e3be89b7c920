"""Colour match (paper Sec. "Color Match", supplementary derivation) and colour preservation.

A linear map ``p' = A p + b`` makes the content colours' mean and covariance equal the style's:
``A = U_s Λ_s^½ U_sᵀ · U_c Λ_c^-½ U_cᵀ``, ``b = μ_s − A μ_c`` with eigen-decompositions of the population
covariances (divide by n, as ARF's ``match_colors_for_image_set``) and eigenvalues clamped to
``eps_clamp``. Computed in float64; returned in the content pixels' floating dtype (float32 for
non-float input). Colours are RGB, any range (the pipeline uses [0, 1]). :func:`apply_group_transforms` applies one
transform per matching group, to Gaussians' DC colours or to an image's pixels; :func:`color_match_model` fits and
applies them to a model's DC colours, and :func:`recolor_to_content` preserves a model's content colours.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor

from abcgs.errors import InputError
from abcgs.features.params import ALL_PIXELS
from abcgs.gaussians import GaussianModel
from abcgs.render import rgb_to_sh0, sh0_to_rgb
from abcgs.types import MatchingGroup

ArrayLike = torch.Tensor | np.ndarray


def _as_pixels(x: ArrayLike, what: str) -> torch.Tensor:
    t = torch.as_tensor(np.ascontiguousarray(x) if isinstance(x, np.ndarray) else x)
    if t.ndim < 1 or t.shape[-1] != 3:
        raise InputError(f"{what}: expected RGB pixels with last dimension 3, got shape {tuple(t.shape)}")
    t = t.reshape(-1, 3)
    if t.shape[0] < 2:
        raise InputError(f"{what}: need at least 2 pixels to estimate a covariance, got {t.shape[0]}")
    t = t.to(torch.float64)
    if not bool(torch.isfinite(t).all()):
        raise InputError(f"{what}: pixels contain NaN/Inf")
    return t


def _mean_cov(p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    mu = p.mean(dim=0)
    d = p - mu
    return mu, (d.t() @ d) / p.shape[0]


def fit_color_transform(
    content_pixels: ArrayLike,
    style_pixels: ArrayLike,
    eps_clamp: tuple[float, float] = (1e-8, 1e8),
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fit ``A`` ``(3, 3)`` and ``b`` ``(3,)`` mapping content colours ``(n, 3)`` to the style's ``(m, 3)`` statistics.

    Inputs may have any leading shape ending in 3 (flattened). With non-degenerate content colours
    (eigenvalues above ``eps_clamp[0]``) the mapped colours have exactly the style's mean and covariance.
    """
    pc = _as_pixels(content_pixels, "colour match content pixels")
    ps = _as_pixels(style_pixels, "colour match style pixels")
    lo, hi = eps_clamp
    mu_c, cov_c = _mean_cov(pc)
    mu_s, cov_s = _mean_cov(ps)
    lam_c, u_c = torch.linalg.eigh(cov_c)
    lam_s, u_s = torch.linalg.eigh(cov_s)
    lam_c = lam_c.clamp(lo, hi)
    lam_s = lam_s.clamp(lo, hi)
    a = (u_s * lam_s.sqrt()) @ u_s.t() @ (u_c * lam_c.rsqrt()) @ u_c.t()
    b = mu_s - a @ mu_c
    src = content_pixels if isinstance(content_pixels, torch.Tensor) else torch.as_tensor(np.asarray(content_pixels))
    dtype = src.dtype if src.is_floating_point() else torch.float32
    return a.to(dtype), b.to(dtype)


def apply_color_transform(
    x: ArrayLike, a: torch.Tensor, b: torch.Tensor, clip: tuple[float, float] | None = None
) -> torch.Tensor:
    """``x`` ``(..., 3)`` → ``A x + b`` (same shape), optionally clipped (e.g. ``(0, 1)`` for images).

    Differentiable in ``x`` (use it on Gaussians' DC colours as well as on images).
    """
    t = torch.as_tensor(x)
    if t.shape[-1] != 3:
        raise InputError(f"apply_color_transform: last dimension must be 3 (RGB), got shape {tuple(t.shape)}")
    if tuple(a.shape) != (3, 3) or tuple(b.shape) != (3,):
        raise InputError(f"apply_color_transform: A must be (3, 3) and b (3,), got {tuple(a.shape)}, {tuple(b.shape)}")
    dtype = t.dtype if t.is_floating_point() else torch.float32
    out = t.to(dtype) @ a.to(device=t.device, dtype=dtype).t() + b.to(device=t.device, dtype=dtype)
    return out.clamp(*clip) if clip is not None else out


def apply_group_transforms(
    x: torch.Tensor,
    selections: Sequence[torch.Tensor],
    transforms: Sequence[tuple[torch.Tensor, torch.Tensor]],
    clip: tuple[float, float] | None = None,
) -> torch.Tensor:
    """Per matching group, its ``A x + b`` (:func:`apply_color_transform`) on the elements of ``x`` ``(..., 3)`` that
    its selection ``(...)`` bool covers: the Gaussians of its content label (DC colours ``(N, 3)``) or the pixels of its
    region in one view (an image ``(H, W, 3)``). Elements no group covers are left as they are.

    The groups are disjoint (one content label each) or one group covers everything (single transfer); each
    transform maps the input colours, not another group's output. Returns a new tensor.
    """
    if len(selections) != len(transforms):
        raise InputError(f"apply_group_transforms: {len(selections)} selections for {len(transforms)} transforms")
    out = x.clone()
    for sel, (a, b) in zip(selections, transforms):
        if tuple(sel.shape) != tuple(x.shape[:-1]):
            raise InputError(f"apply_group_transforms: selection shape {tuple(sel.shape)} does not match colours "
                             f"{tuple(x.shape)} (without the 3)")
        out[sel] = apply_color_transform(x[sel], a, b, clip)
    return out


# YIQ (NTSC) — luminance Y and chroma I, Q.
_RGB2YIQ = torch.tensor(
    [[0.299, 0.587, 0.114], [0.595716, -0.274453, -0.321263], [0.211456, -0.522591, 0.311135]], dtype=torch.float64
)


def rgb_to_yiq(x: torch.Tensor, channel_dim: int = -1) -> torch.Tensor:
    """RGB → YIQ along ``channel_dim``."""
    x = x if x.is_floating_point() else x.float()
    m = _RGB2YIQ.to(device=x.device, dtype=x.dtype)
    return torch.movedim(torch.movedim(x, channel_dim, -1) @ m.t(), -1, channel_dim)


def yiq_to_rgb(x: torch.Tensor, channel_dim: int = -1) -> torch.Tensor:
    """YIQ → RGB along ``channel_dim`` (exact inverse of :func:`rgb_to_yiq`)."""
    x = x if x.is_floating_point() else x.float()
    m = torch.linalg.inv(_RGB2YIQ).to(device=x.device, dtype=x.dtype)
    return torch.movedim(torch.movedim(x, channel_dim, -1) @ m.t(), -1, channel_dim)


def preserve_color(
    stylized: torch.Tensor, original: torch.Tensor, channel_dim: int = -1, clip: tuple[float, float] | None = (0.0, 1.0)
) -> torch.Tensor:
    """Luminance-only transfer: Y of ``stylized`` with I, Q (chroma) of ``original`` (same shape, RGB).

    ``channel_dim`` is the RGB axis (−1 for ``(H, W, 3)``, 1 for ``(B, 3, H, W)``).
    """
    if stylized.shape != original.shape:
        raise InputError(f"preserve_color: shapes differ {tuple(stylized.shape)} vs {tuple(original.shape)}")
    if stylized.shape[channel_dim] != 3:
        raise InputError(f"preserve_color: dimension {channel_dim} must be RGB (3), got shape {tuple(stylized.shape)}")
    ys = rgb_to_yiq(stylized, channel_dim)
    yo = rgb_to_yiq(original.to(ys.dtype), channel_dim)
    y = ys.narrow(channel_dim, 0, 1)
    iq = yo.narrow(channel_dim, 1, 2)
    out = yiq_to_rgb(torch.cat([y, iq], dim=channel_dim), channel_dim)
    return out.clamp(*clip) if clip is not None else out


def color_match_model(
    model: GaussianModel, labels: Tensor, groups: list[MatchingGroup], content_pixels: dict[int, np.ndarray],
    *, zero_higher_sh: bool = True, gaussians: Tensor | None = None,
) -> tuple[GaussianModel, dict[int, tuple[Tensor, Tensor]]]:
    """Apply each group's mean/covariance colour transform to the DC colours of its Gaussians.

    ``content_pixels[z]``: ``(n, 3)`` pixels of the content (training images) covered by group z.
    Single transfer (one group over all pixels) recolours every Gaussian; ``gaussians`` ``(N,)`` bool limits it to
    those (an object scene's object). The higher SH bands are zeroed unless ``zero_higher_sh`` is False
    (``stylize.higher_sh`` other than ``zero``); those of Gaussians outside ``gaussians`` are kept.
    """
    out = model.detach()
    rgb = sh0_to_rgb(out.sh0[:, 0, :])
    transforms = {}
    for g in groups:
        pix = content_pixels.get(g.content_label)
        if pix is None or len(pix) < 2:
            raise InputError(f"colour match: no content pixels for content label {g.content_label}")
        A, b = fit_color_transform(pix, g.style_pixels)
        transforms[g.content_label] = (A, b)
    selections = [torch.ones_like(labels, dtype=torch.bool) if g.content_label == ALL_PIXELS else labels == g.content_label
                  for g in groups]
    if gaussians is not None:
        selections = [sel & gaussians.to(sel.device) for sel in selections]
    rgb = apply_group_transforms(rgb, selections, [transforms[g.content_label] for g in groups])
    if gaussians is None:
        out.sh0 = rgb_to_sh0(rgb)[:, None, :].contiguous()
    else:  # the others keep their exact coefficients
        out.sh0 = torch.where(gaussians.to(rgb.device)[:, None, None], rgb_to_sh0(rgb)[:, None, :], out.sh0).contiguous()
    if out.shN.numel() and zero_higher_sh:  # view-dependent colour would undo the match
        out.shN = (torch.zeros_like(out.shN) if gaussians is None
                   else torch.where(gaussians.to(out.shN.device)[:, None, None], 0.0, out.shN).contiguous())
    return out, transforms


def recolor_to_content(styled: GaussianModel, content: GaussianModel) -> GaussianModel:
    """``preserve_color``: keep the stylised luminance, take chroma from the content colours (YIQ)."""
    out = styled.detach()
    rgb = preserve_color(sh0_to_rgb(styled.sh0[:, 0, :]), sh0_to_rgb(content.sh0[:, 0, :]))
    out.sh0 = rgb_to_sh0(rgb)[:, None, :].contiguous()
    return out
