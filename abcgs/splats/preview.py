"""A preview of a large splat: keep the Gaussians that contribute most, drop the rest.

    small = decimate(model, 300_000)

Importance is ``opacity × σ_max²``, each Gaussian's opacity times the area of its largest cross-section (what it can
cover on screen, up to the camera distance): the faint and the tiny go first. Deterministic (a stable sort; ties
keep file order). A decimated scene is a preview — it stylizes in a fraction of the time and memory but gives back
fewer Gaussians than it came with (``fit.import_max_gaussians``; the full scene runs without it).
"""

from __future__ import annotations

import torch

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel


def importance(model: GaussianModel) -> torch.Tensor:
    """``(N,)`` opacity × largest variance (world units²)."""
    with torch.no_grad():
        return model.opacities * torch.exp(2 * model.log_scales.max(dim=1).values)


def decimate(model: GaussianModel, keep: int) -> GaussianModel:
    """The ``keep`` most important Gaussians of ``model`` in their original order (all of them when it has fewer)."""
    if keep < 1:
        raise InputError(f"a preview must keep at least one Gaussian, got {keep}")
    if model.num_gaussians <= keep:
        return model.detach()
    order = torch.sort(importance(model), descending=True, stable=True).indices[:keep]
    return model.index(torch.sort(order).values)
