"""The ABC-GS stylization stage: optimise the colour-matched Gaussians with

    L = λ_FAST·L_style + λ_c·L_con + λ_tv·L_tv + λ_dep·L_dep + λ_sca·‖Δs‖ + λ_opa·‖Δα‖  (+ λ_st·L_st)

(paper λ = {2, 0.005, 0.02, 0.01, 1, 1}, densification off; ``L_st``, this project's, keeps the content's luminance
gradients; λ_c and λ_st may differ per content label: :class:`abcgs.stylize.targets.LabelWeights`), optionally followed by the authors'
post-process ("colour pass"): re-render every view, colour-match the renders to the style again, and
re-fit colours and rotations (xyz, scales, opacities frozen) to those images with the reconstruction
loss ``0.8·L1 + 0.2·D-SSIM`` (vpx-ecnu/ABC-GS ``abcgs/phases/post_process_phase.py``). ``L_style`` is
FAST (ABC-GS) or a baseline (NNFM, KNNFM, Gram) chosen by one parameter.

The pieces live in their own modules: :mod:`abcgs.stylize.records` (what a run records),
:mod:`abcgs.stylize.targets` (the per-view targets: content features, depth, group masks, silhouettes),
:mod:`abcgs.stylize.passes` (the main pass and the colour pass) and :mod:`abcgs.stylize.color` (the colour match of
the Gaussians, colour preservation); this module runs them (:func:`stylize`, :func:`stylize_scene`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

import numpy as np
import torch
from torch import Tensor

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.features.vgg import VGG16Features
from abcgs.gaussians import GaussianModel, fitted_rows
from abcgs.io.images import resized_labels
from abcgs.runtime import release_free_memory
from abcgs.silhouette import object_gaussians
from abcgs.stylize.color import recolor_to_content
from abcgs.stylize.params import StylizeParams
from abcgs.stylize.passes import color_pass, style_pass
from abcgs.stylize.records import StylizeResult, projected_search_record
from abcgs.stylize.schedule import choose_schedule
from abcgs.stylize.sh_bands import with_higher_sh
from abcgs.stylize.targets import Backdrop, LabelWeights, prepare_targets
from abcgs.types import FRAME_FILLING, Background, MatchingGroup, SceneMasks, StyleMethod

log = logging.getLogger(__name__)


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
    label_weights: LabelWeights = LabelWeights(),  # noqa: B008 (a frozen dataclass)
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
        label_weights: the λ_c and λ_st of the content labels (of ``label_maps``) that have their own.
    """
    if not cameras:
        raise InputError("stylize: no views")
    if method == "none":  # the colour-matched start itself: the baseline that stylizes nothing
        return StylizeResult(model.detach(), [], {"iterations": 0}, {}, 0.0)
    torch.manual_seed(params.seed)
    t0 = time.perf_counter()
    backdrop = Backdrop.of(background, model.device)
    targets = prepare_targets(model, depth_model or model, cameras, label_maps, groups, vgg, params, backdrop,
                              label_weights)
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
    label_weights: LabelWeights = LabelWeights(),  # noqa: B008 (a frozen dataclass)
) -> StylizeResult:
    """:func:`stylize` a colour-matched scene at ``params.resolution_scale`` of its views' size (label maps resized
    with nearest neighbours), keeping the depth of the ``original`` scene; ``background``: the scene's;
    ``label_weights``: the experiment's λ per content label."""
    cams, labels = cameras, masks.view_labels
    if params.resolution_scale != 1.0:
        cams = [c.scaled(params.resolution_scale) for c in cameras]
        labels = [resized_labels(v, (c.height, c.width)) for v, c in zip(labels, cams)]
    res = stylize(with_higher_sh(matched, original, params.higher_sh), cams, labels, masks.gaussian_labels, groups,
                  vgg, params, method=method, depth_model=original, background=background,
                   label_weights=label_weights)
    res.projected_search = projected_search_record(params.fast)
    return res
