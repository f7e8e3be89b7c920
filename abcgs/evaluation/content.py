"""Content preservation: SSIM, masked RMSE and a perceptual distance (real LPIPS or a named VGG proxy).

SSIM (:func:`ssim_wang`) is the standard Wang et al. (2004) index: 11×11 Gaussian window, σ = 1.5,
K1 = 0.01, K2 = 0.03, data range 1, population (biased) local variances, computed per RGB channel
over the *valid* window positions only (no padding — as Wang's MATLAB ``ssim_index`` and
``skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)``)
and averaged over pixels and channels. :func:`abcgs.fit.losses.ssim` has the same window and constants but
zero-pads (3DGS's training loss), which changes a ~5 px border band; in the interior the two maps are
identical (tested). When ``pyiqa`` imports, :func:`ssim` can use ``pyiqa``'s ``ssim`` metric instead
(its defaults: the Y channel of YCbCr); the implementation used is returned alongside the value.

Perceptual distance (:class:`PerceptualDistance`):

- ``lpips`` — the real LPIPS v0.1 with the AlexNet backbone (``lpips.LPIPS(net="alex")``, images in
  [−1, 1]), the number the paper and ArtFID report. Needs the ``lpips`` package *and* torchvision's AlexNet
  weights in the torch hub cache; neither is available offline on this project's machines.
- ``lpips_proxy_vgg`` — the *uncalibrated* LPIPS formula (what ``lpips.LPIPS(net="vgg", lpips=False)``
  computes: per tap, unit-normalise the channel vector at each pixel, sum the squared differences over
  channels, average over space; sum over the taps relu1_2, relu2_2, relu3_3, relu4_3, relu5_3) with the
  project's own ImageNet VGG-16 (:func:`abcgs.features.weights.resolve_vgg16`, offline: the Oxford/Keras
  weights). No learned per-channel weights, a different backbone and training run: its scale is NOT that of
  LPIPS (typically several times larger) and it must never be compared with the paper's LPIPS columns —
  only between runs of this project evaluated with the same weights (their sha256 is recorded).

Masks: a per-pixel weight map in [0, 1] (1 = counts). RMSE averages squared errors over the masked pixels
and the 3 channels. The perceptual distance zeroes masked-out pixels in *both* images before the network
(so occluded content cannot leak in) and averages each tap's distance map with the mask area-resampled
to that tap's resolution.
"""

from __future__ import annotations

import copy
import importlib.metadata
import importlib.util
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Literal

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from abcgs.errors import InputError
from abcgs.evaluation.parallel import ordered_map
from abcgs.types import VggPrecision

log = logging.getLogger(__name__)

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
SSIM_DOC = "Wang et al. 2004: 11x11 Gaussian window sigma 1.5, K1 0.01, K2 0.03, data range 1, valid positions only, RGB channels averaged"
LPIPS_ALEX_BACKBONE = "alexnet-owt-7be5be79.pth"
BATCH_PIXELS = 1 << 19
"""Pixels of one batched VGG forward of the proxy distance (:meth:`PerceptualDistance.distances`; both images of each
pair): 4 images of 270 × 480 (2 pairs), 26 of 160 × 120; one relu1 activation of such a batch is 128 MiB."""


def as_bchw(img: np.ndarray | Tensor) -> Tensor:
    """``(H, W, 3)`` / ``(B, H, W, 3)`` channels-last (numpy or torch) → float32 ``(B, 3, H, W)``."""
    t = torch.as_tensor(np.asarray(img) if not isinstance(img, Tensor) else img).float()
    if t.dim() == 3:
        t = t[None]
    if t.dim() != 4 or t.shape[-1] != 3:
        raise InputError(f"expected an (H, W, 3) or (B, H, W, 3) RGB image, got shape {tuple(t.shape)}")
    return t.permute(0, 3, 1, 2).contiguous()


def check_pair(a, b, what: str = "images") -> None:
    if tuple(np.shape(a)) != tuple(np.shape(b)):
        raise InputError(f"{what} differ in shape: {tuple(np.shape(a))} vs {tuple(np.shape(b))}")


def check_same_count(a: Sequence, b: Sequence, what_a: str = "original renders", what_b: str = "stylized renders") -> None:
    if len(a) != len(b):
        raise InputError(f"{len(a)} {what_a} but {len(b)} {what_b}: the metrics compare the same views one to one")
    if len(a) == 0:
        raise InputError(f"no {what_a} to evaluate")


@lru_cache(maxsize=4)
def _gauss(size: int, sigma: float) -> Tensor:
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2.0
    g = torch.exp(-(x**2) / (2.0 * sigma**2))
    return g / g.sum()


def ssim_map_wang(a: np.ndarray | Tensor, b: np.ndarray | Tensor, *, window: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> Tensor:
    """Per-pixel SSIM ``(B, 3, H − window + 1, W − window + 1)`` over valid window positions (float64)."""
    check_pair(a, b)
    x, y = as_bchw(a).double(), as_bchw(b).double()
    if min(x.shape[-2:]) < window:
        raise InputError(f"SSIM needs images of at least {window}x{window} px, got {tuple(x.shape[-2:])}")
    c = x.shape[1]
    g = _gauss(window, sigma)
    stats = torch.cat([x, y, x * x, y * y, x * y], dim=1)
    stats = F.conv2d(stats, g.view(1, 1, window, 1).expand(5 * c, 1, window, 1), groups=5 * c)
    stats = F.conv2d(stats, g.view(1, 1, 1, window).expand(5 * c, 1, 1, window), groups=5 * c)
    mu1, mu2, e11, e22, e12 = stats.split(c, dim=1)
    c1, c2 = SSIM_K1**2, SSIM_K2**2
    s1, s2, s12 = e11 - mu1 * mu1, e22 - mu2 * mu2, e12 - mu1 * mu2
    return ((2 * mu1 * mu2 + c1) * (2 * s12 + c2)) / ((mu1 * mu1 + mu2 * mu2 + c1) * (s1 + s2 + c2))


def ssim_wang(a, b) -> float:
    """Mean Wang et al. SSIM of two RGB images in [0, 1] (see module docstring); 1.0 for identical images."""
    return float(ssim_map_wang(a, b).mean())


def pyiqa_available() -> bool:
    return importlib.util.find_spec("pyiqa") is not None


def package_version(dist: str) -> str | None:
    """The installed version of distribution ``dist``; None when it is not installed."""
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return None


class SSIM:
    """SSIM with a chosen implementation; ``impl`` is ``"wang"`` (built-in) or ``"pyiqa"``."""

    def __init__(self, impl: str = "auto") -> None:
        if impl == "auto":
            impl = "pyiqa" if pyiqa_available() else "wang"
        if impl == "pyiqa":
            if not pyiqa_available():
                raise InputError("evaluate.ssim_impl is 'pyiqa' but pyiqa is not importable (pip install -e '.[eval]')")
            import pyiqa

            self._metric = pyiqa.create_metric("ssim", device="cpu", as_loss=False)
        self.impl = impl

    def __call__(self, a, b) -> float:
        if self.impl == "wang":
            return ssim_wang(a, b)
        check_pair(a, b)
        with torch.no_grad():
            return float(self._metric(as_bchw(a).clamp(0, 1), as_bchw(b).clamp(0, 1)).mean())

    def provenance(self) -> dict:
        if self.impl == "wang":
            return {"ssim_impl": "abcgs_wang", "ssim_params": SSIM_DOC}
        return {"ssim_impl": "pyiqa", "ssim_params": "pyiqa.create_metric('ssim') defaults", "pyiqa_version": package_version("pyiqa")}


def nan_mean(values: Sequence[float]) -> float:
    """Mean over the finite-or-infinite entries, NaNs left out; NaN when every entry is NaN (e.g. pairs with no
    valid pixel)."""
    a = np.asarray(values, np.float64)
    return float(np.nanmean(a)) if np.isfinite(a).any() else float("nan")


def masked_rmse(a, b, mask: np.ndarray | None = None) -> float:
    """RMSE over masked pixels and the 3 channels (images in [0, 1]); NaN when the mask is empty."""
    check_pair(a, b)
    d2 = ((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2).mean(axis=-1)
    if mask is None:
        return float(np.sqrt(d2.mean()))
    m = np.asarray(mask, np.float64)
    if m.shape != d2.shape:
        raise InputError(f"mask shape {m.shape} does not match image {d2.shape}")
    w = m.sum()
    return float(np.sqrt((d2 * m).sum() / w)) if w > 0 else float("nan")


# ---------------------------------------------------------------------------------------------- perceptual
def _unit(x: Tensor, eps: float = 1e-10) -> Tensor:
    return x / (x.pow(2).sum(dim=1, keepdim=True).sqrt() + eps)  # lpips.normalize_tensor


def lpips_backbone_file() -> Path:
    return Path(torch.hub.get_dir()) / "checkpoints" / LPIPS_ALEX_BACKBONE


def real_lpips_status() -> tuple[bool, str]:
    """Whether real LPIPS-alex can run here without a download, and why not."""
    if importlib.util.find_spec("lpips") is None:
        return False, "the lpips package is not installed (it needs torchvision)"
    if importlib.util.find_spec("torchvision") is None:
        return False, "torchvision is not importable"
    f = lpips_backbone_file()
    if not f.is_file():
        return False, f"torchvision's AlexNet weights are not in the torch hub cache ({f})"
    return True, "lpips package + cached AlexNet backbone"


PROXY_BF16_TOLERANCE = 1e-3
"""The stated bound on the change of one ``lpips_proxy_vgg`` distance (absolute, in the distance's units) when its
convolutions run in bfloat16 instead of float32: bf16 rounds each conv input and weight to 8 significant bits; the sums
and the distance stay float32. Measured on 8 content and 8 consistency pairs of stylized 480 x 270 renders: at most
5.9e-4 (content distances are about 3.6, consistency ones about 0.1: 2e-4 and 3e-3 of the value), ``python -m eval
run proxy_precision``, docs/measurements/proxy_precision.json."""


def proxy_precision(precision: VggPrecision, device: torch.device) -> Literal["float32", "bfloat16"]:
    """``auto``: ``bfloat16`` on a CPU that multiplies bfloat16 natively (:func:`abcgs.features.bf16.bf16_matmul_is_native`:
    AMX or AVX512-BF16, where the VGG runs about 3.5 times faster), else ``float32`` (elsewhere bf16 is emulated and
    no faster; a GPU runs float32 fast enough)."""
    if precision != "auto":
        return precision
    from abcgs.features.bf16 import bf16_matmul_is_native

    return "bfloat16" if device.type == "cpu" and bf16_matmul_is_native() else "float32"


class PerceptualDistance:
    """Masked perceptual distance: real LPIPS-alex (``name == "lpips"``) or the VGG proxy (``"lpips_proxy_vgg"``).

    Args:
        mode: ``auto`` | ``lpips`` | ``proxy`` (see :class:`abcgs.evaluation.params.EvalParams`).
        vgg_state: torchvision-layout VGG-16 state dict for the proxy (None: resolve with ``vgg_params``).
        vgg_info: provenance of ``vgg_state`` (a dict, recorded in the output).
        precision: the proxy's VGG convolutions: ``float32``, ``bfloat16`` (autocast: bf16 products, float32
            sums; the features are taken back to float32 before the distance) or ``auto`` (:func:`proxy_precision`).
    """

    def __init__(self, mode: str = "auto", *, layers: Sequence[str] = ("relu1_2", "relu2_2", "relu3_3", "relu4_3", "relu5_3"),
                 vgg_state: dict | None = None, vgg_info: dict | None = None, vgg_params=None,
                 device: torch.device | str = "cpu", precision: VggPrecision = "float32") -> None:
        ok, why = real_lpips_status()
        self.device = torch.device(device)
        self.note = why
        self.precision: VggPrecision = "float32"
        if mode == "lpips" and not ok:
            raise InputError(f"evaluate.perceptual is 'lpips' but real LPIPS cannot run: {why}")
        self.layers = tuple(layers)
        if mode in ("auto", "lpips") and ok:
            import lpips

            self._lpips = lpips.LPIPS(net="alex", verbose=False).eval().to(self.device)
            # the masked distance needs LPIPS's per-pixel map: a shallow copy sharing the network, so that no
            # call toggles a flag another thread's call reads (abcgs/evaluation/parallel.py)
            self._lpips_spatial = copy.copy(self._lpips)
            self._lpips_spatial.spatial = True
            self.name = "lpips"
            self.info = {"name": "lpips", "implementation": "lpips.LPIPS(net='alex') v0.1, inputs in [-1, 1]",
                         "lpips_version": package_version("lpips"), "backbone": str(lpips_backbone_file())}
            return
        from abcgs.features.vgg import VGG16Features

        if vgg_state is None:
            from abcgs.features.weights import resolve_vgg16

            vgg_state, winfo = resolve_vgg16(vgg_params)
            vgg_info = winfo.model_dump()
        self._vgg = VGG16Features(vgg_state, self.layers).to(self.device)
        self.precision = proxy_precision(precision, self.device)
        self.name = "lpips_proxy_vgg"
        self.info = {
            "name": self.name,
            "implementation": "uncalibrated LPIPS formula (lpips=False): sum over taps of the spatial mean of "
            "sum_c (unit-normalised f1 - unit-normalised f2)^2; project VGG-16, no learned linear layers",
            "layers": list(self.layers), "vgg_weights": vgg_info or {"source": "given state dict"},
            "why_not_lpips": why, "comparable_to_paper": False, "precision": self.precision,
        }

    def _features(self, x: Tensor) -> dict[str, Tensor]:
        """The proxy's taps of ``x`` ``(B, 3, H, W)``, float32, the convolutions in :attr:`precision` (autocast's
        state is per thread: entered here, in the thread that runs the forward)."""
        with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.precision == "bfloat16"):
            feats = self._vgg(x)
        return {k: v.float() for k, v in feats.items()}

    def _inputs(self, a, b, mask: np.ndarray | None) -> tuple[Tensor, Tensor, Tensor | None] | None:
        """The network inputs of one pair, ``(1, 3, H, W)`` each in [0, 1] with masked-out pixels zeroed in both, and
        the mask ``(1, 1, H, W)`` (None without one); None when the mask keeps no pixel."""
        check_pair(a, b)
        m = None
        if mask is not None:
            m = np.asarray(mask, np.float32)
            if m.shape != np.shape(a)[:2]:
                raise InputError(f"mask shape {m.shape} does not match image {np.shape(a)[:2]}")
            if m.sum() <= 0:
                return None
            a = np.asarray(a, np.float32) * m[..., None]
            b = np.asarray(b, np.float32) * m[..., None]
        x, y = as_bchw(a).to(self.device).clamp(0, 1), as_bchw(b).to(self.device).clamp(0, 1)
        return x, y, (torch.from_numpy(m)[None, None].to(self.device) if m is not None else None)

    def _proxy_distance(self, feats: dict[str, Tensor], i: int, j: int, mt: Tensor | None) -> float:
        """The proxy distance between samples ``i`` and ``j`` of one VGG forward's ``feats``; ``mt``: the pair's mask."""
        total = 0.0
        for k in self.layers:
            d = (_unit(feats[k][i : i + 1]) - _unit(feats[k][j : j + 1])).pow(2).sum(dim=1, keepdim=True)
            if mt is None:
                total += float(d.mean())
            else:
                mk = F.interpolate(mt, size=d.shape[-2:], mode="area")
                w = float(mk.sum())
                total += float((d * mk).sum() / w) if w > 0 else 0.0
        return total

    @torch.no_grad()
    def __call__(self, a, b, mask: np.ndarray | None = None) -> float:
        """Distance of one image pair (channels-last, [0, 1]); ``mask`` (H, W) weights pixels, zeroing the rest."""
        inputs = self._inputs(a, b, mask)
        if inputs is None:
            return float("nan")
        x, y, mt = inputs
        if self.name == "lpips":
            if mt is None:
                return float(self._lpips(x * 2 - 1, y * 2 - 1).mean())
            dmap = self._lpips_spatial(x * 2 - 1, y * 2 - 1)  # (1, 1, H, W), upsampled to the input size
            return float((dmap * mt).sum() / mt.sum())
        return self._proxy_distance(self._features(torch.cat([x, y])), 0, 1, mt)

    def distances(self, a: Sequence, b: Sequence, masks: Sequence[np.ndarray | None] | None = None, *,
                  workers: int = 1, batch_pixels: int = BATCH_PIXELS) -> list[float]:
        """``[self(a[k], b[k], masks[k]) for k …]``, the pairs batched: consecutive pairs of one size share a VGG
        forward of up to ``batch_pixels`` pixels (both images of each), the batches spread over ``workers`` threads
        (:func:`abcgs.evaluation.parallel.ordered_map`). A VGG forward gives each sample the same features in any
        batch on the CPU (tested: bitwise), and each pair's distance is then computed exactly as :meth:`__call__`
        computes it, so the numbers are :meth:`__call__`'s. Real LPIPS runs pair by pair."""
        if len(a) != len(b) or (masks is not None and len(masks) != len(a)):
            raise InputError(f"{len(a)} first images, {len(b)} second images and "
                             f"{len(a) if masks is None else len(masks)} masks: the pairs must match one to one")
        ms = list(masks) if masks is not None else [None] * len(a)
        if self.name == "lpips":
            return ordered_map(lambda k: self(a[k], b[k], ms[k]), range(len(a)), workers)
        return [d for chunk in ordered_map(lambda idx: self._batch(a, b, ms, idx), pair_batches(
            [tuple(np.shape(x)[:2]) for x in a], batch_pixels, workers), workers) for d in chunk]

    @torch.no_grad()
    def _batch(self, a: Sequence, b: Sequence, masks: Sequence, idx: list[int]) -> list[float]:
        """The proxy distances of the pairs ``idx`` (one size) from one VGG forward of all their images."""
        inputs = {k: self._inputs(a[k], b[k], masks[k]) for k in idx}
        live = [k for k in idx if inputs[k] is not None]
        out = {k: float("nan") for k in idx if inputs[k] is None}
        if live:
            feats = self._features(torch.cat([inputs[k][0] for k in live] + [inputs[k][1] for k in live]))
            for s, k in enumerate(live):
                out[k] = self._proxy_distance(feats, s, len(live) + s, inputs[k][2])
        return [out[k] for k in idx]


def pair_batches(sizes: Sequence[tuple[int, int]], batch_pixels: int = BATCH_PIXELS, workers: int = 1) -> list[list[int]]:
    """The pairs (indices into ``sizes``, each pair's ``(H, W)``) cut into batches for one VGG forward each: runs of
    consecutive pairs of one size, each run cut into equal batches of at most ``batch_pixels // (2·H·W)`` pairs (at
    least one) and into at least ``workers`` batches where it has that many pairs, so that the threads share it."""
    runs: list[list[int]] = []
    for k, hw in enumerate(sizes):
        if runs and tuple(sizes[runs[-1][-1]]) == tuple(hw):
            runs[-1].append(k)
        else:
            runs.append([k])
    out = []
    for run in runs:
        h, w = sizes[run[0]]
        most = max(1, batch_pixels // max(1, 2 * h * w))
        count = max(-(-len(run) // most), min(max(1, workers), len(run)))
        size = -(-len(run) // count)
        out += [run[s : s + size] for s in range(0, len(run), size)]
    return out


# ---------------------------------------------------------------------------------------------- scores
@dataclass(frozen=True)
class ContentScores:
    """Content preservation of a stylization: each stylized render against the original render of its view."""

    ssim: tuple[float, ...]
    """``(n_views,)`` SSIM per view (:attr:`ssim_impl`), in [-1, 1]; 1 = identical."""
    perceptual: tuple[float, ...]
    """``(n_views,)`` perceptual distance per view (:attr:`perceptual_name`), >= 0; 0 = identical."""
    perceptual_name: str
    """``lpips`` (real LPIPS-alex) or ``lpips_proxy_vgg`` (:class:`PerceptualDistance`)."""
    ssim_impl: str
    """Which SSIM ran: ``abcgs_wang`` or ``pyiqa`` (:meth:`SSIM.provenance`)."""

    @property
    def ssim_mean(self) -> float:
        """Mean SSIM over the views (NaNs left out)."""
        return nan_mean(self.ssim)

    @property
    def perceptual_mean(self) -> float:
        """Mean perceptual distance over the views (NaNs left out)."""
        return nan_mean(self.perceptual)


def content_scores(originals: Sequence[np.ndarray], stylized: Sequence[np.ndarray], ssim: SSIM,
                   perceptual: PerceptualDistance, workers: int = 1) -> ContentScores:
    """SSIM and perceptual distance of every (original, stylized) render pair, channels-last in [0, 1], on
    ``workers`` threads (:func:`abcgs.evaluation.parallel.ordered_map`: the same numbers for any count); the
    perceptual distances batched (:meth:`PerceptualDistance.distances`: the same numbers as pair by pair)."""
    check_same_count(originals, stylized)
    pairs = list(zip(originals, stylized))
    return ContentScores(tuple(ordered_map(lambda pair: ssim(*pair), pairs, workers)),
                         tuple(perceptual.distances(originals, stylized, workers=workers)),
                         perceptual.name, ssim.provenance()["ssim_impl"])
