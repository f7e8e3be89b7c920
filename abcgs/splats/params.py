"""Schema of a scene's trained splat (``data.scenes.<name>.splat``, ``splat_format``, ``views``).

Schema modules import nothing heavier than pydantic, so that reading ``params.yaml`` does not load the code it
configures (each stage's code dependencies stay its own: ``abcgs/dag.py``).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from abcgs.types import SplatFormat

SplatFormatParam = Literal["auto", SplatFormat]
"""``auto`` or a format of :data:`abcgs.types.SplatFormat`."""


class SplatViewsParams(BaseModel, extra="forbid"):
    """Cameras made around a splat that comes without photos or cameras (:func:`abcgs.splats.cameras.cameras_around`);
    the splat's renders from them become the scene's content images."""

    kind: Literal["auto", "orbit", "forward"] = Field(
        "auto", description="orbit: a ring around an object-centred splat; forward: a grid of views facing the splat "
        "from one side; auto: orbit when the splat's robust bounds are compact in every axis, else forward")
    count: int = Field(24, ge=3, le=1000, description="number of views")
    width: int = Field(480, ge=16, le=8192, description="image width (px)")
    height: int = Field(360, ge=16, le=8192, description="image height (px)")
    fov_deg: float = Field(50.0, gt=5.0, lt=150.0, description="horizontal field of view (degrees)")
