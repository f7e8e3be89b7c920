"""Differentiable 3-D Gaussian rasterization: one functional API, interchangeable backends.

See :func:`rasterize` and :func:`accumulate_weights`.
"""

from abcgs.render.cpu import BackendUnavailable
from abcgs.render.projection import Projected, project_gaussians, quat_to_rotmat
from abcgs.render.rasterize import BACKENDS, accumulate_weights, rasterize, select_backend
from abcgs.render.sh import eval_sh, num_sh_bases, rgb_to_sh0, sh0_to_rgb
from abcgs.types import RenderMeta

__all__ = [
    "BACKENDS",
    "BackendUnavailable",
    "Projected",
    "RenderMeta",
    "accumulate_weights",
    "eval_sh",
    "num_sh_bases",
    "project_gaussians",
    "quat_to_rotmat",
    "rasterize",
    "rgb_to_sh0",
    "select_backend",
    "sh0_to_rgb",
]
