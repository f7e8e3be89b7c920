"""Fitting baseline 3DGS (Kerbl et al. 2023) to a calibrated scene: the optimisers, the means' learning-rate schedule
and the training loop.

    result = fit(scene, FitParams(iterations=7000))

One view per step, loss ``(1 − λ)·L1 + λ·(1 − SSIM)`` (λ = 0.2, the reference code's D-SSIM term), one
Adam (eps 1e-15) per parameter with the 3DGS learning rates, the means' rate decayed exponentially from
``lr_means`` to ``lr_means_final`` (both × scene extent), SH bands enabled one per ``sh_degree_interval``
steps, and densification by a pluggable :mod:`strategy <abcgs.fit.strategy>`. Every ``test_every``-th view
(index 0, 8, 16, … — the LLFF convention) is held out for evaluation (:mod:`abcgs.fit.evaluation`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from abcgs.cameras import Camera
from abcgs.errors import InputError, NumericalError
from abcgs.fit import metrics as M
from abcgs.fit.adam import Adam
from abcgs.fit.data import Views, load_views, scene_extent
from abcgs.fit.evaluation import Evaluation, evaluate
from abcgs.fit.losses import LossTerms, reconstruction_loss
from abcgs.fit.params import FitParams
from abcgs.fit.strategy import DefaultStrategy, NoDensification, Optimizers, RefineReport, Strategy
from abcgs.gaussians import FROZEN, PARAM_NAMES, GaussianModel, freeze_gaussians, render
from abcgs.losses.terms import silhouette_loss
from abcgs.progress import progress as progress_bar
from abcgs.render import select_backend
from abcgs.render.cpu import kernel_threads
from abcgs.runtime import resolve_device, torch_threads
from abcgs.silhouette import over, unpremultiply
from abcgs.types import Backend, CalibratedScene

log = logging.getLogger(__name__)


@dataclass
class FitResult:
    """What :func:`fit` returns.

    Attributes:
        model: the trained Gaussians (detached, on the training device).
        history: one dict per step ``{step, loss, psnr, n_gaussians, seconds}`` (training view PSNR in dB,
            ``seconds`` = training wall time so far, evaluation excluded).
        heldout: evaluation of the held-out views at the end (None when ``test_every = 0``).
        eval_history: ``{step, psnr, ssim}`` of periodic held-out evaluations (``eval_every``).
        refinements: densification reports.
        views: the loaded cameras/images and the train/test split.
        scene_extent: world units; seconds: total training time; backend: rasterizer used.
    """

    model: GaussianModel
    history: list[dict]
    heldout: Evaluation | None
    eval_history: list[dict]
    refinements: list[RefineReport]
    views: Views
    scene_extent: float
    seconds: float
    backend: Backend
    params: FitParams = field(default_factory=FitParams)

    def metrics(self) -> dict:
        """The ``metrics.json`` content."""
        held = self.heldout.to_dict() if self.heldout is not None else None
        return {
            "psnr": held["psnr"] if held else None,
            "ssim": held["ssim"] if held else None,
            "n_gaussians": self.model.num_gaussians,
            "seconds": self.seconds,
            "backend": self.backend,
            "iterations": self.params.iterations,
            "scene_extent": self.scene_extent,
            "n_train_views": len(self.views.train),
            "n_test_views": len(self.views.test),
            "per_view": held["per_view"] if held else {},
            "eval_history": self.eval_history,
        }


def make_optimizers(model: GaussianModel, params: FitParams, extent: float) -> Optimizers:
    """One Adam (eps = 1e-15, as 3DGS) per parameter tensor with the 3DGS learning rates; with ``color_only`` only
    for the colours (the other tensors then take no gradient)."""
    lrs = {
        "means": params.lr_means * extent,
        "quats": params.lr_quats,
        "log_scales": params.lr_scales,
        "opacity_logits": params.lr_opacity,
        "sh0": params.lr_sh0,
        "shN": params.lr_shN,
    }
    names = ("sh0", "shN") if params.color_only else PARAM_NAMES
    for name in set(PARAM_NAMES) - set(names):
        getattr(model, name).requires_grad_(False)
    return {name: Adam([getattr(model, name)], lr=lrs[name], eps=1e-15) for name in names}


def means_lr(step: int, params: FitParams, extent: float) -> float:
    """Log-linear decay from ``lr_means`` to ``lr_means_final`` (× extent) over the run (3DGS ``get_expon_lr_func``)."""
    t = min(max(step / params.iterations, 0.0), 1.0)
    return extent * math.exp((1.0 - t) * math.log(params.lr_means) + t * math.log(params.lr_means_final))


def make_strategy(params: FitParams, extent: float, generator: torch.Generator | None = None) -> Strategy:
    """The strategy ``params`` asks for: 3DGS densification (:class:`DefaultStrategy`), or none (``densify: false``)."""
    if not params.densify or params.color_only:
        return NoDensification()
    return DefaultStrategy(params.strategy_params(), extent, params.max_gaussians, generator)


def view_order(train: Sequence[int], rng: np.random.Generator) -> Iterator[int]:
    """The training view of each step: epoch after epoch, a fresh random order of ``train`` (3DGS's viewpoint stack)."""
    if len(train) == 0:
        raise InputError("fit: no training views; hold out fewer views (fit.test_every)")
    while True:
        yield from (int(i) for i in rng.permutation(train))


def _check_finite(terms: LossTerms, step: int, camera: Camera, n_gaussians: int) -> None:
    """Raise :class:`NumericalError` naming the step, the term and the view when a loss term is NaN/Inf."""
    for name, value in terms.items().items():
        if not torch.isfinite(value):
            raise NumericalError(
                f"fit: the {name} loss term is {float(value.detach())} at step {step} (view {camera.name}, "
                f"{n_gaussians} Gaussians); lower the learning rates or check the input images"
            )


def _optimizer_step(optimizers: Optimizers) -> None:
    for opt in optimizers.values():
        opt.step()
        opt.zero_grad(set_to_none=True)


def _eval_due(step: int, params: FitParams, report: RefineReport | None) -> bool:
    """A periodic held-out evaluation (``eval_every``) at ``step``: not at the last step (evaluated at the end) and not
    right after an opacity reset, which it would only measure (opacities clamped to ``reset_opacity``)."""
    just_reset = report is not None and report.opacity_reset
    return bool(params.eval_every) and step % params.eval_every == 0 and step != params.iterations and not just_reset


def _eval_row(step: int, seconds: float, ev: Evaluation) -> dict:
    """One row of :attr:`FitResult.eval_history`."""
    return {"step": step, "seconds": seconds, "psnr": ev.psnr, "ssim": ev.ssim}


def fit(
    scene: CalibratedScene,
    params: FitParams | None = None,
    progress: bool = True,
    *,
    views: Views | None = None,
    initial: GaussianModel | None = None,
    strategy: Strategy | None = None,
    device: torch.device | None = None,
    frozen: torch.Tensor | None = None,
) -> FitResult:
    """Fit 3-D Gaussians to ``scene`` (cameras, image paths, SfM points and colours).

    Args:
        scene: a :class:`~abcgs.types.CalibratedScene`.
        params: :class:`FitParams` (defaults: the 3DGS recipe, 30k steps).
        progress: show a tqdm bar with loss, PSNR, Gaussian count and ETA.
        views: preloaded images (skip :func:`load_views`). initial: start from these Gaussians instead of
            the SfM points. strategy: override the densification strategy built from ``params``.
        device: where to train (``runtime.device`` resolved); default: the device of ``views`` when given, else
            :func:`abcgs.runtime.resolve_device` of ``auto``.
        frozen: ``(N,)`` bool over ``initial``: Gaussians that keep their values (its
            :data:`~abcgs.gaussians.FROZEN` attribute: no gradient, and densification leaves them as they are).

    Raises:
        InputError: unusable scene (no points, image/camera size mismatch, …).
        NumericalError: a loss term became NaN/Inf (message names the step, term and view).
    """
    params = params or FitParams()
    with torch_threads(params.threads), kernel_threads(params.rasterizer_threads):
        if device is None:
            device = views.images[0].device if views is not None and views.images else resolve_device("auto")
        return _fit(scene, params, progress, views, initial, strategy, device, frozen)


def _fit(
    scene: CalibratedScene,
    params: FitParams,
    progress: bool,
    views: Views | None,
    initial: GaussianModel | None,
    strategy: Strategy | None,
    device: torch.device,
    frozen: torch.Tensor | None = None,
) -> FitResult:
    backend = select_backend(device, params.backend)
    torch.manual_seed(params.seed)
    gen = torch.Generator(device=device).manual_seed(params.seed)
    views = views or load_views(scene, params.resolution_scale, params.test_every, device)
    extent = scene_extent(np.stack([views.cameras[i].center for i in views.train]), scene.points)
    if initial is None:
        initial = GaussianModel.from_points(scene.points, scene.colors, params.sh_degree, params.init_opacity, device=device)
    model = initial.to(device).as_parameters()
    optimizers = make_optimizers(model, params, extent)
    strategy = strategy or make_strategy(params, extent, gen)
    if frozen is not None:
        if tuple(frozen.shape) != (model.num_gaussians,):
            raise InputError(f"fit: frozen has shape {tuple(frozen.shape)}, expected ({model.num_gaussians},)")
        model.attributes[FROZEN] = frozen.to(device=device, dtype=torch.bool)
    freeze_gaussians(model)
    state = strategy.initialize_state(model)
    fixed_bg = torch.tensor(params.background, dtype=torch.float32, device=device)
    test_cams, test_imgs = views.pick(views.test)
    order = view_order(views.train, np.random.default_rng(params.seed))

    history: list[dict] = []
    eval_history: list[dict] = []
    refinements: list[RefineReport] = []
    train_seconds = 0.0
    bar = progress_bar(range(1, params.iterations + 1), "fit", enabled=progress)
    for step in bar:
        t0 = time.perf_counter()
        for group in optimizers["means"].param_groups if "means" in optimizers else ():
            group["lr"] = means_lr(step, params, extent)
        idx = next(order)
        cam, gt = views.cameras[idx], views.images[idx]
        bg = torch.rand(3, generator=gen, device=device) if params.random_background else fixed_bg
        degree = min(params.sh_degree, step // params.sh_degree_interval)

        if views.alphas is not None and params.random_background:  # the dataset's object on this step's colour
            gt = over(unpremultiply(gt, views.alphas[idx], fixed_bg), views.alphas[idx], bg)
        # the step's batch of views (one): image (1, H, W, 3), a batched meta for the strategy
        images, alphas, meta = render(model, [cam], backend=backend, sh_degree=degree, background=bg)
        image, alpha = images[0], alphas[0]
        strategy.step_pre_backward(model, optimizers, state, step, meta)
        terms = reconstruction_loss(image, gt, params.ssim_lambda)
        if views.alphas is not None and params.alpha_weight > 0:
            terms = terms.plus(params.alpha_weight * silhouette_loss(alpha, views.alphas[idx]))
        _check_finite(terms, step, cam, model.num_gaussians)
        terms.total.backward()
        _optimizer_step(optimizers)
        report = strategy.step_post_backward(model, optimizers, state, step, meta)
        if report is not None:
            refinements.append(report)
            freeze_gaussians(model)  # the strategy replaced the tensors that carried the hooks
            log.debug("step %d: %s", step, report)
        with torch.no_grad():
            psnr = M.psnr_from_mse(float(((image.detach().clamp(0, 1) - gt) ** 2).mean()))
        train_seconds += time.perf_counter() - t0
        loss = float(terms.total.detach())
        history.append(
            {"step": step, "loss": loss, "psnr": psnr, "n_gaussians": model.num_gaussians, "seconds": train_seconds}
        )
        if progress and (step % 10 == 0 or step == params.iterations):
            bar.set_postfix_str(f"loss={loss:.4f} psnr={psnr:.2f} n_gaussians={model.num_gaussians}", refresh=False)
        if test_cams and _eval_due(step, params, report):
            eval_history.append(_eval_row(step, train_seconds, evaluate(model, test_cams, test_imgs, backend, background=fixed_bg)))
    bar.close()

    final = model.detach()
    heldout = None
    if test_cams:
        heldout = evaluate(final, test_cams, test_imgs, backend, background=fixed_bg, keep_images=True)
        eval_history.append(_eval_row(params.iterations, train_seconds, heldout))
    return FitResult(final, history, heldout, eval_history, refinements, views, extent, train_seconds, backend, params)
