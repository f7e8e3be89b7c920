"""The per-scene evaluation reference: the original scene's renders, the consistency pairs, the optical flows
between them, each pair's occlusion/in-frame mask and the unstylized scene's own warp error over those pairs (the
floor).

All depend on the fitted scene, its views and the flow settings only, never on a stylization, so the
``reference`` DVC stage (``stages/reference.py``) computes them once per scene and every experiment's
``evaluate`` reads them instead of re-rendering and re-estimating the flows (with RAFT on a CPU the flows are
most of an evaluation; with OpenCV's DIS they are seconds).

On disk (one folder per scene)::

    reference.json   view names and sizes, the pairs (:class:`~abcgs.evaluation.pairs.ViewPairs`), the floor,
                     which flows, settings they were made with, provenance
    renders.npz      view_0000 … : (H_i, W_i, 3) float32 renders in [0, 1] (exact, not 8-bit), on the scene's
                     background; alpha_0000 … : (H_i, W_i) float32 their alpha (object scenes)
    flows.npz        i_j_H_W : (H, W, 2) float32 flow from view i to view j on the grid (H, W)
    masks.npz        i_j_H_W : pair (i, j)'s mask (H, W) (fb_consistency_mask of its two flows, made for the floor),
                     bits packed (np.packbits), True = the pixel of view i counts

The arrays stay float32 (the masks exact bits), so metrics computed from a stored reference equal those computed
in memory; an evaluation reads the masks instead of recomputing them from the flows.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.evaluation.consistency import Consistency, FlowCache, make_flow_estimator, warp_floor
from abcgs.evaluation.pairs import ViewPairs, consistency_pairs
from abcgs.evaluation.params import EvalParams
from abcgs.gaussians import GaussianModel, render_each
from abcgs.io.atomic import atomic_path, write_json
from abcgs.silhouette import background_tensor
from abcgs.types import FRAME_FILLING, Backend, Background

REFERENCE_VERSION = 4
FLOW_SETTINGS = ("flow", "raft_weights", "raft_iterations", "pairs", "short_term_gap", "long_term_gap", "max_views",
                 "backend")
"""The ``evaluate`` settings a reference is made with; ``dvc.yaml``'s reference stage tracks these keys."""

FlowKey = tuple[int, int, tuple[int, int]]


@dataclass
class SceneReference:
    """Original renders ``(H_i, W_i, 3)`` float32 in [0, 1] of the evaluated views, their consistency pairs, the
    flows between them and the floor."""

    view_names: list[str]
    originals: list[np.ndarray]
    flows: dict[FlowKey, np.ndarray]
    """``(i, j, (H, W))`` → ``(H, W, 2)`` float32 flow in pixels from view ``i`` to ``j`` on the grid ``(H, W)``."""
    pairs: ViewPairs
    floor: WarpFloor
    """Per kind (``short``, ``long``) the unstylized scene's mean warp RMSE and per pair (:func:`compute_floor`)."""
    alphas: list[np.ndarray] | None = None
    """An object scene's original alpha ``(H_i, W_i)`` float32 per view (:mod:`abcgs.evaluation.objects`); else None."""
    info: dict = field(default_factory=dict)
    """What ``reference.json`` stores: views, settings, pairs, floor, provenance. Deterministic: the folder's hash
    is a dependency of every evaluation of the scene."""
    timings_s: dict[str, float] = field(default_factory=dict)
    """Wall seconds of ``render``, ``flow`` and ``floor`` when computed; logged by the stage, not stored."""
    masks: dict[FlowKey, np.ndarray] = field(default_factory=dict)
    """``(i, j, (H, W))`` → pair ``(i, j)``'s mask ``(H, W)`` bool (:meth:`FlowCache.mask`, made for the floor)."""

    def flow_cache(self) -> FlowCache:
        """A :class:`FlowCache` that serves the stored flows and masks and refuses to estimate other flows."""
        return FlowCache.precomputed(self.originals, self.flows, self.info["flow_provenance"], masks=self.masks)


def settings_of(params: EvalParams) -> dict:
    """The :data:`FLOW_SETTINGS` of ``params``, in that order, as ``reference.json`` stores them."""
    return {"flow": params.flow, "raft_weights": params.raft_weights, "raft_iterations": params.raft_iterations,
            "pairs": params.pairs, "short_term_gap": params.short_term_gap, "long_term_gap": params.long_term_gap,
            "max_views": params.max_views, "backend": params.backend}


@torch.no_grad()
def render_views(model: GaussianModel, cameras: list[Camera], backend: Backend,
                 background: Background = FRAME_FILLING) -> tuple[list[np.ndarray], str]:
    """Renders ``(H, W, 3)`` float32 clamped to [0, 1] (an object scene's on its ``background`` colour) and the
    backend that made them."""
    imgs, used = [], backend
    bg = background_tensor(background, model.means) if background.object else None
    for img, _, meta in render_each(model, cameras, backend=backend, background=bg):
        imgs.append(img.clamp(0, 1).cpu().numpy().astype(np.float32))
        used = meta.backend
    return imgs, used


@torch.no_grad()
def render_alphas(model: GaussianModel, cameras: list[Camera], backend: Backend) -> list[np.ndarray]:
    """The alpha ``(H, W)`` float32 of ``model`` in each of ``cameras``."""
    return [alpha[..., 0].cpu().numpy().astype(np.float32) for _, alpha, _ in render_each(model, cameras, backend=backend)]


def evaluated_cameras(cameras: list[Camera], params: EvalParams) -> list[Camera]:
    """The views evaluation uses: the first ``params.max_views`` (all when unset); at least two."""
    cams = cameras[: params.max_views] if params.max_views else list(cameras)
    if len(cams) < 2:
        raise InputError(f"evaluation needs at least 2 views, the scene has {len(cams)}")
    return cams


def pairs_for(cameras: list[Camera], params: EvalParams) -> ViewPairs:
    """The consistency pairs of the evaluated views ``cameras`` under ``params`` (``pairs``, the two gaps)."""
    return consistency_pairs(cameras, params.pairs, params.short_term_gap, params.long_term_gap)


def flow_pairs(originals: list[np.ndarray], pairs: ViewPairs) -> list[FlowKey]:
    """Every flow the short- and long-term consistency pairs ask for: both directions on the first view's grid."""
    keys: list[FlowKey] = []
    for kind in ("short", "long"):
        for i, j in pairs.of(kind):
            hw = tuple(np.shape(originals[i])[:2])
            for key in ((i, j, hw), (j, i, hw)):
                if key not in keys:
                    keys.append(key)
    return keys


def mask_pairs(originals: list[np.ndarray], pairs: ViewPairs) -> list[FlowKey]:
    """The masks the short- and long-term consistency pairs ask for: ``(i, j)`` on view ``i``'s grid, once each."""
    keys: list[FlowKey] = []
    for kind in ("short", "long"):
        for i, j in pairs.of(kind):
            key = (i, j, tuple(np.shape(originals[i])[:2]))
            if key not in keys:
                keys.append(key)
    return keys


@dataclass(frozen=True)
class KindFloor:
    """The unstylized scene's warp error over one kind of consistency pair (short or long)."""

    rmse: float
    """Mean masked warp RMSE over the pairs, image values in [0, 1] (the units of ``short_rmse``/``long_rmse``)."""
    valid_fraction: float
    """Mean fraction of the pairs' first-view pixels the occlusion/in-frame mask keeps, in [0, 1]."""
    per_pair: tuple[tuple[int, int, float], ...]
    """``(i, j, rmse)`` per pair: view ``j`` warped into view ``i``."""

    def rmse_of(self, i: int, j: int) -> float | None:
        """The RMSE of pair ``(i, j)``; None when the floor has no such pair."""
        return next((r for a, b, r in self.per_pair if (a, b) == (i, j)), None)

    @classmethod
    def of_consistency(cls, c: Consistency) -> KindFloor:
        return cls(c.rmse, c.valid_fraction, tuple((r.i, r.j, r.rmse) for r in c.pairs))

    def to_json(self) -> dict:
        return {"rmse": self.rmse, "valid_fraction": self.valid_fraction,
                "per_pair": [[i, j, r] for i, j, r in self.per_pair]}

    @classmethod
    def from_json(cls, d: dict) -> KindFloor:
        return cls(d["rmse"], d["valid_fraction"], tuple((int(i), int(j), r) for i, j, r in d["per_pair"]))


@dataclass(frozen=True)
class WarpFloor:
    """The floor of the consistency metrics: :func:`~abcgs.evaluation.consistency.warp_floor` over the short- and
    the long-range pairs. Stored in ``reference.json`` as ``{"short": ..., "long": ...}`` (:meth:`to_json`)."""

    short: KindFloor
    long: KindFloor

    def of(self, kind: str) -> KindFloor:
        """``kind``: ``short`` or ``long``."""
        return {"short": self.short, "long": self.long}[kind]

    def to_json(self) -> dict:
        return {"short": self.short.to_json(), "long": self.long.to_json()}

    @classmethod
    def from_json(cls, d: dict) -> WarpFloor:
        return cls(KindFloor.from_json(d["short"]), KindFloor.from_json(d["long"]))


def compute_floor(originals: list[np.ndarray], pairs: ViewPairs, flows: FlowCache) -> WarpFloor:
    """The unstylized scene's warp error over the short and long pairs (:func:`~abcgs.evaluation.consistency.warp_floor`)."""
    return WarpFloor(KindFloor.of_consistency(warp_floor(originals, pairs.short, flows)),
                     KindFloor.of_consistency(warp_floor(originals, pairs.long, flows)))


def compute_reference(cameras: list[Camera], original: GaussianModel, params: EvalParams, *,
                      model_digest: str | None = None, progress=None,
                      background: Background = FRAME_FILLING) -> SceneReference:
    """Render the original scene for the evaluated views (on an object scene's ``background``, with its alphas),
    pick the consistency pairs, estimate every flow they need and measure the floor."""
    cams = evaluated_cameras(cameras, params)
    pairs = pairs_for(cams, params)
    t = time.perf_counter()
    originals, backend = render_views(original, cams, params.backend, background)
    alphas = render_alphas(original, cams, params.backend) if background.object else None
    render_s = time.perf_counter() - t
    flows = FlowCache(originals, make_flow_estimator(params.flow, params.raft_weights, params.raft_iterations))
    t = time.perf_counter()
    keys = flow_pairs(originals, pairs)
    for key in (progress(keys) if progress else keys):
        flows(*key)
    flow_s = time.perf_counter() - t
    t = time.perf_counter()
    floor = compute_floor(originals, pairs, flows)
    masks = {k: flows.mask(*k) for k in mask_pairs(originals, pairs)}  # made by the floor: looked up
    info = {
        "version": REFERENCE_VERSION, "view_names": [c.name for c in cams],
        "sizes": [list(np.shape(o)[:2]) for o in originals], "settings": settings_of(params),
        "pairs": pairs.to_json(), "floor": floor.to_json(),
        "render_backend": backend, "flow_provenance": flows.provenance(), "n_flows": len(keys), "n_masks": len(masks),
        "model_digest": model_digest, "background": background.to_json(),
    }
    timings = {"render": render_s, "flow": flow_s, "floor": time.perf_counter() - t}
    return SceneReference([c.name for c in cams], originals, {k: flows(*k) for k in keys}, pairs, floor, alphas, info,
                          timings, masks)


def model_digest(path: Path) -> str:
    """sha256 (first 16 hex digits) of a PLY: ties a reference to the fitted scene it was rendered from."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def save_reference(folder: Path, ref: SceneReference) -> None:
    """Write ``ref`` to ``folder`` atomically (a half-written reference never appears)."""
    with atomic_path(folder, is_dir=True) as tmp:
        np.savez(tmp / "renders.npz", **{f"view_{k:04d}": o for k, o in enumerate(ref.originals)},
                 **{f"alpha_{k:04d}": a for k, a in enumerate(ref.alphas or [])})
        np.savez(tmp / "flows.npz", **{f"{i}_{j}_{h}_{w}": f for (i, j, (h, w)), f in ref.flows.items()})
        np.savez(tmp / "masks.npz", **{f"{i}_{j}_{h}_{w}": np.packbits(np.asarray(m, bool), axis=None)
                                      for (i, j, (h, w)), m in ref.masks.items()})
        write_json(tmp / "reference.json", ref.info)


def load_reference(folder: Path, cameras: list[Camera], params: EvalParams, *, model_digest: str | None = None,
                   scene: str = "<scene>") -> SceneReference:
    """Read a reference and check that it was made for these views, this fitted scene and these settings."""
    folder = Path(folder)
    redo = f"re-run the reference stage (dvc repro reference@{scene})"
    if not (folder / "reference.json").exists():
        raise InputError(f"{folder} holds no evaluation reference (reference.json missing): {redo}")
    info = json.loads((folder / "reference.json").read_text())
    if info.get("version") != REFERENCE_VERSION:
        raise InputError(f"{folder} is a reference of format {info.get('version')}, expected {REFERENCE_VERSION}: {redo}")
    cams = evaluated_cameras(cameras, params)
    if info["view_names"] != [c.name for c in cams]:
        raise InputError(f"{folder} was made for other views ({len(info['view_names'])} views, not {len(cams)}): {redo}")
    differ = {k: (info["settings"].get(k), v) for k, v in settings_of(params).items() if info["settings"].get(k) != v}
    if differ:
        raise InputError(f"{folder} was made with other evaluate settings {differ} (stored, current): {redo}")
    pairs = pairs_for(cams, params)
    if info.get("pairs") != pairs.to_json():
        raise InputError(f"{folder} was made for other consistency pairs (the camera poses changed): {redo}")
    if model_digest is not None and info.get("model_digest") not in (None, model_digest):
        raise InputError(f"{folder} was rendered from another fit of the scene: {redo}")
    with np.load(folder / "renders.npz") as z:
        originals = [z[f"view_{k:04d}"] for k in range(len(cams))]
        alphas = [z[f"alpha_{k:04d}"] for k in range(len(cams))] if "alpha_0000" in z.files else None
    for k, (o, c) in enumerate(zip(originals, cams)):
        if o.shape != (c.height, c.width, 3):
            raise InputError(f"{folder}: stored render {k} is {o.shape[1]}x{o.shape[0]}, view is {c.width}x{c.height}: {redo}")
    flows = {}
    with np.load(folder / "flows.npz") as z:
        for name in z.files:
            i, j, h, w = (int(v) for v in name.split("_"))
            flows[(i, j, (h, w))] = z[name]
    if not (folder / "masks.npz").is_file():
        raise InputError(f"{folder} holds no pair masks (masks.npz missing): {redo}")
    masks = {}
    with np.load(folder / "masks.npz") as z:
        for name in z.files:
            i, j, h, w = (int(v) for v in name.split("_"))
            masks[(i, j, (h, w))] = np.unpackbits(z[name], count=h * w).reshape(h, w).astype(bool)
    ref = SceneReference(info["view_names"], originals, flows, pairs, WarpFloor.from_json(info["floor"]), alphas, info,
                         masks=masks)
    missing = [k for k in flow_pairs(originals, pairs) if k not in flows]
    if missing:
        raise InputError(f"{folder} lacks {len(missing)} flows the consistency pairs need (e.g. {missing[0]}): {redo}")
    missing = [k for k in mask_pairs(originals, pairs) if k not in masks]
    if missing:
        raise InputError(f"{folder} lacks {len(missing)} masks the consistency pairs need (e.g. {missing[0]}): {redo}")
    return ref
