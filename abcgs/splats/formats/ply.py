"""Any INRIA-layout PLY (SH degree 0–3; OpenSplat's with ``--keep-crs``, …), in the scene's frame. Read and written
by :mod:`abcgs.gaussians.ply` in the source's own property layout. The other PLY formats (:mod:`.gsplat_ply`,
:mod:`.opensplat`, :mod:`.splatfacto`) read and write their file with :func:`read` and :func:`write` and differ in
their frame.
"""

from __future__ import annotations

import os
from pathlib import Path

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.gaussians.ply import PlyLayout, read_ply_layout, write_ply
from abcgs.io.atomic import write_text
from abcgs.splats.contract import SplatFormatSpec, SplatProvenance


def is_compressed_ply(path: str | os.PathLike) -> bool:
    """Whether ``path``'s header declares a ``chunk`` element and packed ``vertex`` properties (SuperSplat's
    compressed PLY, :mod:`.supersplat`)."""
    with open(path, "rb") as f:
        head = f.read(4096).split(b"end_header")[0]
    return b"element chunk" in head and b"packed_position" in head


def is_ply(path: Path) -> bool:
    """Whether ``path`` is a ``.ply`` file; :class:`InputError` when it is one without the PLY magic line."""
    if path.suffix.lower() != ".ply" or not path.is_file():
        return False
    with open(path, "rb") as f:
        if not f.read(4).startswith(b"ply"):
            raise InputError(f"{path} is not a PLY file (it does not start with the 'ply' magic line)")
    return True


def read_file(ply: Path, drop_invalid: bool) -> tuple[GaussianModel, dict]:
    """An INRIA-layout PLY file and its property layout (a SuperSplat compressed PLY is refused: it has its own
    format)."""
    if is_compressed_ply(ply):
        raise InputError(f"{ply} is a SuperSplat compressed PLY; set splat_format: supersplat (or auto)")
    model, layout, _ = read_ply_layout(ply, drop_invalid=drop_invalid)
    return model, {"ply_layout": layout.to_list()}


def read(path: Path, drop_invalid: bool) -> tuple[GaussianModel, dict]:
    return read_file(path, drop_invalid)


def write(model: GaussianModel, path: Path, like: SplatProvenance) -> None:
    """The PLY in the source's property layout, and the source's side files beside it."""
    write_ply(path, model, PlyLayout.from_list(like.ply_layout) if like.ply_layout else None)
    for name, text in like.side_files.items():
        write_text(path.parent / name, text)


FORMAT = SplatFormatSpec("ply", read, write, detect=is_ply, rank=90, suffixes=(".ply",))
