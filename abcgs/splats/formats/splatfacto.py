"""nerfstudio splatfacto exports: ``ns-export gaussian-splat`` writes an INRIA-layout PLY in nerfstudio's world,
which is the dataset's frame moved by the run's ``dataparser_transforms.json`` (:func:`abcgs.splats.frames.nerfstudio_similarity`).
That file sits in the run folder (``outputs/<name>/splatfacto/<timestamp>/``) and is looked for next to the PLY and in
up to three parent folders, or inside a folder given instead of the PLY.
"""

from __future__ import annotations

from pathlib import Path

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.io.guarded import read_text
from abcgs.sfm.align import Similarity
from abcgs.splats import frames
from abcgs.splats.contract import SplatFormatSpec
from abcgs.splats.formats import ply

TRANSFORMS = "dataparser_transforms.json"


def find_transforms(path: Path) -> Path | None:
    """The ``dataparser_transforms.json`` of a splatfacto export (``path``: the PLY or a folder), or ``None``."""
    start = path if path.is_dir() else path.parent
    for folder in [start, *list(start.parents)[:3]]:
        if (folder / TRANSFORMS).is_file():
            return folder / TRANSFORMS
    return None


def splatfacto_ply(path: Path) -> Path:
    """The exported PLY: ``path`` itself, or the one PLY in the folder ``path``."""
    if path.is_file():
        return path
    plys = sorted(path.glob("*.ply"))
    if len(plys) != 1:
        raise InputError(f"{path}: expected one exported .ply in the splatfacto folder, found {len(plys)}; name the PLY "
                         "written by ns-export gaussian-splat")
    return plys[0]


def detect(path: Path) -> bool:
    """A folder with a PLY and a transforms file, or a PLY with one next to it or above."""
    if path.is_dir():
        return find_transforms(path) is not None and any(path.glob("*.ply"))
    return ply.is_ply(path) and find_transforms(path) is not None


def read(path: Path, drop_invalid: bool) -> tuple[GaussianModel, dict]:
    """The exported PLY, and the run's transforms file as a side file (without it the frame cannot be undone)."""
    model, fields = ply.read_file(splatfacto_ply(path), drop_invalid)
    tf = find_transforms(path)
    if tf is None:
        raise InputError(f"{path}: no {TRANSFORMS} next to the PLY or above it; copy the splatfacto run's "
                         f"{TRANSFORMS} beside the exported PLY (its frame cannot be undone without it)")
    frames.nerfstudio_similarity(tf)  # checked now: a side file is written back beside the returned splat
    return model, {**fields, "side_files": {TRANSFORMS: read_text(tf, TRANSFORMS, frames.MAX_TRANSFORMS_BYTES)}}


def frame(path: Path, scene, fields: dict) -> Similarity:
    """Scene → file: nerfstudio's dataparser transform."""
    return frames.nerfstudio_similarity(find_transforms(path))


FORMAT = SplatFormatSpec("splatfacto", read, ply.write, frame, detect=detect, rank=30, suffixes=(".ply",))
