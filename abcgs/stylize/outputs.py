"""What a stylization run writes: the stylized PLY, every view's render, a grid, a turntable video, the loss history
and the run's record.

Layout of ``out/<experiment>/``: ``stylize/{point_cloud.ply, renders/<view>.png, grid.png, turntable.mp4}``,
``stylize_history.csv`` (a DVC plot) and ``stylize.json`` + ``stylize_info.json`` (:func:`abcgs.io.metrics.write_metrics`).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from abcgs.camera_paths import camera_path
from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.features.params import ALL_PIXELS
from abcgs.gaussians import GaussianModel, fitted_rows, render_each
from abcgs.gaussians.ply import write_ply
from abcgs.io.atomic import atomic_path
from abcgs.io.images import save_image
from abcgs.io.tables import write_csv
from abcgs.layout import StylizeDir
from abcgs.silhouette import background_tensor, composite_rgba
from abcgs.stylize.records import LoggedStep
from abcgs.types import FRAME_FILLING, Backend, Background, MatchingGroup, PathKind
from abcgs.viz import colorize_labels, image_grid, style_legend, write_video

HISTORY_COLUMNS = ("step", "seconds", "loss", "style", "content", "structure", "tv", "depth", "scale", "opacity",
                   "silhouette", "background")
"""Columns of ``stylize_history.csv``: per logged step the total loss and Eq. 8's terms, each weighted by its λ
(:class:`abcgs.stylize.records.LoggedStep`); a term that is off is empty."""

GRID_ROWS = 3
"""Views shown in ``grid.png`` when ``stylize.grid_views`` names none."""


def grid_indices(cameras: list[Camera], names: list[str] | None) -> list[int]:
    """The cameras ``grid.png`` shows: those ``names`` names (a view's file name or its stem), in the order of
    ``names``, each once; the first :data:`GRID_ROWS` when ``names`` is ``None``. Names the scene lacks are skipped
    (one list may name the views of several scenes); :class:`InputError` when it has none of them."""
    if names is None:
        return list(range(min(GRID_ROWS, len(cameras))))
    index: dict[str, int] = {}
    for i, cam in enumerate(cameras):
        index.setdefault(cam.name, i)
        index.setdefault(Path(cam.name).stem, i)
    picked = list(dict.fromkeys(index[n] for n in names if n in index))
    if not picked:
        shown = ", ".join(c.name for c in cameras[:8]) + (", …" if len(cameras) > 8 else "")
        raise InputError(f"stylize.grid_views names none of this scene's {len(cameras)} views ({', '.join(names)}); "
                         f"its views are {shown}")
    return picked


def _images(model: GaussianModel, cameras: list[Camera], backend: Backend, background: Background) -> list[np.ndarray]:
    """The renders ``(H, W, 3)`` on the scene's background (an object scene's colour; black for a frame-filling one)."""
    bg = background_tensor(background) if background.object else None
    return [img.clamp(0, 1).numpy(force=True) for img, _, _ in render_each(model, cameras, backend=backend, background=bg)]


def _view_files(model: GaussianModel, cameras: list[Camera], backend: Backend, background: Background
                ) -> list[np.ndarray]:
    """What ``renders/<view>.png`` hold: the renders on the background, or straight-alpha RGBA when it is
    transparent (:func:`abcgs.silhouette.composite_rgba`)."""
    bg = background_tensor(background) if background.object else None
    return [composite_rgba(img.clamp(0, 1).numpy(force=True), alpha.numpy(force=True), background)
            for img, alpha, _ in render_each(model, cameras, backend=backend, background=bg)]


def write_stylized_scene(
    out: Path,
    stylized: GaussianModel,
    original: GaussianModel,
    cameras: list[Camera],
    view_labels: list[np.ndarray],
    groups: list[MatchingGroup],
    *,
    backend: Backend,
    path_kind: PathKind,
    path_frames: int,
    background: Background = FRAME_FILLING,
    grid_views: list[str] | None = None,
) -> dict:
    """Write ``out/`` (a folder, atomically): the stylized PLY, ``fitted_rows.npy`` (each Gaussian's row in the fitted
    scene, :func:`~abcgs.gaussians.fitted_rows`), a render of every camera, ``grid.png`` (content,
    labels, each label beside its painting or painting region, stylized; one row per view of
    :func:`grid_indices` of ``grid_views``) and
    ``turntable.mp4`` along :func:`abcgs.camera_paths.camera_path`, all on the scene's ``background`` (the renders
    as RGBA when it is transparent; the grid and video then on black).

    Returns ``{"render_fps": renders per second over the cameras, "camera_path": the path kind used}``.
    """
    with atomic_path(out, is_dir=True) as tmp, torch.no_grad():
        d = StylizeDir(tmp)
        write_ply(d.ply, stylized)
        np.save(d.fitted_rows, fitted_rows(stylized).numpy(force=True).astype(np.int64))
        d.renders.mkdir()
        t0 = time.perf_counter()
        files = _view_files(stylized, cameras, backend, background)
        fps = len(files) / max(time.perf_counter() - t0, 1e-9)
        for cam, img in zip(cameras, files):
            save_image(d.renders / f"{Path(cam.name).stem}.png", img)
        renders = [f[..., :3] * f[..., 3:] if f.shape[-1] == 4 else f for f in files]  # on black for the grid
        legend = style_legend(
            [(None if g.content_label == ALL_PIXELS else colorize_labels(np.array([g.content_label]))[0],
              g.style_image, g.style_region) for g in groups],
            height=cameras[0].height)
        shown = grid_indices(cameras, grid_views)
        contents = _images(original, [cameras[i] for i in shown], backend, background)
        rows = [[content, colorize_labels(view_labels[i]), legend, renders[i]] for content, i in zip(contents, shown)]
        save_image(d.grid, image_grid(rows, ["content", "labels", "label: painting", "stylized"]))
        path, kind = camera_path(cameras, path_kind, path_frames)
        write_video(d.turntable, _images(stylized, path, backend, background), fps=24)
    return {"render_fps": fps, "camera_path": kind}


def write_history(path: Path, history: list[LoggedStep]) -> None:
    """``stylize_history.csv`` (columns :data:`HISTORY_COLUMNS`)."""
    write_csv(path, [s.row() for s in history], HISTORY_COLUMNS)
