"""Format ``colmap``: a COLMAP model (``sparse/0/`` or ``sparse/``) and its images (:mod:`abcgs.sources.colmap`
reads it). An LLFF release that ships its model beside ``poses_bounds.npy`` is detected as this (the model carries the
sparse points and the exact intrinsics the poses were made from); ``format: llff`` reads the poses instead."""

from __future__ import annotations

from typing import Literal

from abcgs.sources.base import ImagesSource, SceneReader
from abcgs.sources.detect import colmap_model_dir


class ColmapSource(ImagesSource):
    """``source: {format: colmap}``: a COLMAP model (``sparse/0``) and its images."""

    format: Literal["colmap"] = "colmap"



READER = SceneReader("colmap", "colmap:read", "sparse/0", detect=lambda folder: colmap_model_dir(folder) is not None,
                     priority=30, order=20, options=ColmapSource)
