"""gsplat's exported PLY: an INRIA-layout PLY (:mod:`.ply`) in gsplat's normalised world, which nothing in the file
records (:func:`abcgs.splats.frames.gsplat_similarity` recomputes it from the scene's cameras and points). It looks
like any PLY, so it is never auto-detected: ``splat_format: gsplat_ply`` names it.
"""

from __future__ import annotations

from pathlib import Path

from abcgs.sfm.align import Similarity
from abcgs.splats import frames
from abcgs.splats.contract import SplatFormatSpec, needs_scene
from abcgs.splats.formats.ply import read, write


def frame(path: Path, scene, fields: dict) -> Similarity:
    """Scene → file: gsplat's ``normalize_world_space`` of the scene's cameras and points."""
    needs_scene("gsplat_ply", scene)
    return frames.gsplat_similarity(scene.cameras, scene.points)


FORMAT = SplatFormatSpec("gsplat_ply", read, write, frame, suffixes=(".ply",))
