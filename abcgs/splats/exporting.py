"""Giving a stylized scene back in the format, frame and layout of the splat it was imported from.

    give_back("out/garden_x/stylize/point_cloud.ply", "out/garden/gs/splat_source.json", "out/garden_x/returned")

writes ``returned/<the source's file name>`` (:func:`abcgs.splats.registry.write_splat`) and ``returned/returned.json``
(the format, the file, the SH degree, whether the frame was moved). A scene fitted from its photos has no other
format to go back to: the folder then holds ``returned.json`` alone, saying so.
"""

from __future__ import annotations

import os
from pathlib import Path

from abcgs.gaussians.ply import read_ply
from abcgs.io.atomic import atomic_path, write_json
from abcgs.splats import frames
from abcgs.splats.registry import read_provenance, returned_name, write_splat


def give_back(ply: str | os.PathLike, source: str | os.PathLike, out_dir: str | os.PathLike) -> dict:
    """Write the scene ``ply`` (the scene's frame) as its source was (``source``: the fit stage's
    ``splat_source.json``) into ``out_dir`` (replaced atomically). Returns the ``returned.json`` record."""
    prov = read_provenance(source)
    with atomic_path(out_dir, is_dir=True) as tmp:
        if prov is None:
            record = {"format": None, "file": None, "note": "fitted from the photos: the scene's PLY and .spz are its exports"}
        else:
            model = read_ply(ply)
            name = returned_name(prov)
            write_splat(model, tmp / name, prov)
            record = {"format": prov.format, "file": name, "source": prov.source, "sh_degree": model.sh_degree,
                      "n_gaussians": model.num_gaussians,
                      "frame_moved": not frames.is_identity(prov.similarity)}
        write_json(Path(tmp) / "returned.json", record)
    return record
