"""The ``fit`` stage's other branch: import a trained splat instead of fitting one.

    record = import_and_save(scene, Path("data/garden/splat/point_cloud.ply"), "auto", fit_params, "out/garden/gs")

Writes the same files as :func:`abcgs.fit.outputs.fit_and_save` — ``point_cloud.ply`` (INRIA layout, the scene's
frame, the source's SH degree), ``metrics.json`` (held-out PSNR/SSIM over the views ``fit.test_every`` holds out, as
a fit's), ``history.csv`` (no steps: header only) and ``heldout_grid.png`` — plus ``splat_source.json``, the
:class:`~abcgs.splats.contract.SplatProvenance` the ``export`` stage writes the stylized scene back with. A scene
fitted from its photos gets ``splat_source.json`` too, with ``"format": null``.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import torch

from abcgs.fit.data import load_views
from abcgs.fit.evaluation import comparison_grid, evaluate
from abcgs.fit.outputs import HISTORY_COLUMNS
from abcgs.fit.params import FitParams
from abcgs.gaussians.ply import write_ply
from abcgs.io.atomic import write_json
from abcgs.io.images import save_image
from abcgs.io.tables import write_csv
from abcgs.layout import FitDir
from abcgs.render import select_backend
from abcgs.render.cpu import kernel_threads
from abcgs.runtime import torch_threads
from abcgs.splats.preview import decimate
from abcgs.splats.registry import read_splat
from abcgs.splats.validate import check_splat
from abcgs.types import CalibratedScene


def write_fitted_source(out_dir: str | os.PathLike) -> None:
    """``splat_source.json`` of a scene fitted from its photos (nothing to give back in another format)."""
    write_json(FitDir(Path(out_dir)).splat_source, {"format": None, "note": "fitted from the photos by abcgs"})


def import_and_save(scene: CalibratedScene, splat: str | os.PathLike, fmt: str, params: FitParams,
                    out_dir: str | os.PathLike, *, device: torch.device | str = "cpu", drop_invalid: bool = False) -> dict:
    """Read ``splat`` (:func:`~abcgs.splats.registry.read_splat`), check it against the photos
    (:func:`~abcgs.splats.validate.check_splat` with ``params.import_min_psnr``; raises before writing anything
    when it fails; ``params.import_max_gaussians`` decimates it first, :mod:`abcgs.splats.preview`), evaluate the held-out views and write the outputs listed in the module docstring. Returns the
    ``metrics.json`` record. The check and the held-out renders run on ``device``; ``drop_invalid``: drop non-finite
    Gaussians instead of refusing the file (the scene entry's ``splat_nonfinite``)."""
    out = Path(out_dir)
    t0 = time.perf_counter()
    with torch_threads(params.threads), kernel_threads(params.rasterizer_threads):
        imported = read_splat(splat, fmt, scene=scene, drop_invalid=drop_invalid)
        n_source = imported.model.num_gaussians
        if params.import_max_gaussians is not None and n_source > params.import_max_gaussians:
            imported.model = decimate(imported.model, params.import_max_gaussians)
        imported.model = imported.model.to(device)
        backend = select_backend(torch.device(device), params.backend)
        check = check_splat(imported.model, scene, min_psnr=params.import_min_psnr, backend=backend, source=str(splat))
        views = load_views(scene, params.resolution_scale, params.test_every, device)
        bg = torch.tensor(params.background, dtype=torch.float32, device=device)
        ev = evaluate(imported.model, *views.pick(views.test or views.train[:3]), backend, background=bg, keep_images=True)
    seconds = time.perf_counter() - t0
    prov = imported.provenance
    held = ev.to_dict() if views.test else None
    record = {
        "psnr": held["psnr"] if held else None, "ssim": held["ssim"] if held else None,
        "n_gaussians": imported.model.num_gaussians, "seconds": seconds, "backend": backend, "iterations": 0,
        "n_train_views": len(views.train), "n_test_views": len(views.test),
        "per_view": held["per_view"] if held else {}, "eval_history": [],
        "imported": {"format": prov.format, "source": prov.source, "sh_degree": prov.sh_degree,
                     "n_gaussians_source": n_source,
                     "frame_is_scene_frame": bool((abs(torch.tensor(prov.to_file) - torch.eye(4)) < 1e-9).all()),
                     "check": check.to_dict()},
    }
    out.mkdir(parents=True, exist_ok=True)
    d = FitDir(out)
    write_ply(d.ply, imported.model)
    write_json(d.record, record)
    write_csv(d.history, [], HISTORY_COLUMNS)
    save_image(d.heldout_grid, comparison_grid([(v.target, v.render) for v in ev.views]))
    write_json(d.splat_source, prov.to_dict())
    return record
