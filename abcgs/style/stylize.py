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
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field, model_validator
from torch import Tensor

from abcgs.cameras import Camera
from abcgs.errors import InputError, NumericalError
from abcgs.fit.losses import reconstruction_loss
from abcgs.gaussians import GaussianModel, render
from abcgs.progress import progress as progress_bar
from abcgs.render import rgb_to_sh0, sh0_to_rgb
from abcgs.style.color import apply_color_transform, fit_color_transform, preserve_color
from abcgs.style.fast import FastParams, FastStats
from abcgs.style.isolation import downsample_mask
from abcgs.style.knn import StyleFeatures
from abcgs.style.losses import content_loss, style_loss, tv_loss
from abcgs.style.matching import ALL_PIXELS, MatchingGroup
from abcgs.style.vgg import VGG16Features, downsample_half, extract_features

log = logging.getLogger(__name__)


LR_PRESETS: dict[str, dict[str, float]] = {
    # this project's first rates (colour 4× INRIA's, geometry 5× slower, means free); the default until the
    # quality study measured both on three paintings (docs/FIDELITY.md "The authors' learning rates")
    "ours": {"lr_sh0": 0.01, "lr_means": 1.6e-5, "lr_scales": 1e-3, "lr_opacity": 1e-2, "lr_quats": 1e-3},
    # INRIA 3DGS ``training_setup`` as the authors' StyleTrainer uses it: f_dc 0.0025, opacity 0.05, scaling 0.005,
    # rotation 0.001; xyz 1.6e-4 × spatial_lr_scale, which stays 0 for a GaussianModel loaded from a PLY → frozen.
    "authors_code": {"lr_sh0": 0.0025, "lr_means": 0.0, "lr_scales": 5e-3, "lr_opacity": 5e-2, "lr_quats": 1e-3},
}
"""Learning-rate presets of the stylization optimiser (Adam, eps 1e-15), per parameter group."""


class StylizeParams(BaseModel):
    """``params.yaml``: ``stylize``."""

    model_config = ConfigDict(extra="forbid")

    iterations: int = Field(300, ge=0, description="main pass (authors: 600 on LLFF; 300 is the schedule every "
                            "measurement in docs/FIDELITY.md used)")
    color_pass_iterations: int = Field(
        200, ge=0, description="authors' post-process after the main pass: re-render, colour-match again, re-fit colours "
        "and rotations with L1 + D-SSIM (authors: 400; 200 measured on fern: Gram distance 0.315 → 0.267, "
        "docs/FIDELITY.md); 0 turns it off")
    lambda_style: float = Field(2.0, ge=0, description="λ_FAST: stylization strength")
    lambda_content: float = Field(
        0.0005, ge=0, description="λ_c: content preservation (paper 0.005; with the Keras/Oxford VGG features here "
        "that value pins the colour-matched start, see docs/FIDELITY.md 'λ balance')")
    lambda_tv: float = Field(0.02, ge=0)
    lambda_depth: float = Field(0.01, ge=0)
    lambda_scale: float = Field(1.0, ge=0)
    lambda_opacity: float = Field(1.0, ge=0)
    fast: FastParams = Field(default_factory=FastParams)
    layers: list[str] = Field(default_factory=lambda: ["relu3_1", "relu3_2", "relu3_3"])
    downsample_render: bool = Field(True, description="render ×0.5 before VGG (authors' code)")
    style_height: int = Field(256, ge=16, description="style images are resized to this height")
    resolution_scale: float = Field(1.0, gt=0, le=1.0, description="stylize at this fraction of the view size")
    lr_preset: Literal["authors_code", "ours"] = Field(
        "authors_code", description="learning rates: 'authors_code' (INRIA's training_setup rates with xyz frozen, as "
        "the authors' code runs; the default, measured on fern × 3 paintings: docs/FIDELITY.md) or 'ours' (this "
        "project's first rates, see LR_PRESETS); an explicit lr_* key overrides its preset value")
    lr_sh0: float = Field(LR_PRESETS["authors_code"]["lr_sh0"], ge=0)
    lr_means: float = Field(LR_PRESETS["authors_code"]["lr_means"], ge=0, description="0 freezes the means")
    lr_scales: float = Field(LR_PRESETS["authors_code"]["lr_scales"], ge=0)
    lr_opacity: float = Field(LR_PRESETS["authors_code"]["lr_opacity"], ge=0)
    lr_quats: float = Field(LR_PRESETS["authors_code"]["lr_quats"], ge=0)
    optimize_geometry: bool = Field(True, description="also optimise xyz/scale/opacity/rotation in the main pass")
    preserve_color: bool = Field(False, description="keep the scene's colours: transfer luminance only")
    seed: int = 0
    backend: str = "auto"
    log_every: int = Field(10, ge=1)
    threads: int = Field(0, ge=0, description="torch CPU threads for this stage (0: torch's default, all cores); "
                         "with `dvc queue start -j N` on C cores, C // N (README 'Benchmarks at scale')")

    @model_validator(mode="before")
    @classmethod
    def _apply_lr_preset(cls, data):
        """Fill the ``lr_*`` keys the user did not give from ``lr_preset``."""
        if isinstance(data, dict):
            preset = data.get("lr_preset", "authors_code")
            if preset in LR_PRESETS:
                data = {**LR_PRESETS[preset], **data}
        return data


@dataclass
class StylizeResult:
    model: GaussianModel
    history: list[dict]
    timings: dict[str, float]
    fast_stats: dict
    seconds: float
    color_pass_seconds: float = 0.0


@dataclass
class ViewTargets:
    """Per-view fixed targets: content features, original depth, per-group feature masks."""

    camera: Camera
    content_feats: Tensor  # (C, h, w)
    depth: Tensor  # (H, W, 1)
    group_masks: list[Tensor] = field(default_factory=list)  # per group (h, w) bool
    content_image: Tensor | None = None  # (H, W, 3) the colour-matched render


def color_match_model(
    model: GaussianModel, labels: Tensor, groups: list[MatchingGroup], content_pixels: dict[int, np.ndarray]
) -> tuple[GaussianModel, dict[int, tuple[Tensor, Tensor]]]:
    """Apply each group's mean/covariance colour transform to the DC colours of its Gaussians.

    ``content_pixels[z]``: ``(n, 3)`` pixels of the content (training images) covered by group z.
    Single transfer (one group over all pixels) recolours every Gaussian.
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
        sel = torch.ones_like(labels, dtype=torch.bool) if g.content_label == ALL_PIXELS else labels == g.content_label
        rgb[sel] = apply_color_transform(rgb[sel], A, b)
    out.sh0 = rgb_to_sh0(rgb)[:, None, :].contiguous()
    if out.shN.numel():
        out.shN = torch.zeros_like(out.shN)  # view-dependent colour would undo the match
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
) -> list[ViewTargets]:
    """Content features (from the colour-matched scene), depth (from the original scene), group masks."""
    targets = []
    with torch.no_grad():
        for cam, lab in zip(cameras, label_maps):
            # one render gives both when the depth comes from the content scene itself
            img, _, meta = render(model_content, cam, backend=params.backend, render_depth=model_original is model_content)
            if model_original is not model_content:
                _, _, meta = render(model_original, cam, backend=params.backend, render_depth=True)
            feats = _features(vgg, img.clamp(0, 1), params)
            hw = tuple(feats.shape[-2:])
            masks = [downsample_mask(m, hw) if m.any() else torch.zeros(hw, dtype=torch.bool)
                     for m in group_pixel_masks(groups, lab)]
            targets.append(ViewTargets(cam, feats, meta.depth, masks, img))
    return targets


def group_features(feats: Tensor, mask: Tensor) -> Tensor:
    """The ``(C, n)`` columns of ``feats`` ``(C, h, w)`` under ``mask`` ``(h, w)`` bool, in row-major order: a view of
    all columns when the mask covers every cell (single-image transfer), so that neither the forward nor the backward
    copies the features through the mask."""
    return feats.flatten(1) if bool(mask.all()) else feats[:, mask]


def _optimizer(model: GaussianModel, lrs: dict[str, float]) -> torch.optim.Adam:
    """Adam (eps 1e-15, as 3DGS) over the fields with a positive learning rate; the others are frozen."""
    groups = []
    for name, lr in lrs.items():
        tensor = getattr(model, name)
        if lr > 0:
            groups.append({"params": [tensor], "lr": lr})
        else:
            tensor.requires_grad_(False)
    return torch.optim.Adam(groups, eps=1e-15)


def main_pass_lrs(params: StylizeParams) -> dict[str, float]:
    """Learning rate per :class:`GaussianModel` field in the main pass (geometry 0 unless ``optimize_geometry``)."""
    geo = params.optimize_geometry
    return {"sh0": params.lr_sh0, "means": params.lr_means if geo else 0.0, "log_scales": params.lr_scales if geo else 0.0,
            "opacity_logits": params.lr_opacity if geo else 0.0, "quats": params.lr_quats if geo else 0.0}


def _check_finite(value: Tensor, name: str, step: int) -> None:
    if not torch.isfinite(value):
        raise NumericalError(
            f"stylization loss term {name} became {value.item()} at step {step}; lower the learning rates or "
            "λ of that term, or check the inputs (style image, masks)"
        )


@torch.no_grad()
def _renormalize_quats(model: GaussianModel) -> None:
    """Project the rotations back onto unit quaternions after an optimiser step (in place)."""
    model.quats.data = model.quats.data / model.quats.data.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def _random_views(n: int, seed: int):
    """Endless view indices: a seeded random permutation of ``range(n)``, drawn again when used up."""
    gen = torch.Generator().manual_seed(seed)
    while True:
        yield from torch.randperm(n, generator=gen).tolist()


def style_pass(
    model: GaussianModel,
    targets: list[ViewTargets],
    groups: list[MatchingGroup],
    vgg: VGG16Features,
    params: StylizeParams,
    *,
    iterations: int,
    progress: bool = True,
    history: list[dict] | None = None,
    timings: dict[str, float] | None = None,
    fast_stats: FastStats | None = None,
    method: str = "fast",
) -> GaussianModel:
    """The main stylization pass over random views; returns the optimised (detached) model."""
    history = [] if history is None else history
    timings = {} if timings is None else timings
    orig = model.detach()
    orig_scales, orig_opac = orig.scales, orig.opacities
    m = model.as_parameters()
    lrs = main_pass_lrs(params)
    opt = _optimizer(m, lrs)
    views = _random_views(len(targets), params.seed)
    style_feats = [StyleFeatures.of(g.features) for g in groups]  # fixed for the run: prepared once
    bar = progress_bar(range(iterations), "stylize", enabled=progress)
    t_start = time.perf_counter()
    for step in bar:
        tgt = targets[next(views)]
        t0 = time.perf_counter()
        img, alpha, meta = render(m, tgt.camera, backend=params.backend, render_depth=params.lambda_depth > 0)
        t1 = time.perf_counter()
        feats = _features(vgg, img, params)
        t2 = time.perf_counter()
        pairs = [(group_features(feats, mask), fs) for mask, fs in zip(tgt.group_masks, style_feats) if bool(mask.any())]
        terms: dict[str, Tensor] = {}
        if pairs and params.lambda_style > 0:
            terms["style"] = params.lambda_style * style_loss(
                method, pairs, k=params.fast.k, fast_params=params.fast, stats=fast_stats,
                max_block_elems=params.fast.max_block_elems,
            )
        t3 = time.perf_counter()
        if params.lambda_content > 0:
            terms["content"] = params.lambda_content * content_loss(feats, tgt.content_feats)
        if params.lambda_tv > 0:
            terms["tv"] = params.lambda_tv * tv_loss(img.permute(2, 0, 1)[None])
        if params.lambda_depth > 0 and meta.depth is not None:
            terms["depth"] = params.lambda_depth * F.mse_loss(meta.depth, tgt.depth)
        if params.lambda_scale > 0 and lrs["log_scales"] > 0:
            terms["scale"] = params.lambda_scale * (m.scales - orig_scales).norm(dim=-1).mean()
        if params.lambda_opacity > 0 and lrs["opacity_logits"] > 0:
            terms["opacity"] = params.lambda_opacity * (m.opacities - orig_opac).abs().mean()
        for name, value in terms.items():
            _check_finite(value, name, step)
        loss = torch.stack(list(terms.values())).sum()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        t4 = time.perf_counter()
        opt.step()
        _renormalize_quats(m)
        t5 = time.perf_counter()
        for key, dt in (("render", t1 - t0), ("vgg", t2 - t1), ("style_loss", t3 - t2), ("backward", t4 - t3),
                        ("step", t5 - t4)):
            timings[key] = timings.get(key, 0.0) + dt
        timings["iterations"] = timings.get("iterations", 0) + 1
        if step % params.log_every == 0 or step == iterations - 1:
            row = {"step": step, "seconds": time.perf_counter() - t_start, "loss": float(loss.detach()), "pass": "main"}
            row.update({k: float(v.detach()) for k, v in terms.items()})
            history.append(row)
            bar.set_postfix({k: f"{float(v.detach()):.4f}" for k, v in terms.items()}, refresh=False)
    bar.close()
    return m.detach()


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
    history: list[dict] | None = None,
) -> GaussianModel:
    """The authors' post-process: colour-match the re-rendered views to the style again, then re-fit.

    Every view is rendered, each group's covered pixels (alpha > 0.5) get the mean/covariance colour transform to its style
    region (the transform is applied to the group's Gaussians too, as in the colour-match stage), and the
    DC colours and rotations are re-fitted to those images with ``0.8·L1 + 0.2·D-SSIM`` while means,
    scales and opacities stay frozen (``post_process_phase.py`` freezes ``_xyz``, ``_scaling``, ``_opacity``).
    """
    history = [] if history is None else history
    with torch.no_grad():
        outs = [render(model, t.camera, backend=params.backend) for t in targets]
    renders = [o[0].clamp(0, 1) for o in outs]
    pix: dict[int, list[Tensor]] = {g.content_label: [] for g in groups}
    full_masks = []
    for t, img, (_, alpha, _) in zip(targets, renders, outs):
        h, w = img.shape[:2]
        # pixels the scene covers (alpha > 0.5): the black background is neither measured nor recoloured
        covered = alpha.reshape(h, w) > 0.5
        masks = [(F.interpolate(m[None, None].float(), size=(h, w), mode="nearest")[0, 0] > 0.5) & covered
                 for m in t.group_masks]
        full_masks.append(masks)
        for g, m in zip(groups, masks):
            pix[g.content_label].append(img[m])
    content = {k: torch.cat(v).numpy() if v else np.zeros((0, 3), np.float32) for k, v in pix.items()}
    recolored, transforms = color_match_model(model, gaussian_labels, groups, content)
    images = []
    for img, masks in zip(renders, full_masks):
        new = img.clone()
        for g, m in zip(groups, masks):
            a, b = transforms[g.content_label]
            new[m] = apply_color_transform(img[m], a, b, clip=(0.0, 1.0))
        images.append(new)
    m = recolored.as_parameters()
    opt = _optimizer(m, {"sh0": params.lr_sh0, "quats": params.lr_quats, "means": 0.0, "log_scales": 0.0,
                         "opacity_logits": 0.0})
    views = _random_views(len(targets), params.seed + 1)
    bar = progress_bar(range(iterations), "colour pass", enabled=progress)
    t_start = time.perf_counter()
    for it in bar:
        i = next(views)
        img, _, _ = render(m, targets[i].camera, backend=params.backend)
        terms = reconstruction_loss(img, images[i])
        _check_finite(terms.total, "colour-pass reconstruction", start_step + it)
        opt.zero_grad(set_to_none=True)
        terms.total.backward()
        opt.step()
        _renormalize_quats(m)
        if it % params.log_every == 0 or it == iterations - 1:
            history.append({"step": start_step + it, "seconds": time.perf_counter() - t_start, "pass": "color",
                            "loss": float(terms.total.detach()), "l1": float(terms.l1.detach())})
    bar.close()
    return m.detach()


def stylize(
    model: GaussianModel,
    cameras: list[Camera],
    label_maps: list[np.ndarray],
    gaussian_labels: Tensor,
    groups: list[MatchingGroup],
    vgg: VGG16Features,
    params: StylizeParams,
    *,
    method: str = "fast",
    progress: bool = True,
    depth_model: GaussianModel | None = None,
) -> StylizeResult:
    """Run the stylization passes on a (colour-matched) model.

    Args:
        model: the colour-matched, re-fitted scene (the content target and the starting point).
        cameras: the views to stylize from.
        label_maps: per view ``(H, W)`` rendered content labels (ignored by single transfer).
        gaussian_labels: ``(N,)`` lifted content label of each Gaussian (for the colour pass).
        depth_model: the original (pre-colour-match) scene whose depth the depth loss keeps (paper: "we use
            the original Gaussians to render the initial depth map"); default ``model``.
        groups: matching groups with style features (:func:`abcgs.style.matching.build_groups`).
    """
    if not cameras:
        raise InputError("stylize: no views")
    torch.manual_seed(params.seed)
    t0 = time.perf_counter()
    history: list[dict] = []
    timings: dict[str, float] = {}
    stats = FastStats()
    targets = prepare_targets(model, depth_model or model, cameras, label_maps, groups, vgg, params)
    for g, z in enumerate(groups):
        if not any(bool(t.group_masks[g].any()) for t in targets):
            raise InputError(f"matching group for content label {z.content_label} covers no pixel in any view")
    styled = style_pass(model, targets, groups, vgg, params, iterations=params.iterations, progress=progress,
                        history=history, timings=timings, fast_stats=stats, method=method)
    t_cp = time.perf_counter()
    if params.color_pass_iterations > 0:
        styled = color_pass(styled, gaussian_labels, targets, groups, params, iterations=params.color_pass_iterations,
                            start_step=params.iterations, progress=progress, history=history)
    t_cp = time.perf_counter() - t_cp
    if params.preserve_color:
        styled = recolor_to_content(styled, model)
    return StylizeResult(styled, history, timings, stats.as_dict(), time.perf_counter() - t0, t_cp)


def recolor_to_content(styled: GaussianModel, content: GaussianModel) -> GaussianModel:
    """``preserve_color``: keep the stylised luminance, take chroma from the content colours (YIQ)."""
    out = styled.detach()
    rgb = preserve_color(sh0_to_rgb(styled.sh0[:, 0, :]), sh0_to_rgb(content.sh0[:, 0, :]))
    out.sh0 = rgb_to_sh0(rgb)[:, None, :].contiguous()
    return out
