"""INRIA 3DGS output folders: ``point_cloud/iteration_<N>/point_cloud.ply`` (the highest ``N`` is the trained scene),
``cameras.json`` (per view ``img_name``, ``position`` = camera centre and ``rotation`` = camera-to-world rotation, in
the frame of the COLMAP dataset it was trained on) and ``cfg_args`` (the training options as a printed
``Namespace(...)``; its ``source_path`` names that dataset). The PLY is read by :mod:`abcgs.gaussians.ply`.

Frame: the dataset's; where the scene's cameras share names with ``cameras.json``, the similarity between the two
sets of centres (identity when they agree).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.gaussians.ply import PlyLayout, read_ply_layout, write_ply
from abcgs.io.atomic import atomic_path, write_text
from abcgs.io.guarded import parse_json, read_bounded, read_text
from abcgs.sfm.align import Similarity, alignment_residual
from abcgs.splats import frames
from abcgs.splats.contract import SplatFormatSpec, SplatProvenance

MAX_SIDE_FILE_BYTES = 64 << 20
"""Largest ``cameras.json`` or ``cfg_args`` read (bytes; 10 000 views of INRIA's JSON take about 5 MB)."""
MAX_COORDINATE = 1e9
"""Largest camera coordinate read from ``cameras.json`` (a 1e308 one overflows the alignment's squares)."""
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
    cfg_text = read_bounded(cfg, "INRIA cfg_args", MAX_SIDE_FILE_BYTES).decode("utf-8", "replace") if _given(cfg) else None
    source = None
    if cfg_text:
        m = re.search(r"source_path=(['\"])(.*?)\1", cfg_text)  # read as text: cfg_args is never evaluated
        source = m.group(2) if m else None
    cams_text = read_text(cams, "INRIA cameras.json", MAX_SIDE_FILE_BYTES) if _given(cams) else None
    return InriaFolder(ply, iteration, cams_text, cfg_text, source)


def _given(path: Path) -> bool:
    """Whether ``path`` is there at all (a symlink loop, a FIFO or a device is, and is refused when read)."""
    return path.exists() or path.is_symlink()


def inria_camera_centres(cameras_json: str, *, source: str = "cameras.json") -> dict[str, np.ndarray]:
    """``img_name`` (without extension) → camera centre ``(3,)`` from the text of an INRIA ``cameras.json``: a list
    of views, each with a string ``img_name`` and a ``position`` of three finite numbers within
    :data:`MAX_COORDINATE`; :class:`InputError` naming ``source`` and the view otherwise (its depth bounded:
    :func:`abcgs.io.guarded.parse_json`)."""
    views = parse_json(cameras_json, source)
    if not isinstance(views, list):
        raise InputError(f"{source}: not an INRIA cameras.json (a list of views with img_name and position)")
    out = {}
    for i, v in enumerate(views):
        if not isinstance(v, dict) or not isinstance(v.get("img_name"), str) or "position" not in v:
            raise InputError(f"{source}: view {i} is not an object with a string img_name and a position; re-export "
                             "the model's cameras.json")
        try:
            centre = np.asarray(v["position"], np.float64)
        except (TypeError, ValueError, OverflowError):
            centre = np.full(1, np.nan)
        if centre.shape != (3,) or not (np.abs(centre) <= MAX_COORDINATE).all():
            raise InputError(f"{source}: view {i} ({v['img_name'][:60]}) has the position {str(v['position'])[:60]}; "
                             f"a camera centre is three finite numbers within ±{MAX_COORDINATE:g}")
        out[Path(v["img_name"]).stem] = centre
    return out


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
    try:
        rms, relative, sim = alignment_residual(src, dst)
    except InputError as exc:  # umeyama's: all centres alike
        raise InputError(f"{source}: its camera centres do not fix a similarity to the scene's ({exc}); use the "
                         "scene folder the splat was trained on") from None
    if relative > 0.05:
        raise InputError(f"{source}: the {len(names)} training cameras it shares with the scene do not fit one similarity "
                         f"(RMS {rms:.3g}, {relative:.1%} of the scene's extent): the splat was trained on other poses "
                         "than this scene's; use the scene folder the splat was trained on")
    return sim


def read(path: Path, drop_invalid: bool) -> tuple[GaussianModel, dict]:
    """The folder's PLY of the highest iteration, its layout, the iteration and the side files; ``cameras.json``'s
    views are checked here (:func:`inria_camera_centres`), so a reader without the scene's cameras (preflight on a
    scene whose cameras structure from motion will find) refuses a corrupt one too."""
    folder = read_inria_folder(path)
    if folder.cameras_json:
        inria_camera_centres(folder.cameras_json, source=str(Path(path) / "cameras.json"))
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
