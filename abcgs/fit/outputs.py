"""What the fit stage writes: the fitted Gaussians, the run's record, the loss history and the held-out grid.

    fit_and_save(scene, params, "out/fit")   # point_cloud.ply, metrics.json, history.csv, heldout_grid.png
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

from abcgs.fit.evaluation import comparison_grid, evaluate
from abcgs.fit.params import FitParams
from abcgs.fit.plausibility import check_fit
from abcgs.fit.training import FitResult, fit
from abcgs.gaussians.ply import write_ply
from abcgs.io.atomic import write_json
from abcgs.io.images import save_image
from abcgs.io.tables import write_csv
from abcgs.layout import FitDir
from abcgs.render.cpu import kernel_threads
from abcgs.runtime import torch_threads
from abcgs.types import CalibratedScene

HISTORY_COLUMNS = ("step", "seconds", "loss", "psnr", "n_gaussians")
"""Columns of ``history.csv``: one row per training step (training-view PSNR in dB, ``seconds`` of training so far)."""


def fit_and_save(
    scene: CalibratedScene, params: FitParams, out_dir: str | os.PathLike, progress: bool = True, *,
    device: torch.device | None = None,
) -> FitResult:
    """:func:`fit`, then write into ``out_dir`` (each file atomically):

    - ``point_cloud.ply``: INRIA-layout 3DGS PLY (:func:`abcgs.gaussians.ply.write_ply`);
    - ``metrics.json``: held-out ``psnr``/``ssim`` means and ``per_view``, ``n_gaussians``, ``seconds``, ``backend``, …,
      and ``check``: the plausibility check's numbers (:class:`~abcgs.fit.plausibility.FitCheck`);
    - ``history.csv``: ``step, seconds, loss, psnr, n_gaussians`` per step;
    - ``heldout_grid.png``: one row per held-out view, ground truth | render (training views 0–2 when
      nothing is held out).

    Raises:
        FitError: the fit is implausible (:func:`~abcgs.fit.plausibility.check_fit`); nothing is written.
    """
    out = FitDir(Path(out_dir))
    out.root.mkdir(parents=True, exist_ok=True)
    result = fit(scene, params, progress, device=device)
    with torch_threads(params.threads), kernel_threads(params.rasterizer_threads):
        check = check_fit(result)
    check.raise_if_implausible()
    write_ply(out.ply, result.model)
    write_json(out.record, {**result.metrics(), "check": check.to_dict()})
    write_csv(out.history, result.history, HISTORY_COLUMNS)
    if result.heldout is not None:
        pairs = [(v.target, v.render) for v in result.heldout.views]
    else:
        cams, imgs = result.views.pick(result.views.train[:3])
        with torch_threads(params.threads), kernel_threads(params.rasterizer_threads):
            ev = evaluate(
                result.model, cams, imgs, result.backend,
                background=torch.tensor(params.background, dtype=torch.float32, device=result.model.device),
                keep_images=True,
            )
        pairs = [(v.target, v.render) for v in ev.views]
    save_image(out.heldout_grid, comparison_grid(pairs))
    return result
