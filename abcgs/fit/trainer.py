"""Fitting baseline 3DGS (Kerbl et al. 2023) to a calibrated scene.

    result = fit(scene, FitParams(iterations=7000))
    fit_and_save(scene, params, "out/fit")   # point_cloud.ply, metrics.json, history.csv, heldout_grid.png

One view per step, loss ``(1 − λ)·L1 + λ·(1 − SSIM)`` (λ = 0.2, the reference code's D-SSIM term), one
Adam (eps 1e-15) per parameter with the 3DGS learning rates, the means' rate decayed exponentially from
``lr_means`` to ``lr_means_final`` (both × scene extent), SH bands enabled one per ``sh_degree_interval``
steps, and densification by a pluggable :mod:`strategy <abcgs.fit.strategy>`. Every ``test_every``-th view
(index 0, 8, 16, … — the LLFF convention) is held out for evaluation.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor

from abcgs.cameras import Camera
from abcgs.errors import InputError, NumericalError
from abcgs.fit import metrics as M
from abcgs.fit.losses import reconstruction_loss
from abcgs.fit.params import FitParams
from abcgs.fit.strategy import DefaultStrategy, NoDensification, RefineReport, Strategy, scene_extent
from abcgs.gaussians import PARAM_NAMES, GaussianModel, render
from abcgs.io.atomic import write_json
from abcgs.io.images import load_image, save_image
from abcgs.io.ply import write_ply
from abcgs.io.tables import write_csv
from abcgs.progress import progress as progress_bar
from abcgs.render import select_backend
from abcgs.render.cpu import kernel_threads
from abcgs.runtime import resolve_device, torch_threads
from abcgs.types import Backend, SceneLike

log = logging.getLogger(__name__)





# ================================================================================================
# Data
# ================================================================================================


@dataclass
class Views:
    """Training data in memory: cameras at the training resolution and ``(H, W, 3) float32`` image tensors."""

    cameras: list[Camera]
    images: list[Tensor]
    train: list[int]
    test: list[int]


def split_views(n: int, test_every: int) -> tuple[list[int], list[int]]:
    """``(train, test)`` indices: views ``0, k, 2k, …`` are held out (LLFF convention); ``k = 0`` holds none."""
    if test_every <= 0:
        return list(range(n)), []
    test = [i for i in range(n) if i % test_every == 0]
    train = [i for i in range(n) if i % test_every != 0]
    if not train:
        raise InputError(f"with {n} view(s) and test_every={test_every} no view is left for training; set test_every: 0")
    return train, test


def load_views(scene: SceneLike, resolution_scale: float = 1.0, test_every: int = 8, device: str | torch.device = "cpu") -> Views:
    """Load every image once, downscaled by ``resolution_scale`` with ``cv2.INTER_AREA``.

    Each image must have its camera's size (the undistorted images of the reconstruct stage do);
    a mismatch raises :class:`InputError` with both sizes.
    """
    if len(scene.cameras) != len(scene.image_paths):
        raise InputError(f"scene has {len(scene.cameras)} cameras but {len(scene.image_paths)} image paths")
    if not scene.cameras:
        raise InputError("scene has no cameras")
    cams, imgs = [], []
    for cam, path in zip(scene.cameras, scene.image_paths):
        img = load_image(path)
        if img.shape[:2] != (cam.height, cam.width):
            raise InputError(
                f"image {path} is {img.shape[1]}x{img.shape[0]} but its camera {cam.name} is {cam.width}x{cam.height}; "
                "use the undistorted images written with the COLMAP model"
            )
        if resolution_scale != 1.0:
            cam = cam.scaled(resolution_scale)
            img = cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
        cams.append(cam)
        imgs.append(torch.from_numpy(np.ascontiguousarray(img, dtype=np.float32)).to(device))
    train, test = split_views(len(cams), test_every)
    return Views(cams, imgs, train, test)


# ================================================================================================
# Results
# ================================================================================================


@dataclass
class ViewEval:
    """One evaluated view: metrics and (optionally) the images as ``(H, W, 3) float32`` numpy arrays."""

    name: str
    psnr: float
    ssim: float
    render: np.ndarray | None = None
    target: np.ndarray | None = None


@dataclass
class Evaluation:
    """Mean metrics over views (PSNR averaged per view in dB, as 3DGS reports) and the per-view list."""

    psnr: float
    ssim: float
    views: list[ViewEval]

    def to_dict(self) -> dict:
        return {
            "psnr": self.psnr,
            "ssim": self.ssim,
            "n_views": len(self.views),
            "per_view": {v.name: {"psnr": v.psnr, "ssim": v.ssim} for v in self.views},
        }


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


# ================================================================================================
# Evaluation
# ================================================================================================


@torch.no_grad()
def evaluate(
    model: GaussianModel,
    cameras: Sequence[Camera],
    images: Sequence[Tensor | np.ndarray],
    backend: Backend = "auto",
    *,
    background: Tensor | None = None,
    keep_images: bool = False,
) -> Evaluation:
    """Render ``cameras`` and compare with ``images`` ``(H, W, 3)`` in ``[0, 1]``: PSNR (dB) and SSIM.

    Renders are clamped to ``[0, 1]`` before scoring. With ``keep_images`` each :class:`ViewEval` keeps
    the render and the target as numpy arrays.
    """
    if len(cameras) != len(images):
        raise InputError(f"evaluate: {len(cameras)} cameras but {len(images)} images")
    views = []
    for cam, gt in zip(cameras, images):
        gt_t = torch.as_tensor(gt, dtype=torch.float32, device=model.device)
        img, _, _ = render(model, cam, backend=backend, background=background)
        img = img.clamp(0.0, 1.0)
        views.append(
            ViewEval(
                cam.name, M.psnr(img, gt_t), M.ssim(img, gt_t),
                img.cpu().numpy() if keep_images else None, gt_t.cpu().numpy() if keep_images else None,
            )
        )
    if not views:
        return Evaluation(math.nan, math.nan, [])
    return Evaluation(float(np.mean([v.psnr for v in views])), float(np.mean([v.ssim for v in views])), views)


# ================================================================================================
# Training
# ================================================================================================


def make_optimizers(model: GaussianModel, params: FitParams, extent: float) -> dict[str, torch.optim.Optimizer]:
    """One Adam (eps = 1e-15, as 3DGS) per parameter tensor with the 3DGS learning rates."""
    lrs = {
        "means": params.lr_means * extent,
        "quats": params.lr_quats,
        "log_scales": params.lr_scales,
        "opacity_logits": params.lr_opacity,
        "sh0": params.lr_sh0,
        "shN": params.lr_shN,
    }
    return {name: torch.optim.Adam([getattr(model, name)], lr=lrs[name], eps=1e-15) for name in PARAM_NAMES}


def means_lr(step: int, params: FitParams, extent: float) -> float:
    """Log-linear decay from ``lr_means`` to ``lr_means_final`` (× extent) over the run (3DGS ``get_expon_lr_func``)."""
    t = min(max(step / params.iterations, 0.0), 1.0)
    return extent * math.exp((1.0 - t) * math.log(params.lr_means) + t * math.log(params.lr_means_final))


def make_strategy(params: FitParams, extent: float, generator: torch.Generator | None = None) -> Strategy:
    if not params.densify:
        return NoDensification()
    return DefaultStrategy(params.strategy_params(), extent, params.max_gaussians, generator)


def fit(
    scene: SceneLike,
    params: FitParams | None = None,
    progress: bool = True,
    *,
    views: Views | None = None,
    initial: GaussianModel | None = None,
    strategy: Strategy | None = None,
    device: torch.device | None = None,
) -> FitResult:
    """Fit 3-D Gaussians to ``scene`` (cameras, image paths, SfM points and colours).

    Args:
        scene: a :class:`~abcgs.sfm.model.SceneData` (or anything with the same attributes).
        params: :class:`FitParams` (defaults: the 3DGS recipe, 30k steps).
        progress: show a tqdm bar with loss, PSNR, Gaussian count and ETA.
        views: preloaded images (skip :func:`load_views`). initial: start from these Gaussians instead of
            the SfM points. strategy: override the densification strategy built from ``params``.
        device: where to train (``runtime.device`` resolved); default: the device of ``views`` when given, else
            :func:`abcgs.runtime.resolve_device` of ``auto``.

    Raises:
        InputError: unusable scene (no points, image/camera size mismatch, …).
        NumericalError: a loss term became NaN/Inf (message names the step, term and view).
    """
    params = params or FitParams()
    with torch_threads(params.threads), kernel_threads(params.rasterizer_threads):
        if device is None:
            device = views.images[0].device if views is not None and views.images else resolve_device("auto")
        return _fit(scene, params, progress, views, initial, strategy, device)


def _fit(
    scene: SceneLike,
    params: FitParams,
    progress: bool,
    views: Views | None,
    initial: GaussianModel | None,
    strategy: Strategy | None,
    device: torch.device,
) -> FitResult:
    backend = select_backend(device, params.backend)
    torch.manual_seed(params.seed)
    gen = torch.Generator(device=device).manual_seed(params.seed)
    rng = np.random.default_rng(params.seed)

    views = views or load_views(scene, params.resolution_scale, params.test_every, device)
    train_centers = np.stack([views.cameras[i].center for i in views.train])
    extent = scene_extent(train_centers, scene.points)
    if initial is None:
        initial = GaussianModel.from_points(scene.points, scene.colors, params.sh_degree, params.init_opacity, device=device)
    model = initial.to(device).as_parameters()
    optimizers = make_optimizers(model, params, extent)
    strategy = strategy or make_strategy(params, extent, gen)
    state = strategy.initialize_state(model)
    fixed_bg = torch.tensor(params.background, dtype=torch.float32, device=device)
    test_cams = [views.cameras[i] for i in views.test]
    test_imgs = [views.images[i] for i in views.test]

    history: list[dict] = []
    eval_history: list[dict] = []
    refinements: list[RefineReport] = []
    order: list[int] = []
    train_seconds = 0.0
    bar = progress_bar(range(1, params.iterations + 1), "fit", enabled=progress)
    for step in bar:
        t0 = time.perf_counter()
        for group in optimizers["means"].param_groups:
            group["lr"] = means_lr(step, params, extent)
        if not order:
            order = [int(i) for i in rng.permutation(views.train)][::-1]
        idx = order.pop()
        cam, gt = views.cameras[idx], views.images[idx]
        bg = torch.rand(3, generator=gen, device=device) if params.random_background else fixed_bg
        degree = min(params.sh_degree, step // params.sh_degree_interval)

        image, _, meta = render(model, cam, backend=backend, sh_degree=degree, background=bg)
        strategy.step_pre_backward(model, optimizers, state, step, meta)
        terms = reconstruction_loss(image, gt, params.ssim_lambda)
        for name, value in terms.items().items():
            if not torch.isfinite(value):
                raise NumericalError(
                    f"fit: the {name} loss term is {float(value.detach())} at step {step} (view {cam.name}, "
                    f"{model.num_gaussians} Gaussians); lower the learning rates or check the input images"
                )
        terms.total.backward()
        for opt in optimizers.values():
            opt.step()
            opt.zero_grad(set_to_none=True)
        report = strategy.step_post_backward(model, optimizers, state, step, meta)
        if report is not None:
            refinements.append(report)
            log.debug("step %d: %s", step, report)
        with torch.no_grad():
            mse = float(((image.detach().clamp(0, 1) - gt) ** 2).mean())
        train_seconds += time.perf_counter() - t0
        loss = float(terms.total.detach())
        psnr = M.psnr_from_mse(mse)
        history.append(
            {"step": step, "loss": loss, "psnr": psnr, "n_gaussians": model.num_gaussians, "seconds": train_seconds}
        )
        if progress and (step % 10 == 0 or step == params.iterations):
            bar.set_postfix_str(f"loss={loss:.4f} psnr={psnr:.2f} n_gaussians={model.num_gaussians}", refresh=False)
        # An evaluation right after an opacity reset would only measure the reset (opacities clamped to 0.01).
        just_reset = report is not None and report.opacity_reset
        if params.eval_every and test_cams and step % params.eval_every == 0 and step != params.iterations and not just_reset:
            ev = evaluate(model, test_cams, test_imgs, backend, background=fixed_bg)
            eval_history.append({"step": step, "seconds": train_seconds, "psnr": ev.psnr, "ssim": ev.ssim})
    bar.close()

    final = model.detach()
    heldout = None
    if test_cams:
        heldout = evaluate(final, test_cams, test_imgs, backend, background=fixed_bg, keep_images=True)
        eval_history.append(
            {"step": params.iterations, "seconds": train_seconds, "psnr": heldout.psnr, "ssim": heldout.ssim}
        )
    return FitResult(final, history, heldout, eval_history, refinements, views, extent, train_seconds, backend, params)


# ================================================================================================
# Artefacts
# ================================================================================================

HISTORY_COLUMNS = ("step", "seconds", "loss", "psnr", "n_gaussians")


def comparison_grid(pairs: Sequence[tuple[np.ndarray, np.ndarray]], max_tile_width: int = 400, gap: int = 4) -> np.ndarray:
    """Rows of ``target | render`` tiles (``(H, W, 3)`` floats in [0, 1]) on white, tiles downscaled to ``max_tile_width``."""
    rows = []
    for target, rendered in pairs:
        tiles = []
        for img in (target, rendered):
            img = np.clip(np.asarray(img, np.float32), 0.0, 1.0)
            if img.shape[1] > max_tile_width:
                h = max(1, round(img.shape[0] * max_tile_width / img.shape[1]))
                img = cv2.resize(img, (max_tile_width, h), interpolation=cv2.INTER_AREA)
            tiles.append(img)
        h = max(t.shape[0] for t in tiles)
        w = sum(t.shape[1] for t in tiles) + gap
        row = np.ones((h, w, 3), np.float32)
        row[: tiles[0].shape[0], : tiles[0].shape[1]] = tiles[0]
        row[: tiles[1].shape[0], tiles[0].shape[1] + gap :] = tiles[1]
        rows.append(row)
    if not rows:
        return np.ones((1, 1, 3), np.float32)
    width = max(r.shape[1] for r in rows)
    out = np.ones((sum(r.shape[0] for r in rows) + gap * (len(rows) - 1), width, 3), np.float32)
    y = 0
    for r in rows:
        out[y : y + r.shape[0], : r.shape[1]] = r
        y += r.shape[0] + gap
    return out


def fit_and_save(
    scene: SceneLike, params: FitParams, out_dir: str | os.PathLike, progress: bool = True, *,
    device: torch.device | None = None,
) -> FitResult:
    """:func:`fit`, then write into ``out_dir`` (each file atomically):

    - ``point_cloud.ply``: INRIA-layout 3DGS PLY (:func:`abcgs.io.ply.write_ply`);
    - ``metrics.json``: held-out ``psnr``/``ssim`` means and ``per_view``, ``n_gaussians``, ``seconds``, ``backend``, …;
    - ``history.csv``: ``step, seconds, loss, psnr, n_gaussians`` per step;
    - ``heldout_grid.png``: one row per held-out view, ground truth | render (training views 0–2 when
      nothing is held out).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = fit(scene, params, progress, device=device)
    write_ply(out / "point_cloud.ply", result.model)
    write_json(out / "metrics.json", result.metrics())
    write_csv(out / "history.csv", result.history, HISTORY_COLUMNS)
    if result.heldout is not None:
        pairs = [(v.target, v.render) for v in result.heldout.views]
    else:
        idx = result.views.train[:3]
        with torch_threads(params.threads), kernel_threads(params.rasterizer_threads):
            ev = evaluate(
                result.model, [result.views.cameras[i] for i in idx], [result.views.images[i] for i in idx],
                result.backend, background=torch.tensor(params.background, dtype=torch.float32, device=result.model.device),
                keep_images=True,
            )
        pairs = [(v.target, v.render) for v in ev.views]
    save_image(out / "heldout_grid.png", comparison_grid(pairs))
    return result
