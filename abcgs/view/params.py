"""The ``viewer`` section's schema: the 3-D viewer in the report and the turntable's camera path.

Schema modules import nothing heavier than pydantic, so that reading ``params.yaml`` does not load the code
it configures (each stage's code dependencies stay its own: ``abcgs/dag.py``).
"""

from __future__ import annotations

from typing import ClassVar

from pydantic import ConfigDict, Field

from abcgs.sections import Bound, Bounded, unbounded_field
from abcgs.types import PathKind


class ViewerParams(Bounded):
    """``params.yaml``: ``viewer`` (the 3-D viewer in the report)."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(True, description="embed the splat viewer in reports/report.html")
    max_gaussians: int = Field(150_000, ge=100, description="Gaussians per layer on the page (most visible kept; "
                               "the PSNR of fewer against the full render: docs/RENDERING.md, 'The browser viewer')")
    max_width: int = Field(960, ge=64, description="largest canvas width in CSS pixels")
    camera_path: PathKind = Field(
        "auto", description="path of the turntable video and the viewer's ▷ button: orbit (object-centred "
                            "captures), spiral (forward-facing) or auto (detected from the camera layout)")
    path_frames: int = Field(48, ge=2, le=1000, description="cameras on the path (the video plays 24 per second)")
    unbounded: list[str] = unbounded_field()

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "max_gaussians": Bound(100, 10_000_000, soft=True, why=(
            "the page inlines every layer: 10 M Gaussians make a page of several hundred MB, more than a browser "
            "opens")),
        "max_width": Bound(64, 16_384, unit="CSS px", why="a canvas wider than any screen"),
    }
