"""OpenSplat's PLY trained without ``--keep-crs``: an INRIA-layout PLY (:mod:`.ply`) centred and scaled by OpenSplat
(:func:`abcgs.splats.frames.opensplat_similarity` recomputes it from the scene's cameras). It looks like any PLY, so
it is never auto-detected: ``splat_format: opensplat`` names it.
"""

from __future__ import annotations

from pathlib import Path

from abcgs.sfm.align import Similarity
from abcgs.splats import frames
from abcgs.splats.contract import SplatFormatSpec, needs_scene
from abcgs.splats.formats.ply import read, write


def frame(path: Path, scene, fields: dict) -> Similarity:
    """Scene → file: OpenSplat's centring and scaling of the scene's cameras."""
    needs_scene("opensplat", scene)
    return frames.opensplat_similarity(scene.cameras)


FORMAT = SplatFormatSpec("opensplat", read, write, frame, suffixes=(".ply",))
