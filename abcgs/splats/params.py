"""Schema of a scene's trained splat (``data.scenes.<name>.splat``, ``splat_format``, ``views``).

Schema modules import nothing heavier than pydantic, so that reading ``params.yaml`` does not load the code it
configures (each stage's code dependencies stay its own: ``abcgs/dag.py``).
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from abcgs.sections import Bound, Bounded
from abcgs.types import SplatFormat

SplatFormatParam = Literal["auto", SplatFormat]
UpAxis = Literal["auto", "+x", "-x", "+y", "-y", "+z", "-z"]
"""A world axis that is up in generated views, or ``auto`` (``-y``)."""
"""``auto`` or a format of :data:`abcgs.types.SplatFormat`."""


class SplatViewsParams(Bounded, extra="forbid"):
    """Cameras made around a splat that comes without photos or cameras (:func:`abcgs.splats.cameras.cameras_around`);
    the splat's renders from them become the scene's content images."""

    kind: Literal["auto", "orbit", "forward"] = Field(
        "auto", description="orbit: rings of views at several elevations all round an object, each framing every "
        "Gaussian that matters; forward: a grid of views facing the splat from one side, spread over `parallax_deg`; "
        "auto: forward when the Gaussians grow away from one side (a splat trained from there), else orbit")
    count: int = Field(24, ge=3, le=1000, description="number of views")
    width: int = Field(480, ge=16, le=8192, description="image width (px)")
    height: int = Field(360, ge=16, le=8192, description="image height (px)")
    fov_deg: float = Field(50.0, gt=5.0, lt=150.0, description="horizontal field of view (degrees)")
    up: UpAxis = Field(
        "auto", description="the world direction that is up in every view: +x, -x, +y, -y, +z or -z; auto: -y, the "
        "convention of the COLMAP/INRIA frame that 3DGS trainers save splats in (use +z for a splat trained on "
        "NeRF-synthetic or Blender data)")
    elevation_deg: tuple[float, float] = Field(
        (0.0, 60.0), description="orbit: the lowest and highest ring's elevation above the horizon (degrees); the "
        "rings are spread evenly between them")
    parallax_deg: float = Field(40.0, ge=0.0, le=120.0, description="forward: the angle between the outermost views "
                                "(degrees), seen from the splat's centre")
    min_opacity: float = Field(0.1, ge=0.0, le=1.0, description="orbit: the Gaussians at least this opaque lie inside "
                               "every view, with two standard deviations around their centres")

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "elevation_deg": Bound(-90.0, 90.0, unit="degrees", why="an elevation above the horizon: 90 looks straight "
                               "down"),
    }
