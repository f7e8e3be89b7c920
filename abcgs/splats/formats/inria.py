"""INRIA 3DGS output folders: ``point_cloud/iteration_<N>/point_cloud.ply`` (the highest ``N`` is the trained scene),
``cameras.json`` (per view ``img_name``, ``position`` = camera centre and ``rotation`` = camera-to-world rotation, in
the frame of the COLMAP dataset it was trained on) and ``cfg_args`` (the training options as a printed
``Namespace(...)``; its ``source_path`` names that dataset). The PLY is read by :mod:`abcgs.io.ply`.

Frame: the dataset's; where the scene's cameras share names with ``cameras.json``, the similarity between the two
sets of centres (identity when they agree).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.io.atomic import atomic_path, write_text
from abcgs.io.ply import PlyLayout, read_ply_layout, write_ply
from abcgs.sfm.align import Similarity, alignment_residual
from abcgs.splats import frames
from abcgs.splats.contract import SplatFormatSpec, SplatProvenance

CAMERA_ALIGN_TOLERANCE = 1e-3
"""``cameras.json`` centres that match the scene's to this fraction of their spread are taken as the same frame."""


@dataclass(frozen=True)
class InriaFolder:
    """What an INRIA output folder holds.

    Attributes:
        ply: the PLY of the highest iteration. iteration: that iteration.
        cameras_json: the text of ``cameras.json`` (``None`` when absent). cfg_args: the text of ``cfg_args``.
        source_path: ``cfg_args``' ``source_path`` (the dataset the model was trained on), ``None`` when absent.
    """

    ply: Path
    iteration: int
    cameras_json: str | None
    cfg_args: str | None
    source_path: str | None


def is_inria_folder(path: Path) -> bool:
    return path.is_dir() and any((path / "point_cloud").glob("iteration_*/point_cloud.ply"))


def read_inria_folder(folder: str | Path) -> InriaFolder:
    folder = Path(folder)
    runs = []
    for p in (folder / "point_cloud").glob("iteration_*/point_cloud.ply"):
        m = re.fullmatch(r"iteration_(\d+)", p.parent.name)
        if m:
            runs.append((int(m.group(1)), p))
    if not runs:
        raise InputError(f"{folder} is not an INRIA 3DGS output folder (no point_cloud/iteration_<N>/point_cloud.ply); "
                         "name the folder that holds point_cloud/, cameras.json and cfg_args")
    iteration, ply = max(runs)
    cams = folder / "cameras.json"
    cfg = folder / "cfg_args"
    cfg_text = cfg.read_text(errors="replace") if cfg.is_file() else None
    source = None
    if cfg_text:
        m = re.search(r"source_path=(['\"])(.*?)\1", cfg_text)  # read as text: cfg_args is never evaluated
        source = m.group(2) if m else None
    return InriaFolder(ply, iteration, cams.read_text() if cams.is_file() else None, cfg_text, source)


def inria_camera_centres(cameras_json: str, *, source: str = "cameras.json") -> dict[str, np.ndarray]:
    """``img_name`` (without extension) → camera centre ``(3,)`` from the text of an INRIA ``cameras.json``."""
    try:
        views = json.loads(cameras_json)
        return {Path(str(v["img_name"])).stem: np.asarray(v["position"], float) for v in views}
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{source}: not an INRIA cameras.json (a list of views with img_name and position): {exc}") from None


def frame_from_cameras(centres: dict[str, np.ndarray], cameras: list[Camera], *,
                       source: str = "cameras.json") -> Similarity | None:
    """The similarity taking the splat's frame (the ``centres`` of its training cameras, by image stem) onto the
    scene's (its ``cameras``), ``None`` when fewer than 3 names match. Raises :class:`InputError` when the matched
    centres do not fit one similarity (another dataset, or cameras reordered)."""
    scene = {Path(c.name).stem: c.center for c in cameras}
    names = sorted(set(scene) & set(centres))
    if len(names) < 3:
        return None
    src = np.stack([centres[n] for n in names])
    dst = np.stack([scene[n] for n in names])
    if np.ptp(dst, axis=0).max() < 1e-9:
        return None
    rms, relative, sim = alignment_residual(src, dst)
    if relative > 0.05:
        raise InputError(f"{source}: the {len(names)} training cameras it shares with the scene do not fit one similarity "
                         f"(RMS {rms:.3g}, {relative:.1%} of the scene's extent): the splat was trained on other poses "
                         "than this scene's; use the scene folder the splat was trained on")
    return sim


def read(path: Path, drop_invalid: bool) -> tuple[GaussianModel, dict]:
    """The folder's PLY of the highest iteration, its layout, the iteration and the side files."""
    folder = read_inria_folder(path)
    model, layout, _ = read_ply_layout(folder.ply, drop_invalid=drop_invalid)
    side = {k: v for k, v in (("cameras.json", folder.cameras_json), ("cfg_args", folder.cfg_args)) if v}
    return model, {"ply_layout": layout.to_list(), "iteration": folder.iteration, "side_files": side}


def frame(path: Path, scene, fields: dict) -> Similarity:
    """Scene → file: the inverse of the alignment of ``cameras.json`` onto the scene's cameras (identity without
    either, or when they agree)."""
    cameras_json = fields.get("side_files", {}).get("cameras.json")
    if not cameras_json or scene is None:
        return frames.IDENTITY
    source = str(path / "cameras.json")
    sim = frame_from_cameras(inria_camera_centres(cameras_json, source=source), scene.cameras, source=source)
    if sim is None or frames.is_identity(sim, CAMERA_ALIGN_TOLERANCE * max(1.0, abs(sim.t).max())):
        return frames.IDENTITY
    return frames.inverse(sim)


def write(model: GaussianModel, path: Path, like: SplatProvenance) -> None:
    """A folder ``point_cloud/iteration_<N>/point_cloud.ply`` in the source's layout, with its side files."""
    layout = PlyLayout.from_list(like.ply_layout) if like.ply_layout else None
    with atomic_path(path, is_dir=True) as tmp:
        write_ply(tmp / "point_cloud" / f"iteration_{like.iteration or 0}" / "point_cloud.ply", model, layout)
        for name, text in like.side_files.items():
            write_text(tmp / name, text)


FORMAT = SplatFormatSpec("inria", read, write, frame, detect=is_inria_folder, rank=10)
