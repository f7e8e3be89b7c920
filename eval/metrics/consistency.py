"""Multi-view consistency of a stylized scene: warp error between views, with occlusions masked.

For a view pair (i, j) the optical flow f_{i→j} is computed on the ORIGINAL (pre-stylization) renders, so
the correspondence does not depend on the stylization being judged. The stylized render of view j is
backward-warped into view i (``cv2.remap``, bilinear: warped(x) = S_j(x + f_{i→j}(x))) and compared with
the stylized render of view i on the pixels where the correspondence is trustworthy:

- forward–backward check (Sundaram, Brox & Keutzer 2010; the test used by Ruder et al.'s video style transfer
  and the 3D style-transfer papers): with f_b = f_{j→i} sampled at x + f_{i→j}(x), a pixel is kept when
  |f_{i→j} + f_b|² < 0.01·(|f_{i→j}|² + |f_b|²) + 0.5;
- the target x + f_{i→j}(x) must lie inside view j (out-of-frame pixels are invalid).

Reported per pair: masked RMSE (images in [0, 1], averaged over the 3 channels) and a masked perceptual
distance (:class:`eval.metrics.content.PerceptualDistance`: real LPIPS-alex or the named VGG proxy);
short-term pairs are (i, i + 1), long-term pairs (i, i + gap) with gap clipped to n − 1 (training views
in capture order, as for forward-facing LLFF scenes).

Comparability with the paper: the paper's consistency numbers use RAFT flow (authors' later code) or
similar, LPIPS-alex, and the LLFF test views. The RMSE here follows the same definition, so it is
comparable in kind (flow method and view set differ; RMSE is not sensitive to the network); the
perceptual column is comparable only when it is named ``lpips``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from abcgs.errors import InputError
from eval.metrics.content import (
    PerceptualDistance,
    check_pair,
    check_same_count,
    masked_rmse,
)

FB_ALPHA = 0.01
FB_BETA = 0.5


def flow_status(method: str) -> tuple[bool, str]:
    if method == "dis":
        return (hasattr(cv2, "DISOpticalFlow_create"), "cv2.DISOpticalFlow_create(PRESET_MEDIUM)")
    if method in ("deepflow", "dualtvl1"):
        if not hasattr(cv2, "optflow"):
            return False, "cv2.optflow is missing: install opencv-contrib-python(-headless) with a matching version"
        return True, {"deepflow": "cv2.optflow.createOptFlow_DeepFlow()", "dualtvl1": "cv2.optflow.DualTVL1OpticalFlow_create()"}[method]
    return False, f"unknown flow method {method!r} (dis | deepflow | dualtvl1)"


def _gray_u8(img: np.ndarray) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype != np.uint8:
        a = (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return cv2.cvtColor(a, cv2.COLOR_RGB2GRAY) if a.ndim == 3 else a


class FlowEstimator:
    """Dense optical flow ``a → b`` (``(H, W, 2)`` float32, a(x) ≈ b(x + f(x))) by one OpenCV method."""

    def __init__(self, method: str = "dis") -> None:
        ok, what = flow_status(method)
        if not ok:
            raise InputError(f"optical flow {method!r} is not available: {what}")
        self.method, self.implementation = method, what
        if method == "dis":
            self._algo = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        elif method == "deepflow":
            self._algo = cv2.optflow.createOptFlow_DeepFlow()
        else:
            self._algo = cv2.optflow.DualTVL1OpticalFlow_create()

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        check_pair(a, b, "flow inputs")
        return self._algo.calc(_gray_u8(a), _gray_u8(b), None).astype(np.float32)

    def provenance(self) -> dict:
        return {"method": self.method, "implementation": self.implementation, "opencv_version": cv2.__version__,
                "computed_on": "original (pre-stylization) renders, 8-bit grey"}


def _grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    return xs, ys


def backward_warp(img: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """``out(x) = img(x + flow(x))`` (bilinear; outside the frame → 0)."""
    h, w = flow.shape[:2]
    xs, ys = _grid(h, w)
    return cv2.remap(np.ascontiguousarray(img, dtype=np.float32), xs + flow[..., 0], ys + flow[..., 1],
                     interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def in_frame_mask(flow: np.ndarray) -> np.ndarray:
    """Pixels whose target ``x + flow(x)`` lies inside the image (bilinear support within the frame)."""
    h, w = flow.shape[:2]
    xs, ys = _grid(h, w)
    tx, ty = xs + flow[..., 0], ys + flow[..., 1]
    return (tx >= 0) & (tx <= w - 1) & (ty >= 0) & (ty <= h - 1)


def fb_consistency_mask(flow_fw: np.ndarray, flow_bw: np.ndarray, alpha: float = FB_ALPHA, beta: float = FB_BETA) -> np.ndarray:
    """Sundaram et al. forward–backward test AND in-frame test → bool ``(H, W)``, True = valid (not occluded)."""
    check_pair(flow_fw, flow_bw, "forward/backward flows")
    bw_at = backward_warp(flow_bw, flow_fw)  # f_bw(x + f_fw(x))
    lhs = ((flow_fw + bw_at) ** 2).sum(-1)
    rhs = alpha * ((flow_fw**2).sum(-1) + (bw_at**2).sum(-1)) + beta
    return (lhs < rhs) & in_frame_mask(flow_fw)


@dataclass
class PairResult:
    i: int
    j: int
    rmse: float
    perceptual: float
    valid_fraction: float
    warped: np.ndarray = field(repr=False)  # stylized j warped into i
    mask: np.ndarray = field(repr=False)  # (H, W) bool, True = counted

    def error_map(self, stylized_i: np.ndarray) -> np.ndarray:
        return np.sqrt(((np.asarray(stylized_i, np.float64) - self.warped) ** 2).mean(-1))


def view_pairs(n: int, gap: int) -> list[tuple[int, int]]:
    """``(i, i + g)`` for all i with g = min(gap, n − 1)."""
    if n < 2:
        raise InputError(f"consistency needs at least 2 views, got {n}")
    g = max(1, min(gap, n - 1))
    return [(i, i + g) for i in range(n - g)]


class FlowCache:
    """Flows between original renders, computed once per ordered pair."""

    def __init__(self, originals: list[np.ndarray], estimator: FlowEstimator) -> None:
        self.originals, self.estimator, self._c = originals, estimator, {}

    def __call__(self, i: int, j: int) -> np.ndarray:
        if (i, j) not in self._c:
            self._c[(i, j)] = self.estimator(self.originals[i], self.originals[j])
        return self._c[(i, j)]


def evaluate_pair(i: int, j: int, stylized: list[np.ndarray], flows: FlowCache, perceptual: PerceptualDistance | None) -> PairResult:
    f_ij, f_ji = flows(i, j), flows(j, i)
    mask = fb_consistency_mask(f_ij, f_ji)
    warped = backward_warp(stylized[j], f_ij)
    rmse = masked_rmse(stylized[i], warped, mask)
    perc = perceptual(stylized[i], warped, mask) if perceptual is not None else float("nan")
    return PairResult(i, j, rmse, perc, float(mask.mean()), warped, mask)


def consistency(
    originals: list[np.ndarray], stylized: list[np.ndarray], gap: int, flows: FlowCache,
    perceptual: PerceptualDistance | None,
) -> tuple[dict, list[PairResult]]:
    """Mean masked RMSE / perceptual distance over the pairs ``(i, i + gap)``; per-pair results."""
    check_same_count(originals, stylized)
    for k, (o, s) in enumerate(zip(originals, stylized)):
        check_pair(o, s, f"original and stylized render of view {k}")
    results = [evaluate_pair(i, j, stylized, flows, perceptual) for i, j in view_pairs(len(originals), gap)]
    rm = np.array([r.rmse for r in results])
    pc = np.array([r.perceptual for r in results])
    summary = {
        "gap": results[0].j - results[0].i, "n_pairs": len(results),
        "rmse": float(np.nanmean(rm)) if np.isfinite(rm).any() else float("nan"),
        "perceptual": float(np.nanmean(pc)) if np.isfinite(pc).any() else float("nan"),
        "valid_fraction": float(np.mean([r.valid_fraction for r in results])),
    }
    return summary, results


def heatmap_panel(original_i: np.ndarray, stylized_i: np.ndarray, pair: PairResult, vmax: float = 0.5) -> list[np.ndarray]:
    """Cells for ``eval_consistency.png``: original i, stylized i, stylized j warped to i, error map.

    Error map: per-pixel RMSE over channels, inferno colour map on [0, ``vmax``]; pixels rejected by the
    forward–backward / in-frame test are drawn in flat cyan.
    """
    err = np.clip(pair.error_map(stylized_i) / vmax, 0, 1)
    heat = cv2.applyColorMap((err * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)[..., ::-1].copy()
    heat[~pair.mask] = (0, 255, 255)
    return [original_i, stylized_i, np.clip(pair.warped, 0, 1), heat]
