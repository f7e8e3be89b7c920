"""The typed result of one evaluation (:class:`EvalResult`) and the one mapping from its fields to the record:
:func:`eval_record` (``eval.json`` / ``eval_info.json``) and :func:`view_rows` (``eval_views.csv``).

Key names say what a number is: ``lpips`` / ``artfid`` appear only when the official networks ran; offline they are
``lpips_proxy_vgg`` / ``artfid_proxy`` (:data:`PERCEPTUAL_KEYS`, :data:`ARTFID_KEY`); FID/KID are
``fid_tf_inception`` / ``kid_tf_inception`` (patch-based, TF-FID Inception). The metrics themselves are computed by
:mod:`abcgs.evaluation.evaluate`.
"""

from __future__ import annotations

import platform
from dataclasses import dataclass, field

import cv2
import numpy as np
import torch

from abcgs.evaluation.artfid import ArtFID
from abcgs.evaluation.consistency import (
    OCCLUSION_TEST,
    Consistency,
)
from abcgs.evaluation.content import (
    ContentScores,
    package_version,
)
from abcgs.evaluation.fid import PATCH_PROTOCOL, FidKid
from abcgs.evaluation.objects import ObjectScores
from abcgs.evaluation.pairs import ViewPairs
from abcgs.evaluation.reference import (
    SceneReference,
    WarpFloor,
)
from abcgs.evaluation.style_distance import GRAM_DEFINITION, GramScores


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
    cpu_s: dict[str, float] = field(default_factory=dict)
    """CPU seconds of the process (all its threads) in each part, by the same names (``content_s`` …): beside the wall
    seconds, how many cores the part had (about ``evaluate.workers`` × ``num_threads`` on an idle machine, less where
    others share it)."""


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
    scene_timings_s: dict[str, float] = field(default_factory=dict)
    """Seconds of :func:`evaluate_scene`'s own parts, wall and CPU: ``render_cpu_s``, ``speed_s`` / ``speed_cpu_s``
    (the render-speed passes), ``objects_s`` / ``objects_cpu_s``, ``total_s`` / ``total_cpu_s`` (the whole
    evaluation of the scene); empty for :func:`evaluate_images` alone."""

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
                           "fid_s": ev.timings.fid_s, "gram_s": ev.timings.gram_s,
                           **{f"{k.removesuffix('_s')}_cpu_s": v for k, v in ev.timings.cpu_s.items()}},
    }
    if res.render_backends is not None:
        record["provenance"]["render_backend"] = {"original": res.render_backends[0], "stylized": res.render_backends[1]}
    if res.reference is not None:
        record["provenance"]["reference"] = {"model_digest": res.reference.model_digest,
                                             "n_flows": res.reference.n_flows}
    if res.render_s is not None:
        record["eval_timings_s"]["render_s"] = res.render_s
    record["eval_timings_s"].update(res.scene_timings_s)
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
