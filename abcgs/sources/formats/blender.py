"""Format ``blender``: NeRF-synthetic's ``transforms_{train,test}.json`` and RGBA images, an object on white unless
the scene's entry names a ``background`` (:mod:`abcgs.sources.blender` reads it)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from abcgs.sources.base import SceneReader, Source
from abcgs.sources.detect import present


class BlenderSource(Source):
    """``source: {format: blender}``: NeRF-synthetic's ``transforms_{train,test}.json`` (no options)."""

    format: Literal["blender"] = "blender"



def _detect(folder: Path) -> bool:
    return present(folder / "transforms_train.json")


READER = SceneReader("blender", "blender:read", "transforms_train.json", detect=_detect, priority=10, order=50,
                     options=BlenderSource, background=(1.0, 1.0, 1.0))
