"""Find one pipeline experiment's scenes on disk (``out/<experiment>``, ``out/<scene>``) for the viewer."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from abcgs import layout
from abcgs.errors import InputError
from abcgs.gaussians import read_fitted_rows
from abcgs.gaussians.ply import read_ply
from abcgs.sfm.model import read_scene
from abcgs.types import PathKind
from abcgs.view.page import ViewerExperiment, prepare_experiment

log = logging.getLogger(__name__)


def experiment_scene(run_dir: Path, experiments: Mapping[str, Any] | None = None) -> str:
    """The scene key of the experiment in ``run_dir``: ``<name>.scene`` of ``experiments`` (the params file's
    ``experiments`` section, unvalidated), else the only scene under ``run_dir``'s parent that has a fitted
    ``gs/point_cloud.ply``."""
    exp = (experiments or {}).get(run_dir.name)
    if isinstance(exp, Mapping) and exp.get("scene"):
        return str(exp["scene"])
    scenes = sorted(p.name for p in run_dir.parent.iterdir() if layout.SceneOut(p).fit.ply.is_file())
    if len(scenes) == 1:
        return scenes[0]
    raise InputError(f"cannot tell which scene {run_dir} was made from (found {scenes or 'no fitted scene'}); "
                     "pass --scene or --params with an experiments entry for it")


def load_experiment(run_dir: Path, *, scene: str | None = None, root: Path | None = None,
                    max_gaussians: int = 150_000, path_kind: PathKind = "auto",
                    path_frames: int = 48) -> ViewerExperiment:
    """Layers and cameras of the experiment in ``run_dir`` (``out/<experiment>``); the scene's outputs are
    looked up in ``root`` (default: ``run_dir``'s parent) as ``<scene>/{gs,masks,colmap}``."""
    run_dir = Path(run_dir)
    root = Path(root) if root is not None else run_dir.parent
    scene = scene or experiment_scene(run_dir)
    ply = layout.ExperimentOut(run_dir).stylize.ply
    if not ply.is_file():
        raise InputError(f"{ply} does not exist; run the stylize stage for {run_dir.name} first")
    s = layout.scene(scene, root)
    views = read_scene(s.colmap.root)
    original = read_ply(s.fit.ply) if s.fit.ply.is_file() else None
    stylized = read_ply(ply)
    labels = np.load(s.masks.gaussian_labels, allow_pickle=False) if s.masks.gaussian_labels.is_file() else None
    notes: list[str] = []
    if labels is not None:
        labels = _on_stylized_rows(labels, layout.ExperimentOut(run_dir).stylize.fitted_rows, stylized.num_gaussians,
                                   notes, fix=f"re-run its stylize stage (dvc repro stylize@{run_dir.name})")
    exp = prepare_experiment(run_dir.name, stylized, views.cameras, original=original, labels=labels,
                             max_gaussians=max_gaussians, full_artifact=str(ply), path_kind=path_kind,
                             path_frames=path_frames, background=views.background)
    exp.notes += notes
    return exp


def _on_stylized_rows(labels: np.ndarray, rows_file: Path, n_stylized: int, notes: list[str] | None = None,
                      fix: str = "re-run the stylize stage that wrote it") -> np.ndarray | None:
    """The fitted scene's Gaussian ``labels`` on the ``n_stylized`` stylized Gaussians, through the stylize stage's
    ``fitted_rows.npy`` (``rows_file``, read by the guarded :func:`~abcgs.gaussians.read_fitted_rows`): ``labels``
    as they are where there is no such file (a stylized scene with the fitted scene's rows), None where the file is
    refused, the labels layer then left out with the reason (and ``fix``) logged and appended to ``notes``."""
    if not (rows_file.exists() or rows_file.is_symlink()):
        return labels
    try:
        return labels[read_fitted_rows(rows_file, n_stylized, len(labels), fix=fix)]
    except (OSError, ValueError) as exc:  # InputError is a ValueError
        note = f"the labels layer is left out: {exc}"
        log.warning("%s", note)
        if notes is not None:
            notes.append(note)
        return None
