"""Format ``llff``: ``poses_bounds.npy`` and the sorted images of ``images/`` (:mod:`abcgs.sources.llff` reads it)."""

from __future__ import annotations

from typing import Literal

from abcgs.sources.base import ImagesSource, SceneReader
from abcgs.sources.detect import present


class LlffSource(ImagesSource):
    """``source: {format: llff}``: ``poses_bounds.npy`` and the sorted images of ``images``."""

    format: Literal["llff"] = "llff"



READER = SceneReader("llff", "llff:read", "poses_bounds.npy", detect=lambda folder: present(folder / "poses_bounds.npy"),
                     priority=40, order=40, options=LlffSource)
