"""Evaluate one stylized scene against its original: every metric of SPEC stage 7, with provenance.

:func:`evaluate_scene` is the library entry (``stages/evaluate.py`` loads the pipeline outputs and calls it). Each
metric is a function of its own module returning a frozen dataclass (:class:`~abcgs.evaluation.content.ContentScores`,
:class:`~abcgs.evaluation.consistency.Consistency`, :class:`~abcgs.evaluation.reference.WarpFloor`,
:class:`~abcgs.evaluation.fid.FidKid`, :class:`~abcgs.evaluation.style_distance.GramScores`,
:class:`~abcgs.evaluation.artfid.ArtFID`, :class:`RenderSpeed`); :func:`evaluate_images` and :func:`evaluate_scene`
collect them in an :class:`EvalResult`, and :func:`eval_record` / :func:`view_rows` are the one mapping from those
fields to ``eval.json`` and ``eval_views.csv``. Key names say what a number is: ``lpips`` / ``artfid`` appear only when the official networks ran;
offline they are ``lpips_proxy_vgg`` / ``artfid_proxy``; FID/KID are ``fid_tf_inception`` /
``kid_tf_inception`` (patch-based, TF-FID Inception). See the README section "Evaluation metrics".
"""

from __future__ import annotations

import logging
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.evaluation.artfid import ArtFID, artfid
from abcgs.evaluation.consistency import (
    OCCLUSION_TEST,
    Consistency,
    FlowCache,
    PairResult,
    consistency,
    heatmap_panel,
    make_flow_estimator,
)
from abcgs.evaluation.content import (
    SSIM,
    ContentScores,
    PerceptualDistance,
    check_pair,
    check_same_count,
    content_scores,
    masked_rmse,
    package_version,
)
from abcgs.evaluation.fid import PATCH_PROTOCOL, FidKid, TFInception, fid_kid
from abcgs.evaluation.objects import ObjectScores, object_scores
from abcgs.evaluation.pairs import ViewPairs, index_pairs
from abcgs.evaluation.parallel import resolve_workers
from abcgs.evaluation.params import EvalParams
from abcgs.evaluation.reference import (
    SceneReference,
    WarpFloor,
    compute_floor,
    evaluated_cameras,
    pairs_for,
    render_alphas,
    render_views,
)
from abcgs.evaluation.style_distance import GRAM_DEFINITION, GramScores, gram_scores
from abcgs.features.weights import resolve_vgg16
from abcgs.gaussians import GaussianModel, render
from abcgs.io.images import save_image
from abcgs.io.metrics import experiment_headline, read_record, write_headline, write_metrics
from abcgs.io.tables import write_csv
from abcgs.layout import ExperimentOut, StylizeDir
from abcgs.types import FRAME_FILLING, Backend, Background
from abcgs.viz import image_grid

log = logging.getLogger(__name__)


# ------------------------------------------------------------------------------------------------ typed results
@dataclass(frozen=True)
class Versions:
    """Versions of the libraries the numbers depend on; None: not installed (left out of the record)."""

    python: str
    torch: str
    numpy: str
    opencv: str
    scipy: str | None
    lpips: str | None
    pyiqa: str | None

    @classmethod
    def installed(cls) -> Versions:
        return cls(platform.python_version(), torch.__version__, np.__version__, cv2.__version__,
                   package_version("scipy"), package_version("lpips"), package_version("pyiqa"))


@dataclass(frozen=True)
class MetricProvenance:
    """What computed the image metrics (recorded under ``provenance``)."""

    ssim: dict
    """:meth:`~abcgs.evaluation.content.SSIM.provenance`."""
    perceptual: dict
    """:attr:`~abcgs.evaluation.content.PerceptualDistance.info`: the distance, its network and weights."""
    flow: dict
    """:meth:`~abcgs.evaluation.consistency.FlowCache.provenance`: the optical flow method on the original renders."""
    vgg_weights: dict
    """The VGG-16 weights of the Gram distance (and of the perceptual proxy): source, path, sha256."""
    versions: Versions
    seed: int
    """``evaluate.seed``: the FID/KID patches and KID subsets."""


@dataclass(frozen=True)
class EvalTimings:
    """Wall seconds of the parts of :func:`evaluate_images`."""

    content_s: float
    """Loading the VGG-16 and the SSIM/perceptual distance, and the content scores."""
    consistency_s: float
    """Flows (when not stored), both pair kinds and the floor (when not stored)."""
    fid_s: float
    """Patches and the TF-Inception FID/KID."""
    gram_s: float
    """The Gram distance, its VGG-16 and the style images' Gram matrices included."""


@dataclass(frozen=True)
class ConsistencyPanel:
    """``eval_consistency.png``: one warped pair (:func:`~abcgs.evaluation.consistency.heatmap_panel`)."""

    cells: list[np.ndarray] = field(repr=False)
    """Original i, stylized i, stylized j warped into i, the error map (occluded pixels cyan): ``(H, W, 3)`` each."""
    captions: tuple[str, ...]


@dataclass(frozen=True)
class ImageEvaluation:
    """Every image metric of one stylization: :func:`evaluate_images`."""

    view_names: tuple[str, ...]
    view_sizes: tuple[tuple[int, int], ...]
    """``(H, W)`` px of each view's renders."""
    pairs: ViewPairs
    content: ContentScores
    short: Consistency
    """Views ``pairs.short_gap`` apart (list indices of ``pairs``)."""
    long: Consistency
    floor: WarpFloor
    """The unstylized scene's warp error over the same pairs."""
    fid: FidKid
    gram: GramScores
    artfid: ArtFID
    provenance: MetricProvenance
    timings: EvalTimings
    panel: ConsistencyPanel

    @property
    def n_views(self) -> int:
        return len(self.view_names)

    @property
    def resolution(self) -> list[int]:
        """``[W, H]`` px of the first view (views may differ: :attr:`n_view_sizes`)."""
        h, w = self.view_sizes[0]
        return [int(w), int(h)]

    @property
    def n_view_sizes(self) -> int:
        return len(set(self.view_sizes))


@dataclass(frozen=True)
class RenderSpeed:
    """Render speed of the stylized scene at evaluation resolution (:func:`render_speed`)."""

    fps: float
    """Views per second: views per pass / the median pass time."""
    pass_seconds: tuple[float, ...]
    """Wall seconds of each full pass over the views."""
    views_per_pass: int
    backend: str
    """The rasterizer backend that rendered."""
    device: str
    torch_threads: int
    pair_workers: int
    """Threads over the image pairs of the metrics (:func:`~abcgs.evaluation.parallel.resolve_workers`)."""


@dataclass(frozen=True)
class StylizeTiming:
    """The stylize stage's timing, from its record (``stylize.json``); None where the record lacks a field."""

    seconds: float | None
    """Wall seconds of the stylization."""
    iterations: int | None
    seconds_per_iteration: dict | None
    """Mean seconds per iteration of each part of a step (render, vgg, style_loss, backward, step)."""
    n_gaussians: int | None

    @classmethod
    def of_record(cls, record: dict) -> StylizeTiming:
        return cls(record.get("stylize_seconds"), record.get("iterations"), record.get("seconds_per_iteration"),
                   record.get("n_gaussians"))

    @property
    def minutes(self) -> float | None:
        return None if self.seconds is None else self.seconds / 60.0


@dataclass(frozen=True)
class ReferenceUse:
    """Which stored evaluation reference (:class:`~abcgs.evaluation.reference.SceneReference`) was used."""

    model_digest: str | None
    """:func:`~abcgs.evaluation.reference.model_digest` of the fitted scene it was rendered from."""
    n_flows: int | None
    """Stored flows."""

    @classmethod
    def of(cls, reference: SceneReference) -> ReferenceUse:
        return cls(reference.info.get("model_digest"), reference.info.get("n_flows"))


@dataclass(frozen=True)
class EvalResult:
    """One stylized scene's evaluation: :func:`evaluate_scene`, or :func:`evaluate_images` alone (the scene fields
    None). :attr:`metrics` is its record (``eval.json``)."""

    images: ImageEvaluation
    speed: RenderSpeed | None = None
    render_s: float | None = None
    """Wall seconds of rendering (or loading) the original and stylized views."""
    render_backends: tuple[str, str] | None = None
    """The backends of the original renders (``stored`` or the reference's) and of the stylized renders."""
    stylize: StylizeTiming | None = None
    saved_renders_rmse: float | None = None
    """Largest RMSE between a re-render and the stylize stage's 8-bit PNG of the view (~quantisation noise)."""
    reference: ReferenceUse | None = None
    """The stored reference the original renders and flows came from, when one was used."""
    objects: ObjectScores | None = None
    """An object scene's own metrics (:mod:`abcgs.evaluation.objects`); None for a frame-filling scene."""

    @property
    def metrics(self) -> dict:
        return eval_record(self)

    @property
    def per_view(self) -> list[dict]:
        rows = view_rows(self.images)
        if self.objects is not None:
            o = self.objects
            for row, ssim, change, iou in zip(rows, o.per_view_ssim, o.per_view_background_change,
                                              o.per_view_silhouette_iou):
                row.update(ssim_object=ssim, background_change=change, silhouette_iou=iou)
        return rows


# ------------------------------------------------------------------------------------------------ the metrics
@torch.no_grad()
def render_speed(model: GaussianModel, cameras: list[Camera], params: EvalParams, backend: Backend) -> RenderSpeed:
    """Median over ``params.fps_passes`` full passes of (views / seconds); the caller renders once before (warm-up).
    ``backend``: the one that rendered then (recorded)."""
    times = []
    for _ in range(params.fps_passes):
        t0 = time.perf_counter()
        for cam in cameras:
            img, _, _ = render(model, cam, backend=params.backend)
        if img.is_cuda:
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return RenderSpeed(len(cameras) / statistics.median(times), tuple(times), len(cameras), backend, str(model.device),
                       torch.get_num_threads(), resolve_workers(params.workers))


def saved_renders_rmse(renders: list[np.ndarray], saved: list[np.ndarray]) -> float:
    """Largest RMSE between ``renders`` and the first ``len(renders)`` ``saved`` ones; fails on a count or size
    mismatch (the stylize stage's PNGs must be these views)."""
    saved = saved[: len(renders)]
    check_same_count(renders, saved, "re-rendered stylized views", "saved stylize renders")
    for k, (a, b) in enumerate(zip(renders, saved)):
        check_pair(a, b, f"re-rendered and saved stylized view {k}")
    return max(masked_rmse(a, b) for a, b in zip(renders, saved))


def _checked_pairs(originals, stylized, style_images, params: EvalParams, pairs: ViewPairs | None) -> ViewPairs:
    """Fail on mismatched inputs before any network loads; the consistency pairs (list order without ``pairs``)."""
    check_same_count(originals, stylized)
    for k, (o, s) in enumerate(zip(originals, stylized)):
        check_pair(o, s, f"original and stylized render of view {k}")
    n = len(originals)
    if n < 2:
        raise InputError(f"evaluation needs at least 2 views, got {n}")
    if not style_images:
        raise InputError("no style images to compare the stylized renders with")
    if pairs is None:
        if params.pairs != "index":
            raise InputError(f"evaluate.pairs: {params.pairs} pairs views by their cameras: pass the pairs "
                             "(abcgs.evaluation.reference.pairs_for), or use evaluate.pairs: index")
        pairs = index_pairs(n, params.short_term_gap, params.long_term_gap)
    if sorted(pairs.order) != list(range(n)):
        raise InputError(f"the consistency pairs were made for {len(pairs.order)} views, not these {n}")
    return pairs


def _stopwatch() -> Callable[[], float]:
    """A lap timer: each call returns the wall seconds since the previous call (or since its creation)."""
    last = [time.perf_counter()]

    def lap() -> float:
        now = time.perf_counter()
        seconds, last[0] = now - last[0], now
        return seconds

    return lap


def consistency_panel(originals, stylized, names, short: Consistency, long: Consistency,
                      params: EvalParams) -> ConsistencyPanel:
    """The pair ``eval_consistency.png`` shows: of ``params.heatmap_pair``'s kind, the one starting at view
    ``params.heatmap_view`` (else the pair at that position)."""
    shown = (short if params.heatmap_pair == "short" else long).pairs
    pr: PairResult = next((r for r in shown if r.i == params.heatmap_view),
                          shown[min(params.heatmap_view, len(shown) - 1)])
    return ConsistencyPanel(heatmap_panel(originals[pr.i], stylized[pr.i], pr),
                            (f"original {names[pr.i]}", f"stylized {names[pr.i]}", f"stylized {names[pr.j]} warped",
                             f"error (cyan: occluded) rmse {pr.rmse:.3f}"))


def evaluate_images(
    originals: list[np.ndarray],
    stylized: list[np.ndarray],
    style_images: list[np.ndarray],
    params: EvalParams,
    *,
    perceptual: PerceptualDistance | None = None,
    inception: TFInception | None = None,
    view_names: list[str] | None = None,
    vgg_params=None,
    flows: FlowCache | None = None,
    pairs: ViewPairs | None = None,
    floor: WarpFloor | None = None,
    device: torch.device | str = "cpu",
) -> EvalResult:
    """All image metrics for matched lists of original/stylized renders (channels-last, [0, 1]).

    ``flows``: flows between the original renders (e.g. a stored :class:`~abcgs.evaluation.reference.SceneReference`'s);
    estimated here with ``params.flow`` when not given. ``pairs``: the consistency pairs
    (:func:`abcgs.evaluation.reference.pairs_for` the cameras); without them only ``evaluate.pairs: index`` works
    (list order). ``floor``: the unstylized scene's warp error over those pairs
    (:func:`abcgs.evaluation.reference.compute_floor`, stored in a reference); measured here when not given.
    ``device``: where the metric networks (VGG, Inception, LPIPS) run; the images stay numpy on the host.
    """
    pairs = _checked_pairs(originals, stylized, style_images, params, pairs)
    names = tuple(view_names or [str(i) for i in range(len(originals))])
    workers = resolve_workers(params.workers)
    lap = _stopwatch()
    vgg_state, vgg_info = resolve_vgg16(vgg_params)  # one VGG-16 for the perceptual proxy and the Gram distance
    ssim = SSIM(params.ssim_impl)
    perceptual = perceptual or PerceptualDistance(params.perceptual, layers=params.proxy_layers, vgg_state=vgg_state,
                                                  vgg_info=vgg_info.model_dump(), device=device)
    content = content_scores(originals, stylized, ssim, perceptual, workers)
    content_s = lap()
    if flows is None:
        flows = FlowCache(originals, make_flow_estimator(params.flow, params.raft_weights, params.raft_iterations))
    short = consistency(originals, stylized, pairs.short, flows, perceptual, workers=workers)
    long = consistency(originals, stylized, pairs.long, flows, perceptual, workers=workers)
    floor = floor if floor is not None else compute_floor(originals, pairs, flows)
    consistency_s = lap()
    fk = fid_kid(stylized, style_images, params, inception, workers=workers, device=device)
    fid_s = lap()
    gram = gram_scores(vgg_state, stylized, style_images, params.gram_layers, params.gram_style_height,
                       workers=workers, device=device)
    gram_s = lap()
    art = artfid(content, fk, perceptual.note, params.art_inception_path, batch=params.fid_batch, device=device)
    return EvalResult(ImageEvaluation(
        view_names=names, view_sizes=tuple(tuple(int(v) for v in np.shape(o)[:2]) for o in originals), pairs=pairs,
        content=content, short=short, long=long, floor=floor, fid=fk, gram=gram, artfid=art,
        provenance=MetricProvenance(ssim.provenance(), perceptual.info, flows.provenance(), vgg_info.model_dump(),
                                    Versions.installed(), params.seed),
        timings=EvalTimings(content_s, consistency_s, fid_s, gram_s),
        panel=consistency_panel(originals, stylized, names, short, long, params),
    ))


def evaluate_scene(
    cameras: list[Camera],
    original: GaussianModel,
    stylized: GaussianModel,
    style_images: list[np.ndarray],
    params: EvalParams,
    *,
    stylize_info: dict | None = None,
    saved_renders: list[np.ndarray] | None = None,
    reference: SceneReference | None = None,
    background: Background = FRAME_FILLING,
    **kwargs,
) -> EvalResult:
    """Render both scenes for ``cameras`` (first ``params.max_views``), compute all metrics, time rendering.

    ``reference``: the original scene's stored renders and flows (the per-scene ``reference`` stage; see
    :mod:`abcgs.evaluation.reference`), used instead of rendering ``original`` and estimating flows here.
    ``background``: the scene's; both scenes render on an object scene's colour, and its object metrics are added
    (:mod:`abcgs.evaluation.objects`).
    """
    if params.num_threads is not None:
        old = torch.get_num_threads()
        torch.set_num_threads(params.num_threads)
        try:
            return _evaluate_scene(cameras, original, stylized, style_images, params, stylize_info=stylize_info,
                                   saved_renders=saved_renders, reference=reference, background=background, **kwargs)
        finally:
            torch.set_num_threads(old)
    return _evaluate_scene(cameras, original, stylized, style_images, params, stylize_info=stylize_info,
                           saved_renders=saved_renders, reference=reference, background=background, **kwargs)


def _evaluate_scene(cameras: list[Camera], original: GaussianModel, stylized: GaussianModel,
                    style_images: list[np.ndarray], params: EvalParams, *, stylize_info: dict | None = None,
                    saved_renders: list[np.ndarray] | None = None, reference: SceneReference | None = None,
                    background: Background = FRAME_FILLING, **kwargs) -> EvalResult:
    cams = evaluated_cameras(cameras, params)
    t = time.perf_counter()
    ref_alphas = None
    if reference is not None:
        if reference.view_names != [c.name for c in cams]:
            raise InputError("the evaluation reference was made for other views; re-run the reference stage")
        if reference.info.get("background", Background().to_json()) != background.to_json():
            raise InputError("the evaluation reference was rendered on another background than the scene's; re-run "
                             "the reference stage")
        originals, backend = reference.originals, reference.info.get("render_backend", "stored")
        ref_alphas = reference.alphas
        kwargs.update(flows=reference.flow_cache(), pairs=reference.pairs, floor=reference.floor)
    else:
        originals, backend = render_views(original, cams, params.backend, background)
        kwargs.setdefault("pairs", pairs_for(cams, params))
    styl, backend_s = render_views(stylized, cams, params.backend, background)
    render_s = time.perf_counter() - t
    # the stylize stage's PNGs must be these views (fail before the slow metrics)
    saved_rmse = saved_renders_rmse(styl, saved_renders) if saved_renders is not None else None
    speed = render_speed(stylized, cams, params, backend_s)
    res = evaluate_images(originals, styl, style_images, params, view_names=[Path(c.name).stem for c in cams],
                          device=stylized.device, **kwargs)
    objects = None
    if background.object:
        ref_alphas = ref_alphas if ref_alphas is not None else render_alphas(original, cams, params.backend)
        objects = object_scores(originals, styl, ref_alphas, render_alphas(stylized, cams, params.backend),
                                res.images.short, res.images.long)
    return EvalResult(
        res.images, speed, render_s, (backend, backend_s),
        StylizeTiming.of_record(stylize_info) if stylize_info is not None else None, saved_rmse,
        None if reference is None else ReferenceUse.of(reference), objects,
    )


# ------------------------------------------------------------------------------------------------ the record
@dataclass(frozen=True)
class PerceptualKeys:
    """The record keys of one perceptual distance: its name says whether it is the official LPIPS or the proxy."""

    content: str
    short: str
    long: str
    pair: str
    """The per-pair key under ``consistency_pairs``."""


PERCEPTUAL_KEYS: dict[str, PerceptualKeys] = {
    "lpips": PerceptualKeys("content_lpips", "short_lpips", "long_lpips", "lpips"),
    "lpips_proxy_vgg": PerceptualKeys("content_lpips_proxy_vgg", "short_lpips_proxy_vgg", "long_lpips_proxy_vgg",
                                      "lpips_proxy_vgg"),
}
"""Perceptual distance name (:attr:`~abcgs.evaluation.content.PerceptualDistance.name`) → its record keys."""
ARTFID_KEY: dict[bool, str] = {True: "artfid", False: "artfid_proxy"}
"""Official (both official components ran) → the record key of the ArtFID value."""


def _without_none(d: dict) -> dict:
    return {k: v for k, v in d.items() if v is not None}


def _pair_rows(c: Consistency, floor, names, pk: PerceptualKeys) -> list[dict]:
    return [{"view": names[r.i], "pair_view": names[r.j], "i": r.i, "j": r.j, "rmse": r.rmse, pk.pair: r.perceptual,
             "valid_fraction": r.valid_fraction, "rmse_floor": floor.rmse_of(r.i, r.j)} for r in c.pairs]


def view_rows(ev: ImageEvaluation) -> list[dict]:
    """``eval_views.csv``: per view its scores; a pair ``(i, j)`` is attributed to view ``i`` (each view is the first
    of at most one pair of a kind)."""
    pk = PERCEPTUAL_KEYS[ev.content.perceptual_name]
    short, long = {r.i: r for r in ev.short.pairs}, {r.i: r for r in ev.long.pairs}
    rows = []
    for i, name in enumerate(ev.view_names):
        s, lg = short.get(i), long.get(i)
        rows.append({
            "view": i, "name": name, "ssim": ev.content.ssim[i], pk.content: ev.content.perceptual[i],
            "short_rmse": s.rmse if s else None, pk.short: s.perceptual if s else None,
            "short_pair": ev.view_names[s.j] if s else None, "short_valid_fraction": s.valid_fraction if s else None,
            "long_rmse": lg.rmse if lg else None, pk.long: lg.perceptual if lg else None,
            "long_pair": ev.view_names[lg.j] if lg else None, "long_valid_fraction": lg.valid_fraction if lg else None,
            "gram_distance": ev.gram.per_view[i],
        })
    return rows


def eval_record(res: EvalResult) -> dict:
    """The evaluation record (``eval.json`` / ``eval_info.json``, the headline's source), written out field by field."""
    ev, pk = res.images, PERCEPTUAL_KEYS[res.images.content.perceptual_name]
    fk, art, prov = ev.fid, ev.artfid, ev.provenance
    style_distance = {"name": art.style_name, "value": art.style_value}
    if art.style_network is not None:
        style_distance["network"] = art.style_network
    v = prov.versions
    record = {
        "n_views": ev.n_views, "resolution": ev.resolution,  # of the first view; views may differ (n_view_sizes)
        "ssim": ev.content.ssim_mean, "ssim_impl": ev.content.ssim_impl,
        pk.content: ev.content.perceptual_mean,
        "short_rmse": ev.short.rmse, pk.short: ev.short.perceptual,
        "long_rmse": ev.long.rmse, pk.long: ev.long.perceptual,
        "short_rmse_floor": ev.floor.short.rmse, "long_rmse_floor": ev.floor.long.rmse,
        "pairs": ev.pairs.mode, "short_term_gap": ev.pairs.short_gap, "long_term_gap": ev.pairs.long_gap,
        "short_valid_fraction": ev.short.valid_fraction, "long_valid_fraction": ev.long.valid_fraction,
        "consistency_pairs": {"mode": ev.pairs.mode, "order": [ev.view_names[k] for k in ev.pairs.order],
                              "short": _pair_rows(ev.short, ev.floor.short, ev.view_names, pk),
                              "long": _pair_rows(ev.long, ev.floor.long, ev.view_names, pk)},
        "n_view_sizes": ev.n_view_sizes,
        "short_pairs_resampled": ev.short.n_pairs_resampled, "long_pairs_resampled": ev.long.n_pairs_resampled,
        "fid_tf_inception": fk.fid, "kid_tf_inception": fk.kid, "kid_tf_inception_std": fk.kid_std,
        "gram_distance": ev.gram.mean,
        ARTFID_KEY[art.official]: art.value,
        "artfid_components": {"content_distance": {"name": art.content_name, "value": art.content_value},
                              "style_distance": style_distance, "note": art.note},
        "provenance": {
            "ssim": prov.ssim, "perceptual": prov.perceptual, "flow": prov.flow, "occlusion": OCCLUSION_TEST,
            "fid_kid": {
                "inception": fk.inception if fk.inception is not None else "not computed: evaluate.fid is false",
                "n_stylized_patches": fk.n_stylized_patches, "n_style_patches": fk.n_style_patches,
                "n_style_images": fk.n_style_images, "patch_size_px": fk.patch_size_px,
                "kid_subset_size": fk.kid_subset_size, "kid_subsets": fk.kid_subsets, "protocol": PATCH_PROTOCOL,
            },
            "gram_distance": {"name": "gram_distance", "layers": list(ev.gram.layers),
                              "downsample_renders": ev.gram.downsample_renders, "definition": GRAM_DEFINITION,
                              "style_height": ev.gram.style_height, "vgg_weights": prov.vgg_weights},
            "seed": prov.seed,
            "versions": _without_none({"python": v.python, "torch": v.torch, "numpy": v.numpy, "opencv": v.opencv,
                                       "scipy": v.scipy, "lpips": v.lpips, "pyiqa": v.pyiqa}),
        },
        "eval_timings_s": {"content_s": ev.timings.content_s, "consistency_s": ev.timings.consistency_s,
                           "fid_s": ev.timings.fid_s, "gram_s": ev.timings.gram_s},
    }
    if res.render_backends is not None:
        record["provenance"]["render_backend"] = {"original": res.render_backends[0], "stylized": res.render_backends[1]}
    if res.reference is not None:
        record["provenance"]["reference"] = {"model_digest": res.reference.model_digest,
                                             "n_flows": res.reference.n_flows}
    if res.render_s is not None:
        record["eval_timings_s"]["render_s"] = res.render_s
    if res.speed is not None:
        sp = res.speed
        record["render_fps"] = sp.fps
        record["speed"] = {"render_fps": sp.fps, "fps_passes_s": list(sp.pass_seconds),
                           "fps_views_per_pass": sp.views_per_pass, "backend": sp.backend, "device": sp.device,
                           "resolution": ev.resolution, "torch_threads": sp.torch_threads,
                           "pair_workers": sp.pair_workers}
    if res.stylize is not None:
        st = res.stylize
        record["stylize_seconds"], record["stylize_minutes"] = st.seconds, st.minutes
        record.setdefault("speed", {}).update({"stylize_seconds": st.seconds, "iterations": st.iterations,
                                               "seconds_per_iteration": st.seconds_per_iteration,
                                               "n_gaussians": st.n_gaussians})
    if res.objects is not None:
        record.update(res.objects.record())
    if res.saved_renders_rmse is not None:
        record["saved_renders_rmse"] = res.saved_renders_rmse  # re-render vs stylize's 8-bit PNGs: ~quantisation noise
    return record


def load_stylize_run(stylized: StylizeDir, record: Path, name: str,
                     view_stems: list[str]) -> tuple[Path, dict, list[Path]]:
    """The stylize stage's outputs for experiment ``name``: its folder ``stylized`` (PLY, one render per view in
    ``view_stems``' order, checked against the scene's views) and its full ``record`` (``stylize_info.json``)."""
    ply, renders = stylized.ply, stylized.renders
    for p in (ply, record, renders):
        if not p.exists():
            raise InputError(f"{p} is missing: run the stylize stage for experiment {name!r} first (dvc repro stylize@{name})")
    pngs = sorted(renders.glob("*.png"))
    if len(pngs) != len(view_stems):
        raise InputError(
            f"{renders} holds {len(pngs)} renders but the scene has {len(view_stems)} views: the stylize run is stale "
            f"or incomplete; re-run dvc repro stylize@{name}"
        )
    by_stem = {p.stem: p for p in pngs}
    missing = [s for s in view_stems if s not in by_stem]
    if missing:
        raise InputError(f"{renders} has no render for views {missing[:5]}: names do not match the scene's cameras")
    return ply, read_record(record), [by_stem[s] for s in view_stems]


def write_evaluation(record_path: Path, headline_path: Path, record: dict, result: EvalResult) -> None:
    """Write the evaluation's files: the full record ``record_path`` (``eval.json`` + ``eval_info.json``), the
    headline DVC metric ``headline_path`` (:func:`abcgs.io.metrics.experiment_headline`), ``eval_views.csv`` (per-view
    scores, a DVC plot) and ``eval_consistency.png`` (one warped pair: error map, occlusion mask in cyan) beside the
    record."""
    panel, beside = result.images.panel, ExperimentOut(record_path.parent)
    save_image(beside.eval_consistency,
               image_grid([panel.cells], list(panel.captions), height=max(160, panel.cells[0].shape[0])))
    write_csv(beside.eval_views, result.per_view)
    write_metrics(record_path, record)
    write_headline(headline_path, experiment_headline(record))
