"""Evaluate one stylized scene against its original: every metric of SPEC stage 7, with provenance.

:func:`evaluate_scene` is the library entry (``stages/evaluate.py`` loads the pipeline outputs and calls it).
Key names say what a number is: ``lpips`` / ``artfid`` appear only when the official networks ran;
offline they are ``lpips_proxy_vgg`` / ``artfid_proxy``; FID/KID are ``fid_tf_inception`` /
``kid_tf_inception`` (patch-based, TF-FID Inception). See the README section "Evaluation metrics".
"""

from __future__ import annotations

import importlib.metadata
import logging
import platform
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.evaluation.artfid import ArtInception, artfid_formula, find_art_inception
from abcgs.evaluation.consistency import (
    FlowCache,
    consistency,
    heatmap_panel,
    make_flow_estimator,
)
from abcgs.evaluation.content import (
    SSIM,
    PerceptualDistance,
    check_pair,
    check_same_count,
    masked_rmse,
)
from abcgs.evaluation.fid import (
    TFInception,
    fid_from_features,
    kid,
    random_patches,
    resize_short_side,
)
from abcgs.evaluation.pairs import ViewPairs, index_pairs
from abcgs.evaluation.parallel import ordered_map, resolve_workers
from abcgs.evaluation.params import EvalParams
from abcgs.evaluation.reference import SceneReference, compute_floor, evaluated_cameras, pairs_for, render_views
from abcgs.evaluation.style_distance import GramDistance
from abcgs.features.matching import resize_to_height
from abcgs.features.weights import resolve_vgg16
from abcgs.gaussians import GaussianModel, render
from abcgs.io.images import save_image
from abcgs.io.metrics import experiment_headline, read_record, write_headline, write_metrics
from abcgs.io.tables import write_csv
from abcgs.types import Backend
from abcgs.viz import image_grid

log = logging.getLogger(__name__)

@dataclass
class EvalResult:
    metrics: dict
    per_view: list[dict]
    heatmap: list[np.ndarray]  # cells of one image_grid row (see consistency.heatmap_panel)
    heatmap_captions: list[str]


def _versions() -> dict:
    out = {"python": platform.python_version(), "torch": torch.__version__, "numpy": np.__version__, "opencv": cv2.__version__}
    for dist in ("scipy", "lpips", "pyiqa"):
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            pass
    return out


@torch.no_grad()
def render_fps(model: GaussianModel, cameras: list[Camera], backend: Backend, passes: int) -> tuple[float, list[float]]:
    """Median over ``passes`` full passes of (views / seconds); the caller renders once before (warm-up)."""
    times = []
    for _ in range(passes):
        t0 = time.perf_counter()
        for cam in cameras:
            img, _, _ = render(model, cam, backend=backend)
        if img.is_cuda:
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return len(cameras) / statistics.median(times), times


def _mean(v) -> float:
    a = np.asarray(v, np.float64)
    return float(np.nanmean(a)) if np.isfinite(a).any() else float("nan")


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
    floor: dict | None = None,
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
    check_same_count(originals, stylized)
    for k, (o, s) in enumerate(zip(originals, stylized)):
        check_pair(o, s, f"original and stylized render of view {k}")
    if len(originals) < 2:
        raise InputError(f"evaluation needs at least 2 views, got {len(originals)}")
    if not style_images:
        raise InputError("no style images to compare the stylized renders with")
    n = len(originals)
    names = view_names or [str(i) for i in range(n)]
    if pairs is None:
        if params.pairs != "index":
            raise InputError(f"evaluate.pairs: {params.pairs} pairs views by their cameras: pass the pairs "
                             "(abcgs.evaluation.reference.pairs_for), or use evaluate.pairs: index")
        pairs = index_pairs(n, params.short_term_gap, params.long_term_gap)
    if sorted(pairs.order) != list(range(n)):
        raise InputError(f"the consistency pairs were made for {len(pairs.order)} views, not these {n}")
    timings: dict[str, float] = {}
    t = time.perf_counter()

    # one VGG-16 resolution for the perceptual proxy and the Gram distance
    vgg_state, vgg_info = resolve_vgg16(vgg_params)
    ssim = SSIM(params.ssim_impl)
    perceptual = perceptual or PerceptualDistance(params.perceptual, layers=params.proxy_layers, vgg_state=vgg_state,
                                                  vgg_info=vgg_info.model_dump(), device=device)
    pname = perceptual.name
    workers = resolve_workers(params.workers)
    ssims = ordered_map(lambda pair: ssim(*pair), zip(originals, stylized), workers)
    content = ordered_map(lambda pair: perceptual(*pair), zip(originals, stylized), workers)
    timings["content_s"] = time.perf_counter() - t

    t = time.perf_counter()
    if flows is None:
        flows = FlowCache(originals, make_flow_estimator(params.flow, params.raft_weights, params.raft_iterations))
    short, short_pairs = consistency(originals, stylized, pairs.short, flows, perceptual, workers=workers)
    long, long_pairs = consistency(originals, stylized, pairs.long, flows, perceptual, workers=workers)
    if floor is None:
        floor = compute_floor(originals, pairs, flows)
    timings["consistency_s"] = time.perf_counter() - t

    t = time.perf_counter()
    h, w = originals[0].shape[:2]
    n_r = n * params.fid_patches_per_image
    n_s = params.fid_style_patches or n_r
    styles = [resize_short_side(s, min(h, w)) for s in style_images]
    rng_r, rng_s = np.random.default_rng([params.seed, 1]), np.random.default_rng([params.seed, 2])
    p_r = random_patches(stylized, n_r, params.fid_patch_size, rng_r)
    p_s = random_patches(styles, n_s, params.fid_patch_size, rng_s)
    fid = kid_mean = kid_std = None
    kid_m = 0
    if params.fid:
        inception = inception or TFInception(batch=params.fid_batch, device=device)
        f_r, f_s = inception.features_of_sets([p_r, p_s], workers)
        fid = fid_from_features(f_s, f_r)
        kid_mean, kid_std, kid_m = kid(f_s, f_r, params.kid_subsets, params.kid_subset_size, params.seed)
    timings["fid_s"] = time.perf_counter() - t

    t = time.perf_counter()
    gram = GramDistance(vgg_state, [resize_to_height(s, params.gram_style_height) for s in style_images],
                        params.gram_layers, device=device)
    gram_per_view = ordered_map(gram.per_image, stylized, workers)
    timings["gram_s"] = time.perf_counter() - t

    # ArtFID: official only with real LPIPS and the art-trained Inception
    art_path, art_why = find_art_inception(params.art_inception_path)
    content_mean = _mean(content)
    components = {"content_distance": {"name": pname, "value": content_mean}}
    if not params.fid:
        components["style_distance"] = {"name": "fid_tf_inception", "value": None}
        art_key, art_val, art_note = "artfid_proxy", None, "not computed: evaluate.fid is false"
    elif art_path is not None and pname == "lpips":
        art = ArtInception(art_path, params.fid_batch, device)
        fid_art = fid_from_features(art.features(p_s), art.features(p_r))
        components["style_distance"] = {"name": "fid_art_inception", "value": fid_art, "network": art.provenance()}
        art_key, art_val = "artfid", artfid_formula(content_mean, fid_art)
        art_note = "official components (LPIPS-alex, art-trained Inception); FID on the same random patches as fid_tf_inception"
    else:
        components["style_distance"] = {"name": "fid_tf_inception", "value": fid}
        art_key, art_val = "artfid_proxy", artfid_formula(content_mean, fid)
        reasons = [r for r in ((None if pname == "lpips" else f"content distance is {pname}: {perceptual.note}"),
                               (None if art_path is not None else art_why)) if r]
        art_note = "proxy, NOT comparable to the paper's ArtFID: " + "; ".join(reasons)

    # per view: a pair (i, j) is attributed to view i (each view is the first of at most one pair of a kind)
    sp = {r.i: r for r in short_pairs}
    lp = {r.i: r for r in long_pairs}
    rows = []
    for i in range(n):
        s, lg = sp.get(i), lp.get(i)
        rows.append({
            "view": i, "name": names[i], "ssim": ssims[i], f"content_{pname}": content[i],
            "short_rmse": s.rmse if s else None, f"short_{pname}": s.perceptual if s else None,
            "short_pair": names[s.j] if s else None, "short_valid_fraction": s.valid_fraction if s else None,
            "long_rmse": lg.rmse if lg else None, f"long_{pname}": lg.perceptual if lg else None,
            "long_pair": names[lg.j] if lg else None, "long_valid_fraction": lg.valid_fraction if lg else None,
            "gram_distance": gram_per_view[i],
        })

    def pair_rows(results, kind: str) -> list[dict]:
        floor_of = {(i, j): r for i, j, r in floor[kind]["per_pair"]}
        return [{"view": names[r.i], "pair_view": names[r.j], "i": r.i, "j": r.j, "rmse": r.rmse,
                 pname: r.perceptual, "valid_fraction": r.valid_fraction, "rmse_floor": floor_of.get((r.i, r.j))}
                for r in results]

    shown = short_pairs if params.heatmap_pair == "short" else long_pairs
    pr = next((r for r in shown if r.i == params.heatmap_view), shown[min(params.heatmap_view, len(shown) - 1)])
    panel = heatmap_panel(originals[pr.i], stylized[pr.i], pr)
    captions = [f"original {names[pr.i]}", f"stylized {names[pr.i]}", f"stylized {names[pr.j]} warped",
                f"error (cyan: occluded) rmse {pr.rmse:.3f}"]

    metrics = {
        "n_views": n, "resolution": [int(w), int(h)],  # of the first view; views may differ (n_view_sizes)
        "ssim": _mean(ssims), "ssim_impl": ssim.provenance()["ssim_impl"],
        f"content_{pname}": content_mean,
        "short_rmse": short["rmse"], f"short_{pname}": short["perceptual"],
        "long_rmse": long["rmse"], f"long_{pname}": long["perceptual"],
        "short_rmse_floor": floor["short"]["rmse"], "long_rmse_floor": floor["long"]["rmse"],
        "pairs": pairs.mode, "short_term_gap": pairs.short_gap, "long_term_gap": pairs.long_gap,
        "short_valid_fraction": short["valid_fraction"], "long_valid_fraction": long["valid_fraction"],
        "consistency_pairs": {"mode": pairs.mode, "order": [names[k] for k in pairs.order],
                              "short": pair_rows(short_pairs, "short"), "long": pair_rows(long_pairs, "long")},
        "n_view_sizes": len({tuple(np.shape(o)[:2]) for o in originals}),
        "short_pairs_resampled": short["n_pairs_resampled"], "long_pairs_resampled": long["n_pairs_resampled"],
        "fid_tf_inception": fid, "kid_tf_inception": kid_mean, "kid_tf_inception_std": kid_std,
        "gram_distance": _mean(gram_per_view),
        art_key: art_val,
        "artfid_components": {**components, "note": art_note},
        "provenance": {
            "ssim": ssim.provenance(),
            "perceptual": perceptual.info,
            "flow": flows.provenance(),
            "occlusion": "forward-backward check |f_fw + f_bw(x+f_fw)|^2 < 0.01(|f_fw|^2+|f_bw|^2) + 0.5 (Sundaram et al. 2010) and target inside the frame",
            "fid_kid": {
                "inception": inception.provenance() if params.fid else "not computed: evaluate.fid is false",
                "n_stylized_patches": int(n_r), "n_style_patches": int(n_s), "n_style_images": len(style_images),
                "patch_size_px": int(p_r.shape[1]), "kid_subset_size": int(kid_m), "kid_subsets": params.kid_subsets,
                "protocol": "seeded random square crops resized to 299x299; style images first resized to the renders' short side; "
                            "FID with n << 2048 is biased upwards and depends on n; KID = unbiased MMD^2, cubic polynomial kernel",
            },
            "gram_distance": {**gram.info, "style_height": params.gram_style_height,
                              "vgg_weights": vgg_info.model_dump()},
            "seed": params.seed, "versions": _versions(),
        },
        "eval_timings_s": timings,
    }
    return EvalResult(metrics, rows, panel, captions)


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
    **kwargs,
) -> EvalResult:
    """Render both scenes for ``cameras`` (first ``params.max_views``), compute all metrics, time rendering.

    ``reference``: the original scene's stored renders and flows (the per-scene ``reference`` stage; see
    :mod:`abcgs.evaluation.reference`), used instead of rendering ``original`` and estimating flows here.
    """
    if params.num_threads is not None:
        old = torch.get_num_threads()
        torch.set_num_threads(params.num_threads)
        try:
            return _evaluate_scene(cameras, original, stylized, style_images, params, stylize_info=stylize_info,
                                   saved_renders=saved_renders, reference=reference, **kwargs)
        finally:
            torch.set_num_threads(old)
    return _evaluate_scene(cameras, original, stylized, style_images, params, stylize_info=stylize_info,
                           saved_renders=saved_renders, reference=reference, **kwargs)


def _evaluate_scene(cameras, original, stylized, style_images, params, *, stylize_info=None, saved_renders=None,
                    reference=None, **kwargs):
    cams = evaluated_cameras(cameras, params)
    t = time.perf_counter()
    if reference is not None:
        if reference.view_names != [c.name for c in cams]:
            raise InputError("the evaluation reference was made for other views; re-run the reference stage")
        originals, backend = reference.originals, reference.info.get("render_backend", "stored")
        kwargs.update(flows=reference.flow_cache(), pairs=reference.pairs, floor=reference.floor)
    else:
        originals, backend = render_views(original, cams, params.backend)
        kwargs.setdefault("pairs", pairs_for(cams, params))
    styl, backend_s = render_views(stylized, cams, params.backend)
    render_s = time.perf_counter() - t
    saved_rmse = None
    if saved_renders is not None:  # the stylize stage's PNGs must be these views (fail before the slow metrics)
        sr = saved_renders[: len(cams)]
        check_same_count(styl, sr, "re-rendered stylized views", "saved stylize renders")
        for k, (a, b) in enumerate(zip(styl, sr)):
            check_pair(a, b, f"re-rendered and saved stylized view {k}")
        saved_rmse = max(masked_rmse(a, b) for a, b in zip(styl, sr))
    fps, pass_times = render_fps(stylized, cams, params.backend, params.fps_passes)
    res = evaluate_images(originals, styl, style_images, params, view_names=[Path(c.name).stem for c in cams],
                          device=stylized.device, **kwargs)
    m = res.metrics
    m["render_fps"] = fps
    m["speed"] = {"render_fps": fps, "fps_passes_s": pass_times, "fps_views_per_pass": len(cams), "backend": backend_s,
                  "device": str(stylized.device), "resolution": m["resolution"],
                  "torch_threads": torch.get_num_threads(), "pair_workers": resolve_workers(params.workers)}
    if stylize_info is not None:
        m["stylize_seconds"] = stylize_info.get("stylize_seconds")
        m["stylize_minutes"] = stylize_info["stylize_seconds"] / 60.0 if stylize_info.get("stylize_seconds") is not None else None
        m["speed"].update({k: stylize_info.get(k) for k in ("stylize_seconds", "iterations", "seconds_per_iteration", "n_gaussians")})
    if saved_rmse is not None:
        m["saved_renders_rmse"] = saved_rmse  # re-render vs stylize's 8-bit PNGs: ~quantisation noise expected
    m["eval_timings_s"]["render_s"] = render_s
    m["provenance"]["render_backend"] = {"original": backend, "stylized": backend_s}
    if reference is not None:
        m["provenance"]["reference"] = {k: reference.info.get(k) for k in ("model_digest", "n_flows")}
    return res


def load_stylize_run(root: Path, name: str, view_stems: list[str]) -> tuple[Path, dict, list[Path]]:
    """The stylize stage's outputs for experiment ``name`` (PLY, record, one render per view in ``view_stems``'
    order), checked against the scene's views."""
    run = root / name
    ply, record, renders = run / "stylize" / "point_cloud.ply", run / "stylize.json", run / "stylize" / "renders"
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
    heat = result.heatmap
    save_image(record_path.with_name("eval_consistency.png"),
               image_grid([heat], result.heatmap_captions, height=max(160, heat[0].shape[0])))
    write_csv(record_path.with_name("eval_views.csv"), result.per_view)
    write_metrics(record_path, record)
    write_headline(headline_path, experiment_headline(result.metrics))
