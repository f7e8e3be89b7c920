"""The colour pass's views replayed: with its geometry frozen, each view's blending map is recorded once
(:mod:`abcgs.render.frozen`) and every later render of that view is a sparse product in the DC colours.

It applies when nothing but the DC colours changes: rotations frozen (``stylize.color_only`` or
``stylize.optim.color_pass_rotations: false``), the higher SH bands frozen (``higher_sh`` zero or frozen), the
CPU rasterizer and float32. Maps are kept up to :data:`MAP_BUDGET_BYTES` in all; a view past the budget renders
as before. A replayed render equals the rasterizer's (``tests/test_render_frozen.py``).
"""

from __future__ import annotations

import torch
from torch import Tensor

from abcgs.cameras import Camera
from abcgs.gaussians import GaussianModel, render
from abcgs.render.frozen import FrozenView, record_view, render_frozen
from abcgs.render.rasterize import select_backend
from abcgs.types import Backend

MAP_BUDGET_BYTES = 2 * 2**30
"""Memory for the recorded maps of one colour pass (a 3 M-Gaussian view at 504 × 378 holds about 120 MiB)."""


def can_replay(model: GaussianModel, backend: Backend, trained: dict[str, float]) -> bool:
    """Whether a pass that trains the fields ``trained`` (name → learning rate) leaves every view's blending map
    fixed and runs where maps can be replayed (the CPU kernels, float32)."""
    moving = {name for name, lr in trained.items() if lr > 0}
    return (moving <= {"sh0"} and model.sh0.dtype == torch.float32
            and select_backend(model.device, backend) == "cpu")


class ReplayedViews:
    """Renders of ``cameras`` for a pass in which only ``model.sh0`` changes: each view's map is recorded at its
    first render (within :data:`MAP_BUDGET_BYTES`), later renders replay it."""

    def __init__(self, model: GaussianModel, cameras: list[Camera], backend: Backend = "auto",
                 budget_bytes: int = MAP_BUDGET_BYTES):
        self.model, self.cameras, self.backend, self.budget = model, cameras, backend, budget_bytes
        self.views: dict[int, FrozenView] = {}
        self.held = 0

    def render(self, i: int, background: Tensor | None) -> Tensor:
        """Image ``(H, W, 3)`` of view ``i``, differentiable in ``model.sh0``."""
        view = self.views.get(i)
        if view is None and self.held < self.budget:
            m, cam = self.model, self.cameras[i]
            view = record_view(m.means.detach(), m.quats.detach(), m.scales.detach(), m.opacities.detach(),
                               m.shN.detach(), m.sh_degree, cam.torch_viewmat(m.device), cam.torch_K(m.device),
                               cam.width, cam.height)
            self.views[i] = view
            self.held += view.nbytes
        if view is None:
            return render(self.model, self.cameras[i], backend=self.backend, background=background)[0]
        return render_frozen(view, self.model.sh0, background)[0]
