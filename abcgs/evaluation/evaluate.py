"""Evaluate one stylized scene against its original: every metric of SPEC stage 7, with provenance.

:func:`evaluate_scene` is the library entry (``stages/evaluate.py`` loads the pipeline outputs and calls it). Each
metric is a function of its own module returning a frozen dataclass (:class:`~abcgs.evaluation.content.ContentScores`,
:class:`~abcgs.evaluation.consistency.Consistency`, :class:`~abcgs.evaluation.reference.WarpFloor`,
:class:`~abcgs.evaluation.fid.FidKid`, :class:`~abcgs.evaluation.style_distance.GramScores`,
:class:`~abcgs.evaluation.artfid.ArtFID`, :class:`~abcgs.evaluation.record.RenderSpeed`); :func:`evaluate_images` and
:func:`evaluate_scene` collect them in an :class:`~abcgs.evaluation.record.EvalResult`, whose record
(``eval.json``, ``eval_views.csv``) :mod:`abcgs.evaluation.record` writes out. See the README section "Evaluation
metrics".
"""

from __future__ import annotations

import logging
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.evaluation.artfid import artfid
from abcgs.evaluation.consistency import (
    Consistency,
    FlowCache,
    PairResult,
    consistency,
    heatmap_panel,
    make_flow_estimator,
)
from abcgs.evaluation.content import (
    SSIM,
    PerceptualDistance,
    check_pair,
    check_same_count,
    content_scores,
    masked_rmse,
)
from abcgs.evaluation.fid import TFInception, fid_kid
from abcgs.evaluation.objects import object_scores
from abcgs.evaluation.pairs import ViewPairs, index_pairs
from abcgs.evaluation.parallel import resolve_workers
from abcgs.evaluation.params import EvalParams
from abcgs.evaluation.record import (
    ConsistencyPanel,
    EvalResult,
    EvalTimings,
    ImageEvaluation,
    MetricProvenance,
    ReferenceUse,
    RenderSpeed,
    StylizeTiming,
    Versions,
)
from abcgs.evaluation.reference import (
    SceneReference,
    WarpFloor,
    compute_floor,
    evaluated_cameras,
    pairs_for,
    render_alphas,
    render_views,
)
from abcgs.evaluation.style_distance import gram_scores
from abcgs.features.weights import resolve_vgg16
from abcgs.gaussians import GaussianModel, render
from abcgs.io.images import save_image
from abcgs.io.metrics import experiment_headline, read_record, write_headline, write_metrics
from abcgs.io.tables import write_csv
from abcgs.layout import ExperimentOut, StylizeDir
from abcgs.types import FRAME_FILLING, Backend, Background
from abcgs.viz import image_grid

log = logging.getLogger(__name__)


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


def _stopwatch() -> Callable[[], tuple[float, float]]:
    """A lap timer: each call returns the wall and the process CPU seconds (all threads) since the previous call (or
    since its creation)."""
    last = [time.perf_counter(), time.process_time()]

    def lap() -> tuple[float, float]:
        now = [time.perf_counter(), time.process_time()]
        wall, cpu = now[0] - last[0], now[1] - last[1]
        last[:] = now
        return wall, cpu

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
                                                  vgg_info=vgg_info.model_dump(), device=device,
                                                  precision=params.proxy_precision)
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
        timings=EvalTimings(content_s[0], consistency_s[0], fid_s[0], gram_s[0],
                            {"content_s": content_s[1], "consistency_s": consistency_s[1], "fid_s": fid_s[1],
                             "gram_s": gram_s[1]}),
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
    lap, started = _stopwatch(), (time.perf_counter(), time.process_time())
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
    render_s, render_cpu_s = lap()
    # the stylize stage's PNGs must be these views (fail before the slow metrics)
    saved_rmse = saved_renders_rmse(styl, saved_renders) if saved_renders is not None else None
    lap()
    speed = render_speed(stylized, cams, params, backend_s)
    speed_s = lap()
    res = evaluate_images(originals, styl, style_images, params, view_names=[Path(c.name).stem for c in cams],
                          device=stylized.device, **kwargs)
    lap()
    objects = None
    if background.object:
        ref_alphas = ref_alphas if ref_alphas is not None else render_alphas(original, cams, params.backend)
        objects = object_scores(originals, styl, ref_alphas, render_alphas(stylized, cams, params.backend),
                                res.images.short, res.images.long)
    objects_s = lap()
    timings = {"render_cpu_s": render_cpu_s, "speed_s": speed_s[0], "speed_cpu_s": speed_s[1]}
    if objects is not None:
        timings.update(objects_s=objects_s[0], objects_cpu_s=objects_s[1])
    timings.update(total_s=time.perf_counter() - started[0], total_cpu_s=time.process_time() - started[1])
    return EvalResult(
        res.images, speed, render_s, (backend, backend_s),
        StylizeTiming.of_record(stylize_info) if stylize_info is not None else None, saved_rmse,
        None if reference is None else ReferenceUse.of(reference), objects, timings,
    )


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
