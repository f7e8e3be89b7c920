"""The ``tiny`` section's schema: the embedded synthetic scene (:mod:`abcgs.scene.synthetic`).

Schema modules import nothing heavier than pydantic, so that reading ``params.yaml`` does not load the code
it configures (each stage's code dependencies stay its own: ``abcgs/dag.py``).
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from abcgs.sections import SEED, Bound, Bounded


class TinySceneParams(Bounded, extra="forbid"):
    """Knobs of the embedded scene. Lengths in scene units, sizes in pixels."""

    seed: int = 0
    n_views: int = Field(16, ge=3, le=64, description="number of views on the forward-facing grid")
    width: int = Field(160, ge=32, le=2048, description="view width in pixels")
    height: int = Field(120, ge=32, le=2048, description="view height in pixels")
    focal_factor: float = Field(0.85, gt=0.1, le=5.0, description="focal length in units of the view width")
    baseline: float = Field(1.2, gt=0.0, le=5.0, description="horizontal extent of the camera grid (scene units)")
    wall_depth: float = Field(6.0, gt=1.0, description="distance of the back wall from the camera plane")
    supersample: int = Field(2, ge=1, le=4, description="rays per pixel along each axis (anti-aliasing)")
    style_height: int = Field(256, ge=32, le=2048, description="height of the generated paintings in pixels")
    layout: Literal["forward", "orbit", "object"] = Field(
        "forward", description="forward: a wall behind the objects, cameras on a forward-facing grid; orbit: the "
                               "objects inside a textured dome, cameras on a ring all around them; object: the objects "
                               "on nothing (RGBA views, alpha = coverage), cameras on three rings around and above them "
                               "(abcgs.scene.synthetic.write_object_dataset writes it as a NeRF-synthetic dataset)")
    mask_views: int = Field(0, ge=0, description="write label maps for the first this many views only (0: all); "
                                                 "e.g. 1 = one user mask to lift")
    odd_view_width_delta: int = Field(
        0, ge=0, le=64,
        description="odd-numbered views are this many pixels narrower (a second camera with the same lens and a "
                    "cropped sensor, as COLMAP gives each camera its own undistorted size); 0: one camera",
    )

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "seed": SEED,
        "wall_depth": Bound(1.0, 1000.0, "scene units (the camera grid spans 1.2); a wall 1000 away is no backdrop"),
        "mask_views": Bound(0, 64, "views with a label map; the scene has at most 64 views (n_views)"),
    }


TINY_STYLE_FILES = ("styles/paint.png", "styles/paint2.png", "styles/paint_labels.png")
"""The paintings and the painting label map ``make_tiny`` writes into the tiny scene folder, relative to it
(:func:`abcgs.scene.synthetic.write_tiny_scene`): the files there that ``data.styles`` / ``data.style_masks`` can
name. ``preflight`` checks such paths against this list, before the folder exists."""
