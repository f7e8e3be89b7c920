"""Format ``nerfstudio``: ``transforms.json`` and the images it names (:mod:`abcgs.sources.nerfstudio` reads it)."""

from __future__ import annotations

from typing import Literal

from abcgs.sources.base import ImagesSource, SceneReader
from abcgs.sources.detect import present


class NerfstudioSource(ImagesSource):
    """``source: {format: nerfstudio}``: ``transforms.json`` and the images it names (``images``: where they are
    when not where the file says)."""

    format: Literal["nerfstudio"] = "nerfstudio"



READER = SceneReader("nerfstudio", "nerfstudio:read", "transforms.json", detect=lambda folder: present(folder / "transforms.json"),
                     priority=20, order=30, options=NerfstudioSource)
