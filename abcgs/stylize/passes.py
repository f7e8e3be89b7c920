"""The two optimisation passes of the stylization: the main pass of Eq. 8 over random views (:func:`style_pass`)
and the authors' colour pass (:func:`color_pass`): the re-rendered views colour-matched to the style again and the
colours and rotations re-fitted to them with ``0.8·L1 + 0.2·D-SSIM``.

Shapes: renders ``(H, W, 3)``; VGG features ``(C, h, w)``; per-group features ``(C, N)``.
"""

from __future__ import annotations

import time

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from abcgs.errors import NumericalError
from abcgs.features.knn import StyleFeatures
from abcgs.features.vgg import VGG16Features
from abcgs.fit.adam import Adam
from abcgs.fit.losses import reconstruction_loss
from abcgs.gaussians import GaussianModel, freeze_gaussians, render, render_each
from abcgs.losses.drift import opacity_drift, scale_drift
from abcgs.losses.terms import background_loss, content_loss, silhouette_loss, structure_loss, style_loss, tv_loss
from abcgs.progress import progress as progress_bar
from abcgs.stylize.color import apply_group_transforms, color_match_model
from abcgs.stylize.params import StyleWeights, StylizeParams
from abcgs.stylize.records import LoggedStep, PassLog
from abcgs.stylize.replay import ReplayedViews, can_replay
from abcgs.stylize.sh_bands import higher_sh_lr, keep_bands_above_1_zero, render_sh_degree
from abcgs.stylize.targets import Backdrop, ViewTargets, group_features, view_features
from abcgs.types import MatchingGroup, StyleMethod


def _optimizer(model: GaussianModel, lrs: dict[str, float]) -> Adam:
    """Adam (eps 1e-15, as 3DGS) over the fields with a positive learning rate; the others are frozen. The fused
    kernel: one pass over each field per step (3 M Gaussians: 0.06 s a step on two cores, where the per-tensor loop
    takes 0.5 s; the same update up to rounding)."""
    groups = []
    for name, lr in lrs.items():
        tensor = getattr(model, name)
        if lr > 0:
            groups.append({"params": [tensor], "lr": lr})
        else:
            tensor.requires_grad_(False)
    return Adam(groups, eps=1e-15, mode="fused" if model.device.type in ("cpu", "cuda") else "per_tensor")


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
    """Eq. 8's terms of one view besides the style: content (VGG features), structure (the luminance gradients of the
    render ``(H, W, 3)`` and of the content image), TV (the render), depth (``(H, W, 1)``, when rendered), each
    weighted by its λ, or by the view's λ map of a term whose content labels have their own (:class:`~abcgs.stylize.targets.LabelWeights`);
    a term whose λ is 0 everywhere is left out."""
    terms = {}
    if target.content_weight is not None:
        if bool((target.content_weight > 0).any()):
            terms["content"] = content_loss(feats, target.content_feats, target.content_weight)
    elif w.content > 0:
        terms["content"] = w.content * content_loss(feats, target.content_feats)
    if target.structure_weight is not None:
        if bool((target.structure_weight > 0).any()):
            terms["structure"] = structure_loss(img, target.content_image, target.structure_weight)
    elif w.structure > 0:
        terms["structure"] = w.structure * structure_loss(img, target.content_image)
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
    backdrop: Backdrop = Backdrop(None),  # noqa: B008 (a frozen dataclass)
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
        feats = view_features(vgg, img, params)
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
    params: StylizeParams, backdrop: Backdrop = Backdrop(None),  # noqa: B008 (a frozen dataclass)
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
    backdrop: Backdrop = Backdrop(None),  # noqa: B008 (a frozen dataclass)
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
