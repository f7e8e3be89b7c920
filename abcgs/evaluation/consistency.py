"""Multi-view consistency of a stylized scene: warp error between views, with occlusions masked.

For a view pair (i, j) the optical flow f_{i→j} is computed on the ORIGINAL (pre-stylization) renders, so
the correspondence does not depend on the stylization being judged. The stylized render of view j is
backward-warped into view i (``cv2.remap``, bilinear: warped(x) = S_j(x + f_{i→j}(x))) and compared with
the stylized render of view i on the pixels where the correspondence is trustworthy:

- forward–backward check (Sundaram, Brox & Keutzer 2010; the test used by Ruder et al.'s video style transfer
  and the 3D style-transfer papers): with f_b = f_{j→i} sampled at x + f_{i→j}(x), a pixel is kept when
  |f_{i→j} + f_b|² < 0.01·(|f_{i→j}|² + |f_b|²) + 0.5;
- the target x + f_{i→j}(x) must lie inside view j (out-of-frame pixels are invalid).

Views may differ in size (COLMAP gives each camera its own undistorted size): a pair is compared on the
grid of its first view ``i``, view ``j`` resampled onto it (:func:`on_grid`) before the flow and the warp;
the number of resampled pairs is reported.

Reported per pair: masked RMSE (images in [0, 1], averaged over the 3 channels), a masked perceptual
distance (:class:`abcgs.evaluation.content.PerceptualDistance`: real LPIPS-alex or the named VGG proxy) and the
fraction of view ``i``'s pixels the mask keeps. Which views are paired is :mod:`abcgs.evaluation.pairs`: views 1
and 7 apart along a path through the camera poses (``evaluate.pairs: pose``), or in file order (``index``).

The floor (:func:`warp_floor`): the same pairs, flows and masks applied to the original renders themselves. The
unstylized scene is consistent by construction, so what it scores is flow error, occlusion edges and resampling:
the part of a stylized scene's number that is measurement, not stylization.

Flow (``evaluate.flow``): ``raft`` = torchvision's RAFT-large (Teed & Deng 2020; weights from
``evaluate.raft_weights`` or torchvision's ``Raft_Large_Weights.DEFAULT`` file in the torch hub cache, which
torchvision downloads when online), ``dis`` = OpenCV DIS (PRESET_MEDIUM), ``deepflow`` / ``dualtvl1`` =
opencv-contrib; ``auto`` = RAFT when torchvision imports and its weights are on disk, else DIS. The method
used is recorded in the provenance.

Comparability with the paper: the paper's consistency numbers use RAFT flow (authors' later code) or
similar, LPIPS-alex, and the LLFF test views. The RMSE here follows the same definition, so it is
comparable in kind (the view set differs, and the flow method unless RAFT ran); the perceptual column is
comparable only when it is named ``lpips``.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from abcgs.errors import InputError
from abcgs.evaluation.content import (
    PerceptualDistance,
    check_pair,
    check_same_count,
    masked_rmse,
    nan_mean,
)
from abcgs.evaluation.pairs import path_pairs
from abcgs.evaluation.parallel import ordered_map
from abcgs.types import FlowEstimatorLike, FlowMethod

FB_ALPHA = 0.01
FB_BETA = 0.5
OCCLUSION_TEST = ("forward-backward check |f_fw + f_bw(x+f_fw)|^2 < 0.01(|f_fw|^2+|f_bw|^2) + 0.5 (Sundaram et al. 2010) "
                  "and target inside the frame")
"""The mask :func:`fb_consistency_mask` applies, in words (recorded with the numbers)."""


def flow_status(method: str) -> tuple[bool, str]:
    if method == "dis":
        return (hasattr(cv2, "DISOpticalFlow_create"), "cv2.DISOpticalFlow_create(PRESET_MEDIUM)")
    if method in ("deepflow", "dualtvl1"):
        if not hasattr(cv2, "optflow"):
            return False, "cv2.optflow is missing: install opencv-contrib-python(-headless) with a matching version"
        return True, {"deepflow": "cv2.optflow.createOptFlow_DeepFlow()", "dualtvl1": "cv2.optflow.DualTVL1OpticalFlow_create()"}[method]
    return False, f"unknown flow method {method!r} (auto | raft | dis | deepflow | dualtvl1)"


def raft_default_weights_file() -> Path | None:
    """Where torchvision keeps ``Raft_Large_Weights.DEFAULT`` in the torch hub cache (None: no torchvision)."""
    try:
        from torchvision.models.optical_flow import Raft_Large_Weights
    except Exception:  # not installed, or a torchvision built for another torch
        return None
    return Path(torch.hub.get_dir()) / "checkpoints" / Path(Raft_Large_Weights.DEFAULT.url).name


def raft_status(weights_path: str | None = None) -> tuple[bool, str]:
    """Whether RAFT can run here without a download: ``(ok, weights file or the reason it cannot)``."""
    if importlib.util.find_spec("torchvision") is None:
        return False, "torchvision is not installed (RAFT comes from torchvision; see README 'Evaluation metrics')"
    default = raft_default_weights_file()
    if default is None:
        return False, "torchvision does not import beside this torch build (see README 'Evaluation metrics')"
    f = Path(weights_path) if weights_path else default
    if not f.is_file():
        return False, f"RAFT weights not found at {f} (set evaluate.raft_weights, or run once online)"
    return True, str(f)


class RaftFlow:
    """Dense optical flow ``a → b`` by torchvision's RAFT-large, same convention as :class:`FlowEstimator`.

    Images in [0, 1] are mapped to [−1, 1] (torchvision's RAFT transforms), padded by edge replication to
    sides that are multiples of 8 and at least 128 px, and the last of ``iterations`` refinement steps is
    returned, cropped back.
    """

    def __init__(self, weights_path: str | None = None, iterations: int = 12) -> None:
        ok, what = raft_status(weights_path)
        if not ok:
            raise InputError(f"optical flow 'raft' is not available: {what}")
        from torchvision.models.optical_flow import raft_large

        from abcgs.io.digest import sha256_file

        self.weights, self.iterations, self.method = Path(what), iterations, "raft"
        self.model = raft_large(weights=None, progress=False).eval()
        try:
            self.model.load_state_dict(torch.load(self.weights, map_location="cpu", weights_only=True))
        except Exception as exc:
            raise InputError(f"{self.weights} is not a torchvision RAFT-large state dict: {exc}") from exc
        self.sha256 = sha256_file(self.weights)
        self.implementation = f"torchvision.models.optical_flow.raft_large, {iterations} updates"

    @torch.no_grad()
    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        check_pair(a, b, "flow inputs")
        h, w = np.asarray(a).shape[:2]
        # RAFT needs sides that are multiples of 8 and at least 128 px (its 4-level correlation pyramid at 1/8)
        ph, pw = max(128, h + (-h) % 8) - h, max(128, w + (-w) % 8) - w

        def prep(img: np.ndarray) -> torch.Tensor:
            t = torch.from_numpy(np.ascontiguousarray(img, dtype=np.float32)[..., :3]).permute(2, 0, 1)[None]
            t = t.clamp(0, 1) * 2 - 1
            return torch.nn.functional.pad(t, (0, pw, 0, ph), mode="replicate") if ph or pw else t

        flow = self.model(prep(a), prep(b), num_flow_updates=self.iterations)[-1]
        return flow[0, :, :h, :w].permute(1, 2, 0).contiguous().numpy().astype(np.float32)

    def provenance(self) -> dict:
        import torchvision

        return {"method": "raft", "implementation": self.implementation, "weights": str(self.weights),
                "weights_sha256": self.sha256, "torchvision_version": torchvision.__version__,
                "computed_on": "original (pre-stylization) renders, RGB in [-1, 1]"}


def make_flow_estimator(method: FlowMethod = "auto", raft_weights: str | None = None,
                        raft_iterations: int = 12) -> FlowEstimatorLike:
    """The flow estimator for ``evaluate.flow``; ``auto`` picks RAFT when :func:`raft_status` allows, else DIS."""
    if method != "auto":
        return RaftFlow(raft_weights, raft_iterations) if method == "raft" else FlowEstimator(method)
    ok, why = raft_status(raft_weights)
    return RaftFlow(raft_weights, raft_iterations) if ok else FlowEstimator("dis", why_not_raft=why)


def _gray_u8(img: np.ndarray) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype != np.uint8:
        a = (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return cv2.cvtColor(a, cv2.COLOR_RGB2GRAY) if a.ndim == 3 else a


class FlowEstimator:
    """Dense optical flow ``a → b`` (``(H, W, 2)`` float32, a(x) ≈ b(x + f(x))) by one OpenCV method."""

    def __init__(self, method: str = "dis", *, why_not_raft: str | None = None) -> None:
        ok, what = flow_status(method)
        if not ok:
            raise InputError(f"optical flow {method!r} is not available: {what}")
        self.method, self.implementation = method, what
        self.why_not_raft = why_not_raft  # set when `auto` fell back from RAFT; recorded in the provenance
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
        out = {"method": self.method, "implementation": self.implementation, "opencv_version": cv2.__version__,
               "computed_on": "original (pre-stylization) renders, 8-bit grey"}
        if self.why_not_raft:
            out["why_not_raft"] = self.why_not_raft
        return out


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


def depth_correspondence(
    depth_i: np.ndarray, depth_j: np.ndarray, K_i: np.ndarray, viewmat_i: np.ndarray, K_j: np.ndarray,
    viewmat_j: np.ndarray, *, valid_i: np.ndarray | None = None, rel_tol: float = 0.02,
) -> tuple[np.ndarray, np.ndarray]:
    """Correspondence ``i → j`` from a scene's own geometry instead of optical flow (a diagnostic).

    Every pixel centre of view ``i`` (``x + 0.5``, the renderer's convention) is lifted with its rendered
    depth ``depth_i`` ``(H, W)`` (camera z, world units), moved by the world→camera matrices ``viewmat_*``
    ``(4, 4)`` and projected with ``K_j`` ``(3, 3)``. Returns ``(flow, mask)``: ``flow`` ``(H, W, 2)`` float32
    in the :func:`backward_warp` convention, ``mask`` ``(H, W)`` bool — in front of camera ``j``, inside its
    frame, ``valid_i`` (e.g. alpha > 0.95), and visible in ``j`` (its depth there within ``rel_tol`` of the
    projected depth: occlusion test). Exact where the depth is (inside surfaces); what remains on the
    unstylized scene is depth blur at occlusion edges and resampling, so it bounds how much of a flow-based
    error is measurement.
    """
    if np.ndim(depth_i) < 2 or np.ndim(depth_j) < 2:
        raise InputError(f"depth maps must be (H, W); got {np.shape(depth_i)} and {np.shape(depth_j)}")
    h, w = depth_i.shape[:2]
    hj, wj = depth_j.shape[:2]
    z = np.asarray(depth_i, np.float64).reshape(h, w)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    cam_i = np.stack([(xs + 0.5 - K_i[0, 2]) / K_i[0, 0] * z, (ys + 0.5 - K_i[1, 2]) / K_i[1, 1] * z, z,
                      np.ones_like(z)], -1)
    cam_j = cam_i @ (np.asarray(viewmat_j, np.float64) @ np.linalg.inv(np.asarray(viewmat_i, np.float64))).T
    zj = cam_j[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = cam_j[..., 0] / zj * K_j[0, 0] + K_j[0, 2] - 0.5
        v = cam_j[..., 1] / zj * K_j[1, 1] + K_j[1, 2] - 0.5
    front = (z > 0) & (zj > 1e-9) & np.isfinite(u) & np.isfinite(v)
    u, v = np.where(front, u, -1.0), np.where(front, v, -1.0)
    flow = np.stack([u - xs, v - ys], -1).astype(np.float32)
    seen = cv2.remap(np.asarray(depth_j, np.float32).reshape(hj, wj), u.astype(np.float32), v.astype(np.float32),
                     interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    inside = (u >= 0) & (u <= wj - 1) & (v >= 0) & (v <= hj - 1)
    mask = front & inside & (np.abs(seen - zj) <= rel_tol * np.abs(zj))
    if valid_i is not None:
        mask &= np.asarray(valid_i, bool).reshape(h, w)
    return flow, mask


@dataclass
class PairResult:
    i: int
    j: int
    rmse: float
    perceptual: float
    valid_fraction: float
    warped: np.ndarray = field(repr=False)  # stylized j warped into i
    mask: np.ndarray = field(repr=False)  # (H, W) bool, True = counted
    resampled: bool = False  # view j differed in size and was resampled onto view i's grid

    def error_map(self, stylized_i: np.ndarray) -> np.ndarray:
        return np.sqrt(((np.asarray(stylized_i, np.float64) - self.warped) ** 2).mean(-1))


def view_pairs(n: int, gap: int) -> list[tuple[int, int]]:
    """``(i, i + g)`` for all i with g = min(gap, n − 1): ``n`` views paired in list order."""
    return path_pairs(range(n), gap)


def on_grid(img: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """``img`` resampled to ``hw = (H, W)`` (bilinear; area averaging when shrinking), unchanged if it fits.

    Views of one scene may differ in size (COLMAP gives every camera its own undistorted size); a pair is
    compared on the grid of its first view, the second view is resampled onto it before flow and warping.
    """
    a = np.asarray(img)
    if a.shape[:2] == tuple(hw):
        return a
    shrink = a.shape[0] * a.shape[1] > hw[0] * hw[1]
    out = cv2.resize(np.ascontiguousarray(a, dtype=np.float32), (int(hw[1]), int(hw[0])),
                     interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return out.reshape(*hw, *a.shape[2:])


class FlowCache:
    """Flows between original renders, computed once per ordered pair and grid, and the pairs' masks.

    ``flows(i, j, hw)``: flow from view ``i`` to view ``j``, both first put on the grid ``hw`` (the grid of
    the pair's reference view; :func:`on_grid`). ``flows.mask(i, j, hw)``: the pair's occlusion/in-frame mask
    (:func:`fb_consistency_mask` of the two flows), computed once. :meth:`precomputed` serves stored flows (and
    masks) only (the per-scene evaluation reference, :mod:`abcgs.evaluation.reference`).
    """

    def __init__(self, originals: list[np.ndarray], estimator: FlowEstimatorLike | None,
                 flows: dict | None = None, provenance: dict | None = None, masks: dict | None = None) -> None:
        self.originals, self.estimator, self._c = originals, estimator, dict(flows or {})
        self._provenance = provenance
        self._masks = dict(masks or {})

    @classmethod
    def precomputed(cls, originals: list[np.ndarray], flows: dict, provenance: dict,
                    masks: dict | None = None) -> FlowCache:
        """Stored flows ``{(i, j, (H, W)): (H, W, 2)}`` made by the estimator that ``provenance`` describes, and
        optionally the pairs' stored masks ``{(i, j, (H, W)): (H, W) bool}`` (others are computed from the flows)."""
        return cls(originals, None, flows, provenance, masks)

    def provenance(self) -> dict:
        return self._provenance if self.estimator is None else self.estimator.provenance()

    def __call__(self, i: int, j: int, hw: tuple[int, int] | None = None) -> np.ndarray:
        hw = tuple(hw) if hw is not None else tuple(np.shape(self.originals[i])[:2])
        if (i, j, hw) not in self._c:
            if self.estimator is None:
                raise InputError(f"no stored flow from view {i} to view {j} on the grid {hw}: the evaluation "
                                 "reference was made for other pairs; re-run the reference stage")
            self._c[(i, j, hw)] = self.estimator(on_grid(self.originals[i], hw), on_grid(self.originals[j], hw))
        return self._c[(i, j, hw)]

    def mask(self, i: int, j: int, hw: tuple[int, int] | None = None) -> np.ndarray:
        """Pair ``(i, j)``'s mask on the grid ``hw``: :func:`fb_consistency_mask` of the flows ``i → j`` and
        ``j → i``, computed once (or the stored one; the same array: it is a function of the stored flows)."""
        hw = tuple(hw) if hw is not None else tuple(np.shape(self.originals[i])[:2])
        m = self._masks.get((i, j, hw))
        if m is None:
            m = self._masks[(i, j, hw)] = fb_consistency_mask(self(i, j, hw), self(j, i, hw))
        return m


def warp_error(i: int, j: int, stylized: list[np.ndarray], flow: np.ndarray, mask: np.ndarray,
               perceptual: PerceptualDistance | None) -> PairResult:
    """Stylized view ``j`` warped into ``i`` by ``flow`` (``i → j``), compared with view ``i`` where ``mask``.

    ``flow`` is on view ``i``'s grid; view ``j`` is resampled onto that grid first when its size differs.
    """
    r = _warped(i, j, stylized, flow, mask)
    if perceptual is not None:
        r.perceptual = perceptual(stylized[i], r.warped, mask)
    return r


def _warped(i: int, j: int, stylized: list[np.ndarray], flow: np.ndarray, mask: np.ndarray) -> PairResult:
    """:func:`warp_error` without the perceptual distance (NaN): the warp, the masked RMSE, the valid fraction."""
    hw = flow.shape[:2]
    warped = backward_warp(on_grid(stylized[j], hw), flow)
    return PairResult(i, j, masked_rmse(stylized[i], warped, mask), float("nan"), float(mask.mean()), warped, mask,
                      resampled=tuple(np.shape(stylized[j])[:2]) != tuple(hw))


def evaluate_pair(i: int, j: int, stylized: list[np.ndarray], flows: FlowCache, perceptual: PerceptualDistance | None) -> PairResult:
    hw = tuple(np.shape(stylized[i])[:2])
    return warp_error(i, j, stylized, flows(i, j, hw), flows.mask(i, j, hw), perceptual)


@dataclass(frozen=True)
class Consistency:
    """Warp error of one kind of view pair (e.g. the short- or the long-range pairs) over a set of views."""

    rmse: float
    """Mean over the pairs of the masked RMSE, image values in [0, 1] averaged over the 3 channels; pairs without a
    valid pixel left out (NaN when no pair has one)."""
    perceptual: float
    """Mean over the pairs of the masked perceptual distance (its name: the ``PerceptualDistance``'s); NaN when none
    was given."""
    valid_fraction: float
    """Mean over the pairs of the fraction of view ``i``'s pixels the occlusion/in-frame mask keeps, in [0, 1]."""
    n_pairs_resampled: int
    """Pairs whose view ``j`` differed in size and was resampled onto view ``i``'s grid."""
    pairs: tuple[PairResult, ...] = field(repr=False, compare=False)
    """Per pair ``(i, j)`` (view ``j`` warped into view ``i``), in the order the pairs were given (not compared:
    they hold images)."""

    @property
    def n_pairs(self) -> int:
        return len(self.pairs)


def consistency(
    originals: list[np.ndarray], stylized: list[np.ndarray], pairs: int | Sequence[tuple[int, int]], flows: FlowCache,
    perceptual: PerceptualDistance | None, *, workers: int = 1,
) -> Consistency:
    """Mean masked RMSE / perceptual distance / valid fraction over ``pairs``, and the per-pair results.

    ``pairs``: ``(i, j)`` list indices (view ``j`` warped into view ``i``; e.g. a
    :class:`~abcgs.evaluation.pairs.ViewPairs`' ``short``), or an int: that gap in list order (:func:`view_pairs`).
    ``workers``: threads over the pairs (:func:`abcgs.evaluation.parallel.ordered_map`; the same results for any
    count). The flows are looked up (estimated, when ``flows`` has an estimator) first, in this thread; then each
    pair is warped and its mask taken (``flows.mask``: stored with a reference), and the perceptual distances of all
    pairs are computed batched (:meth:`~abcgs.evaluation.content.PerceptualDistance.distances`): the numbers are those
    of :func:`evaluate_pair` pair by pair.
    """
    check_same_count(originals, stylized)
    for k, (o, s) in enumerate(zip(originals, stylized)):
        check_pair(o, s, f"original and stylized render of view {k}")
    pairs = view_pairs(len(originals), pairs) if isinstance(pairs, int) else [(int(i), int(j)) for i, j in pairs]
    if not pairs:
        raise InputError("no view pairs to measure consistency on")
    for i, j in pairs:  # an estimator (one OpenCV object, or RAFT on torch's threads) runs here, not in the workers
        hw = tuple(np.shape(stylized[i])[:2])
        flows(i, j, hw), flows(j, i, hw)

    def warped(ij: tuple[int, int]) -> PairResult:
        hw = tuple(np.shape(stylized[ij[0]])[:2])
        return _warped(ij[0], ij[1], stylized, flows(ij[0], ij[1], hw), flows.mask(ij[0], ij[1], hw))

    results = ordered_map(warped, pairs, workers)
    if perceptual is not None:
        perc = perceptual.distances([stylized[r.i] for r in results], [r.warped for r in results],
                                    [r.mask for r in results], workers=workers)
        for r, d in zip(results, perc):
            r.perceptual = d
    return Consistency(
        pairs=tuple(results),
        rmse=nan_mean([r.rmse for r in results]),
        perceptual=nan_mean([r.perceptual for r in results]),
        valid_fraction=float(np.mean([r.valid_fraction for r in results])),
        n_pairs_resampled=sum(r.resampled for r in results),
    )


def warp_floor(originals: list[np.ndarray], pairs: int | Sequence[tuple[int, int]], flows: FlowCache, *,
               workers: int = 1) -> Consistency:
    """The unstylized scene's own warp error: :func:`consistency` of the original renders against themselves.

    Original view ``j`` warped into view ``i`` with the same flows and masks a stylization is measured with; the
    masked RMSE (no perceptual distance) per pair and its mean, in the same units as ``short_rmse``/``long_rmse``.
    """
    return consistency(originals, originals, pairs, flows, None, workers=workers)


def heatmap_panel(original_i: np.ndarray, stylized_i: np.ndarray, pair: PairResult, vmax: float = 0.5) -> list[np.ndarray]:
    """Cells for ``eval_consistency.png``: original i, stylized i, stylized j warped to i, error map.

    Error map: per-pixel RMSE over channels, inferno colour map on [0, ``vmax``]; pixels rejected by the
    forward–backward / in-frame test are drawn in flat cyan.
    """
    err = np.clip(pair.error_map(stylized_i) / vmax, 0, 1)
    heat = cv2.applyColorMap((err * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)[..., ::-1].copy()
    heat[~pair.mask] = (0, 255, 255)
    return [original_i, stylized_i, np.clip(pair.warped, 0, 1), heat]
