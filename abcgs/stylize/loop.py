"""The ABC-GS stylization stage: optimise the colour-matched Gaussians with

    L = λ_FAST·L_style + λ_c·L_con + λ_tv·L_tv + λ_dep·L_dep + λ_sca·‖Δs‖ + λ_opa·‖Δα‖

(paper λ = {2, 0.005, 0.02, 0.01, 1, 1}, densification off), optionally followed by the authors'
post-process ("colour pass"): re-render every view, colour-match the renders to the style again, and
re-fit colours and rotations (xyz, scales, opacities frozen) to those images with the reconstruction
loss ``0.8·L1 + 0.2·D-SSIM`` (vpx-ecnu/ABC-GS ``abcgs/phases/post_process_phase.py``). ``L_style`` is
FAST (ABC-GS) or a baseline (NNFM, KNNFM, Gram) chosen by one parameter.

Shapes: renders ``(H, W, 3)``; VGG features ``(C, h, w)`` at 1/4 of the (×0.5 downsampled) render;
per-group features ``(C, N)``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from typing import Literal

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from abcgs.cameras import Camera
from abcgs.errors import InputError, NumericalError
from abcgs.features import knn
from abcgs.features.isolation import downsample_mask
from abcgs.features.knn import StyleFeatures
from abcgs.features.params import ALL_PIXELS
from abcgs.features.vgg import VGG16Features, downsample_half, extract_features
from abcgs.fit.losses import reconstruction_loss
from abcgs.gaussians import GaussianModel, fitted_rows, freeze_gaussians, render, render_each
from abcgs.losses.drift import opacity_drift, scale_drift
from abcgs.losses.fast import FastStats
from abcgs.losses.params import FastParams
from abcgs.losses.terms import background_loss, content_loss, silhouette_loss, style_loss, tv_loss
from abcgs.progress import progress as progress_bar
from abcgs.render import rgb_to_sh0, sh0_to_rgb
from abcgs.runtime import release_free_memory
from abcgs.silhouette import Silhouette, background_tensor, object_gaussians
from abcgs.stylize.color import apply_group_transforms, fit_color_transform, preserve_color
from abcgs.stylize.params import StyleWeights, StylizeParams
from abcgs.stylize.replay import ReplayedViews, can_replay
from abcgs.stylize.schedule import choose_schedule
from abcgs.stylize.sh_bands import higher_sh_lr, keep_bands_above_1_zero, render_sh_degree, with_higher_sh
from abcgs.types import FRAME_FILLING, Background, MatchingGroup, SceneMasks, StyleMethod

log = logging.getLogger(__name__)


TIMED_PARTS = ("render", "vgg", "style_loss", "backward", "step")
"""The parts of a main-pass step timed in ``stylize.json``'s ``seconds_per_iteration``."""


@dataclass(frozen=True)
class LoggedStep:
    """One logged step of a stylization pass: a row of ``stylize_history.csv``."""

    step: int
    """The step number; the colour pass counts on from the main pass's ``iterations``."""
    seconds: float
    """Wall seconds since the pass began."""
    pass_name: Literal["main", "color"]
    loss: float
    """The step's total loss."""
    terms: dict[str, float]
    """Each loss term as it is added to ``loss`` (weighted by its λ): in the main pass those switched on of style,
    content, tv, depth, scale, opacity; in the colour pass the reconstruction's ``l1``."""

    def row(self) -> dict[str, float | int | str]:
        """The step as a table row: ``step``, ``seconds``, ``loss``, ``pass`` and the terms."""
        return {"step": self.step, "seconds": self.seconds, "loss": self.loss, "pass": self.pass_name, **self.terms}


@dataclass
class PassLog:
    """What the main pass records besides the model."""

    steps: list[LoggedStep] = field(default_factory=list)
    """Every ``stylize.compute.log_every``-th step and the last."""
    timings: dict[str, float] = field(default_factory=dict)
    """Wall seconds per part of a step (:data:`TIMED_PARTS`) summed over the steps, and ``iterations`` (the count)."""
    fast: FastStats = field(default_factory=FastStats)
    """The FAST solves' counters."""

    def add_step_times(self, ticks: list[float]) -> None:
        """Add one step's ``perf_counter`` readings at the bounds of :data:`TIMED_PARTS` to :attr:`timings`."""
        for key, t_begin, t_end in zip(TIMED_PARTS, ticks, ticks[1:]):
            self.timings[key] = self.timings.get(key, 0.0) + (t_end - t_begin)
        self.timings["iterations"] = self.timings.get("iterations", 0) + 1


@dataclass
class StylizeResult:
    """A stylization run: the stylized model and what it logged (``stylize_history.csv``, ``stylize.json``)."""

    model: GaussianModel
    history: list[LoggedStep]
    """The logged steps of the main pass, then of the colour pass."""
    timings: dict[str, float]
    fast_stats: dict
    seconds: float
    color_pass_seconds: float = 0.0
    projected_search: dict | None = None
    color_timings: dict[str, float] = field(default_factory=dict)
    """The colour pass's split (:func:`color_pass`)."""
    schedule: dict | None = None
    """The step counts run and why (:meth:`abcgs.stylize.schedule.Schedule.to_dict`)."""

    def record(self) -> dict:
        """The run's numbers for ``stylize.json``: wall time, per-iteration timings, FAST counters, size."""
        n_it = max(1, int(self.timings.get("iterations", 1)))
        return {
            "stylize_seconds": self.seconds, "iterations": int(self.timings.get("iterations", 0)),
            "seconds_per_iteration": {k: v / n_it for k, v in self.timings.items() if k != "iterations"},
            "fast": self.fast_stats, "n_gaussians": self.model.num_gaussians,
            "projected_search": self.projected_search, "schedule": self.schedule,
        }


@dataclass
class ViewTargets:
    """Per-view fixed targets: content features, original depth, per-group feature masks."""

    camera: Camera
    content_feats: Tensor  # (C, h, w)
    depth: Tensor  # (H, W, 1)
    group_masks: list[Tensor] = field(default_factory=list)  # per group (h, w) bool; object pixels only (object scene)
    content_image: Tensor | None = None  # (H, W, 3) the colour-matched render
    silhouette: Silhouette | None = None  # object scenes: the original scene's alpha in this view


@dataclass(frozen=True)
class Backdrop:
    """How the loop composites and what it holds: the scene's :class:`~abcgs.types.Background`, as a tensor.

    ``color`` ``(3,)`` is composited behind every render of an object scene; ``None`` for a frame-filling scene,
    which renders as it always has (on black, no silhouette or background terms). ``gaussians`` ``(N,)`` bool: an
    object scene's object (:func:`abcgs.silhouette.object_gaussians`), the only Gaussians that change."""

    color: Tensor | None
    gaussians: Tensor | None = None

    @classmethod
    def of(cls, background: Background, device: torch.device) -> Backdrop:
        return cls(background_tensor(background).to(device) if background.object else None)

    @property
    def object(self) -> bool:
        return self.color is not None


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


def group_pixel_masks(groups: list[MatchingGroup], label_map: np.ndarray) -> list[np.ndarray]:
    """Per group, the ``(H, W)`` bool pixels it covers in one view's (rendered) label map."""
    return [np.ones_like(label_map, bool) if g.content_label == ALL_PIXELS else label_map == g.content_label for g in groups]


def _features(vgg: VGG16Features, img_hw3: Tensor, params: StylizeParams) -> Tensor:
    x = img_hw3.permute(2, 0, 1)[None]
    if params.downsample_render:
        x = downsample_half(x)
    return extract_features(vgg, x, params.layers)[0]


def prepare_targets(
    model_content: GaussianModel,
    model_original: GaussianModel,
    cameras: list[Camera],
    label_maps: list[np.ndarray],
    groups: list[MatchingGroup],
    vgg: VGG16Features,
    params: StylizeParams,
    backdrop: Backdrop = Backdrop(None),
) -> list[ViewTargets]:
    """Content features (from the colour-matched scene), depth (from the original scene), group masks; for an object
    scene (``backdrop``) also the original scene's silhouette, and the group masks keep its object pixels only."""
    targets = []
    backend = params.compute.backend
    with torch.no_grad():
        # one render gives both when the depth comes from the content scene itself
        same = model_original is model_content
        contents = render_each(model_content, cameras, backend=backend, background=backdrop.color,
                               render_mode="RGB+D" if same else "RGB")
        originals = None if same else render_each(model_original, cameras, backend=backend, render_mode="RGB+D")
        for cam, lab, (img, alpha, meta) in zip(cameras, label_maps, contents):
            if originals is not None:
                _, alpha, meta = next(originals)
            feats = _features(vgg, img.clamp(0, 1), params)
            hw = tuple(feats.shape[-2:])
            pixel_masks = group_pixel_masks(groups, lab)
            sil = None
            if backdrop.object:
                sil = Silhouette(alpha.float())
                on_object = sil.object.numpy(force=True)
                pixel_masks = [m & on_object for m in pixel_masks]
            masks = [downsample_mask(m, hw).to(feats.device) if m.any() else torch.zeros(hw, dtype=torch.bool, device=feats.device)
                     for m in pixel_masks]
            targets.append(ViewTargets(cam, feats, meta.depth, masks, img, sil))
    return targets


def group_features(feats: Tensor, mask: Tensor) -> Tensor:
    """The ``(C, n)`` columns of ``feats`` ``(C, h, w)`` under ``mask`` ``(h, w)`` bool, in row-major order: a view of
    all columns when the mask covers every cell (single-image transfer), so that neither the forward nor the backward
    copies the features through the mask."""
    return feats.flatten(1) if bool(mask.all()) else feats[:, mask]


def _optimizer(model: GaussianModel, lrs: dict[str, float]) -> torch.optim.Adam:
    """Adam (eps 1e-15, as 3DGS) over the fields with a positive learning rate; the others are frozen. torch's
    fused implementation: one pass over each field per step (3 M Gaussians: 0.06 s a step on two cores, where the
    per-tensor loop takes 0.5 s; the same update up to rounding)."""
    groups = []
    for name, lr in lrs.items():
        tensor = getattr(model, name)
        if lr > 0:
            groups.append({"params": [tensor], "lr": lr})
        else:
            tensor.requires_grad_(False)
    return torch.optim.Adam(groups, eps=1e-15, fused=bool(groups) and model.device.type in ("cpu", "cuda"))


def main_pass_lrs(params: StylizeParams) -> dict[str, float]:
    """Learning rate per :class:`GaussianModel` field in the main pass (geometry 0 unless ``optim.optimize_geometry``,
    and never with ``color_only``)."""
    o = params.optim
    geo = o.optimize_geometry and not params.color_only
    return {"sh0": o.lr_sh0, "means": o.lr_means if geo else 0.0, "log_scales": o.lr_scales if geo else 0.0,
            "opacity_logits": o.lr_opacity if geo else 0.0, "quats": o.lr_quats if geo else 0.0}


def _check_finite(value: Tensor, name: str, step: int) -> None:
    if not torch.isfinite(value):
        raise NumericalError(
            f"stylization loss term {name} became {value.item()} at step {step}; lower the learning rates or "
            "λ of that term, or check the inputs (style image, masks)"
        )


@torch.no_grad()
def _renormalize_quats(model: GaussianModel, rows: Tensor | None = None) -> None:
    """Project the rotations back onto unit quaternions after an optimiser step (in place); only ``rows`` ``(N,)``
    bool when given (the Gaussians that may change: an object scene's object)."""
    q = model.quats.data
    norm = torch.linalg.vector_norm(q, dim=-1, keepdim=True).clamp_min_(1e-12)
    q.div_(norm if rows is None else torch.where(rows[:, None], norm, 1.0))  # in place: no (N, 4) temporaries


def _random_views(n: int, seed: int):
    """Endless view indices: a seeded random permutation of ``range(n)``, drawn again when used up."""
    gen = torch.Generator().manual_seed(seed)
    while True:
        yield from torch.randperm(n, generator=gen).tolist()


def _object_terms(img: Tensor, alpha: Tensor, target: ViewTargets, w: StyleWeights, backdrop: Backdrop,
                  lrs: dict[str, float]) -> dict[str, Tensor]:
    """An object scene's hold on its shape and its empty space, weighted: ``silhouette`` (alpha ``(H, W, 1)`` against
    the original's, when opacities or scales move) and ``background`` (the render ``(H, W, 3)`` on the empty pixels);
    nothing for a frame-filling scene."""
    if not backdrop.object or target.silhouette is None:
        return {}
    terms = {}
    if w.silhouette > 0 and (lrs["opacity_logits"] > 0 or lrs["log_scales"] > 0 or lrs["means"] > 0):
        terms["silhouette"] = w.silhouette * silhouette_loss(alpha, target.silhouette.alpha)
    if w.background > 0:
        terms["background"] = w.background * background_loss(img, backdrop.color, target.silhouette.empty)
    return terms


def _view_terms(img: Tensor, depth: Tensor | None, feats: Tensor, target: ViewTargets, w: StyleWeights) -> dict[str, Tensor]:
    """Eq. 8's terms of one view besides the style: content (VGG features), TV (the render ``(H, W, 3)``), depth
    (``(H, W, 1)``, when rendered), each weighted by its λ; a term whose λ is 0 is left out."""
    terms = {}
    if w.content > 0:
        terms["content"] = w.content * content_loss(feats, target.content_feats)
    if w.tv > 0:
        terms["tv"] = w.tv * tv_loss(img.permute(2, 0, 1)[None])
    if w.depth > 0 and depth is not None:
        terms["depth"] = w.depth * F.mse_loss(depth, target.depth)
    return terms


def _drift_terms(m: GaussianModel, start: GaussianModel, w: StyleWeights,
                 lrs: dict[str, float]) -> dict[str, Tensor]:
    """Eq. 8's geometry terms: mean ‖Δ scale‖ and mean |Δ opacity| from the ``start`` model, weighted, for the optimised
    fields (:mod:`abcgs.losses.drift`)."""
    terms = {}
    if w.scale > 0 and lrs["log_scales"] > 0:
        terms["scale"] = w.scale * scale_drift(m.log_scales, start.log_scales)
    if w.opacity > 0 and lrs["opacity_logits"] > 0:
        terms["opacity"] = w.opacity * opacity_drift(m.opacity_logits, start.opacity_logits)
    return terms


def style_pass(
    model: GaussianModel,
    targets: list[ViewTargets],
    groups: list[MatchingGroup],
    vgg: VGG16Features,
    params: StylizeParams,
    *,
    iterations: int,
    method: StyleMethod = "fast",
    progress: bool = True,
    backdrop: Backdrop = Backdrop(None),
) -> tuple[GaussianModel, PassLog]:
    """The main stylization pass over random views: the optimised (detached) model and the pass's log. An object
    scene (``backdrop``) renders on its background and adds :func:`_object_terms`."""
    lrs = main_pass_lrs(params) | {"shN": higher_sh_lr(params, model)}
    m = model.as_parameters(trainable=[k for k, lr in lrs.items() if lr > 0])
    opt = _optimizer(m, lrs)
    keep_bands_above_1_zero(m, params)
    views = _random_views(len(targets), params.seed)
    style_feats = [StyleFeatures.of(g.features) for g in groups]  # fixed for the run: prepared once
    w, fast, backend, log_every = params.weights, params.fast, params.compute.backend, params.compute.log_every
    freeze_gaussians(m, None if backdrop.gaussians is None else ~backdrop.gaussians)
    degree = render_sh_degree(m, lrs)
    record = PassLog()
    bar = progress_bar(range(iterations), "stylize", enabled=progress)
    t_start = time.perf_counter()
    for step in bar:
        tgt = targets[next(views)]
        ticks = [time.perf_counter()]
        imgs, alphas, meta = render(m, [tgt.camera], backend=backend, background=backdrop.color, sh_degree=degree,
                                    render_mode="RGB+D" if w.depth > 0 else "RGB")  # the step's batch: one view
        img, alpha, meta = imgs[0], alphas[0], meta.view(0)
        ticks.append(time.perf_counter())
        feats = _features(vgg, img, params)
        ticks.append(time.perf_counter())
        pairs = [(group_features(feats, mask), fs) for mask, fs in zip(tgt.group_masks, style_feats) if bool(mask.any())]
        terms: dict[str, Tensor] = {}
        if pairs and w.style > 0:
            terms["style"] = w.style * style_loss(method, pairs, k=fast.k, fast_params=fast, stats=record.fast,
                                                  max_block_elems=fast.max_block_elems)
        ticks.append(time.perf_counter())
        terms |= _view_terms(img, meta.depth, feats, tgt, w)
        terms |= _drift_terms(m, model, w, lrs)  # model: the start (the pass trains copies)
        terms |= _object_terms(img, alpha, tgt, w, backdrop, lrs)
        loss = torch.stack(list(terms.values())).sum()
        if not torch.isfinite(loss):  # one device-to-host read per step; then name the culprit
            for name, value in terms.items():
                _check_finite(value, name, step)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        ticks.append(time.perf_counter())
        opt.step()
        if lrs["quats"] > 0:
            _renormalize_quats(m, backdrop.gaussians)
        ticks.append(time.perf_counter())
        record.add_step_times(ticks)
        if step % log_every == 0 or step == iterations - 1:
            values = {k: float(v.detach()) for k, v in terms.items()}
            record.steps.append(LoggedStep(step, time.perf_counter() - t_start, "main", float(loss.detach()), values))
            bar.set_postfix({k: f"{v:.4f}" for k, v in values.items()}, refresh=False)
    bar.close()
    return m.released(), record


def _recolored_targets(
    model: GaussianModel, gaussian_labels: Tensor, targets: list[ViewTargets], groups: list[MatchingGroup],
    params: StylizeParams, backdrop: Backdrop = Backdrop(None),
) -> tuple[GaussianModel, list[Tensor]]:
    """The colour pass's start and targets: every view rendered, each group colour-matched to its style again on the
    pixels it covers that the scene covers (alpha > 0.5; an object scene: its original object pixels), the same
    transforms applied to the group's Gaussians."""
    with torch.no_grad():
        outs = list(render_each(model, [t.camera for t in targets], backend=params.compute.backend,
                                background=backdrop.color))
    renders = [o[0].clamp(0, 1) for o in outs]
    pix: dict[int, list[Tensor]] = {g.content_label: [] for g in groups}
    full_masks = []
    for t, img, (_, alpha, _) in zip(targets, renders, outs):
        h, w = img.shape[:2]
        # pixels the scene covers (alpha > 0.5): the background is neither measured nor recoloured
        covered = t.silhouette.object if t.silhouette is not None else alpha.reshape(h, w) > 0.5
        masks = [(F.interpolate(m[None, None].float(), size=(h, w), mode="nearest")[0, 0] > 0.5) & covered
                 for m in t.group_masks]
        full_masks.append(masks)
        for g, m in zip(groups, masks):
            pix[g.content_label].append(img[m])
    content = {k: torch.cat(v).numpy(force=True) if v else np.zeros((0, 3), np.float32) for k, v in pix.items()}
    recolored, transforms = color_match_model(model, gaussian_labels, groups, content,
                                              zero_higher_sh=params.higher_sh == "zero", gaussians=backdrop.gaussians)
    per_group = [transforms[g.content_label] for g in groups]
    images = [apply_group_transforms(img, masks, per_group, clip=(0.0, 1.0)) for img, masks in zip(renders, full_masks)]
    return recolored, images


def color_pass(
    model: GaussianModel,
    gaussian_labels: Tensor,
    targets: list[ViewTargets],
    groups: list[MatchingGroup],
    params: StylizeParams,
    *,
    iterations: int,
    start_step: int = 0,
    progress: bool = True,
    backdrop: Backdrop = Backdrop(None),
) -> tuple[GaussianModel, list[LoggedStep], dict[str, float]]:
    """The authors' post-process: colour-match the re-rendered views to the style again, then re-fit.

    Every view is rendered, each group's covered pixels (alpha > 0.5) get the mean/covariance colour transform to its style
    region (the transform is applied to the group's Gaussians too, as in the colour-match stage), and the
    DC colours and rotations are re-fitted to those images with ``0.8·L1 + 0.2·D-SSIM`` while means,
    scales and opacities stay frozen (``post_process_phase.py`` freezes ``_xyz``, ``_scaling``, ``_opacity``;
    ``color_only`` or ``optim.color_pass_rotations: false`` freeze the rotations too, and then each view's
    blending map is recorded once and replayed: :mod:`abcgs.stylize.replay`). An object scene (``backdrop``)
    renders on its background, so its empty pixels are fitted to it. Returns the re-fitted (detached) model and the logged steps, numbered from
    ``start_step``.
    """
    t_prepare = time.perf_counter()
    recolored, images = _recolored_targets(model, gaussian_labels, targets, groups, params, backdrop)
    lr_quats = params.optim.lr_quats if params.optim.color_pass_rotations and not params.color_only else 0.0
    lrs = {"sh0": params.optim.lr_sh0, "quats": lr_quats, "means": 0.0, "log_scales": 0.0, "opacity_logits": 0.0,
           "shN": higher_sh_lr(params, recolored)}
    m = recolored.as_parameters(trainable=[k for k, lr in lrs.items() if lr > 0])
    del recolored
    opt = _optimizer(m, lrs)
    keep_bands_above_1_zero(m, params)
    replay = ReplayedViews(m, [t.camera for t in targets], params.compute.backend) if can_replay(
        m, params.compute.backend, lrs) else None
    freeze_gaussians(m, None if backdrop.gaussians is None else ~backdrop.gaussians)
    degree = render_sh_degree(m, lrs)
    views = _random_views(len(targets), params.seed + 1)
    steps: list[LoggedStep] = []
    bar = progress_bar(range(iterations), "colour pass", enabled=progress)
    t_start = time.perf_counter()
    timings = {"prepare_s": t_start - t_prepare, "record_steps": 0, "record_s": 0.0, "steps": 0, "steps_s": 0.0}
    for it in bar:
        i = next(views)
        t_step, records = time.perf_counter(), replay is not None and i not in replay.views
        if replay is not None:
            img = replay.render(i, backdrop.color)
        else:
            img = render(m, [targets[i].camera], backend=params.compute.backend, background=backdrop.color,
                         sh_degree=degree)[0][0]
        terms = reconstruction_loss(img, images[i])
        _check_finite(terms.total, "colour-pass reconstruction", start_step + it)
        opt.zero_grad(set_to_none=True)
        terms.total.backward()
        opt.step()
        if lr_quats > 0:
            _renormalize_quats(m, backdrop.gaussians)
        prefix = "record_" if records else ""
        timings[prefix + "steps"] += 1
        timings[prefix + "s" if records else "steps_s"] += time.perf_counter() - t_step
        if it % params.compute.log_every == 0 or it == iterations - 1:
            steps.append(LoggedStep(start_step + it, time.perf_counter() - t_start, "color", float(terms.total.detach()),
                                    {"l1": float(terms.l1.detach())}))
    bar.close()
    return m.released(), steps, timings


def stylize(
    model: GaussianModel,
    cameras: list[Camera],
    label_maps: list[np.ndarray],
    gaussian_labels: Tensor,
    groups: list[MatchingGroup],
    vgg: VGG16Features,
    params: StylizeParams,
    *,
    method: StyleMethod = "fast",
    progress: bool = True,
    depth_model: GaussianModel | None = None,
    background: Background = FRAME_FILLING,
) -> StylizeResult:
    """Run the stylization passes on a (colour-matched) model.

    Args:
        model: the colour-matched, re-fitted scene (the content target and the starting point); its Gaussians map
            onto ``depth_model``'s by their :func:`~abcgs.gaussians.fitted_rows`.
        cameras: the views to stylize from.
        label_maps: per view ``(H, W)`` rendered content labels (ignored by single transfer).
        gaussian_labels: ``(N,)`` lifted content label of each of ``model``'s Gaussians (for the colour pass).
        depth_model: the original (pre-colour-match) scene whose depth the depth loss keeps (paper: "we use
            the original Gaussians to render the initial depth map"); default ``model``.
        groups: matching groups with style features (:func:`abcgs.features.matching.build_groups`).
        background: the scene's; an object scene renders on its colour, styles its object pixels only and holds its
            silhouette and empty space (:mod:`abcgs.silhouette`).
    """
    if not cameras:
        raise InputError("stylize: no views")
    if method == "none":  # the colour-matched start itself: the baseline that stylizes nothing
        return StylizeResult(model.detach(), [], {"iterations": 0}, {}, 0.0)
    torch.manual_seed(params.seed)
    t0 = time.perf_counter()
    backdrop = Backdrop.of(background, model.device)
    targets = prepare_targets(model, depth_model or model, cameras, label_maps, groups, vgg, params, backdrop)
    if backdrop.object:  # the original's object Gaussians, mapped onto the re-fitted rows
        objects = object_gaussians(depth_model or model, cameras, [t.silhouette for t in targets],
                                   params.compute.backend)
        backdrop = replace(backdrop, gaussians=objects if depth_model is None else objects[fitted_rows(model)])
    for g, z in enumerate(groups):
        if not any(bool(t.group_masks[g].any()) for t in targets):
            raise InputError(f"matching group for content label {z.content_label} covers no pixel in any view")
    schedule = choose_schedule(cameras, main=params.optim.iterations, color_pass=params.optim.color_pass_iterations)
    n_main, n_color = schedule.steps["main"], schedule.steps["color_pass"]
    styled, main = style_pass(model, targets, groups, vgg, params, iterations=n_main, method=method, progress=progress,
                              backdrop=backdrop)
    release_free_memory()  # the pass's freed tensors, kept by the allocator between its steps (runtime.setup)
    history = list(main.steps)
    t_cp, color_timings = time.perf_counter(), {}
    if n_color > 0:
        styled, color_steps, color_timings = color_pass(styled, gaussian_labels, targets, groups, params,
                                                        iterations=n_color, start_step=n_main, progress=progress,
                                                        backdrop=backdrop)
        history += color_steps
    t_cp = time.perf_counter() - t_cp
    if params.preserve_color:
        styled = recolor_to_content(styled, model)
    release_free_memory()
    return StylizeResult(styled, history, main.timings, main.fast.as_dict(), time.perf_counter() - t0, t_cp,
                         color_timings=color_timings, schedule=schedule.to_dict())


def stylize_scene(
    matched: GaussianModel,
    original: GaussianModel,
    cameras: list[Camera],
    masks: SceneMasks,
    groups: list[MatchingGroup],
    vgg: VGG16Features,
    params: StylizeParams,
    *,
    method: StyleMethod = "fast",
    background: Background = FRAME_FILLING,
) -> StylizeResult:
    """:func:`stylize` a colour-matched scene at ``params.resolution_scale`` of its views' size (label maps resized
    with nearest neighbours), keeping the depth of the ``original`` scene; ``background``: the scene's."""
    cams, labels = cameras, masks.view_labels
    if params.resolution_scale != 1.0:
        cams = [c.scaled(params.resolution_scale) for c in cameras]
        labels = [cv2.resize(v.astype(np.int32), (c.width, c.height), interpolation=cv2.INTER_NEAREST).astype(np.int64)
                  for v, c in zip(labels, cams)]
    res = stylize(with_higher_sh(matched, original, params.higher_sh), cams, labels, masks.gaussian_labels, groups,
                  vgg, params, method=method, depth_model=original, background=background)
    res.projected_search = projected_search_record(params.fast)
    return res


def projected_search_record(fast_params: FastParams) -> dict | None:
    """The approximate neighbour search as it runs here (``projection_products: auto`` resolved on this CPU), or
    None when it is off; it applies to CPU searches of at least ``min_similarities`` only."""
    proj = knn.projection_of(fast_params)
    if proj is None:
        return None
    return {"rank": proj.rank, "candidates": proj.candidates, "min_similarities": proj.min_similarities,
            "products": "bfloat16" if proj.bf16_products() else "float32"}


def recolor_to_content(styled: GaussianModel, content: GaussianModel) -> GaussianModel:
    """``preserve_color``: keep the stylised luminance, take chroma from the content colours (YIQ)."""
    out = styled.detach()
    rgb = preserve_color(sh0_to_rgb(styled.sh0[:, 0, :]), sh0_to_rgb(content.sh0[:, 0, :]))
    out.sh0 = rgb_to_sh0(rgb)[:, None, :].contiguous()
    return out
