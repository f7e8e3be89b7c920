"""Format ``splat``: a scene that is only a trained splat (a splat file, or a folder holding one and nothing but
``masks/``); cameras are made around it and its renders are the photos (:mod:`abcgs.sources.bare_splat`). An object on
black unless the scene's entry names a ``background``."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from abcgs.sources.base import SceneReader, Source
from abcgs.sources.detect import is_bare_splat
from abcgs.splats.params import SplatViewsParams


class SplatSource(Source):
    """``source: {format: splat}``: only a trained splat; ``views``: the cameras made around it."""

    format: Literal["splat"] = "splat"
    views: SplatViewsParams | None = Field(
        None, description="the cameras made around the splat (count, size, field of view, kind)")



READER = SceneReader("splat", "bare_splat:read", "the splat file", detect=is_bare_splat, priority=60, order=60,
                     options=SplatSource, cameras="made", background=(0.0, 0.0, 0.0))
