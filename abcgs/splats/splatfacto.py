"""nerfstudio splatfacto exports: ``ns-export gaussian-splat`` writes an INRIA-layout PLY in nerfstudio's world,
which is the dataset's frame moved by the run's ``dataparser_transforms.json`` (:func:`abcgs.splats.frames.nerfstudio_similarity`).
That file sits in the run folder (``outputs/<name>/splatfacto/<timestamp>/``) and is looked for next to the PLY and in
up to three parent folders, or inside a folder given instead of the PLY.
"""

from __future__ import annotations

from pathlib import Path

from abcgs.errors import InputError

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
