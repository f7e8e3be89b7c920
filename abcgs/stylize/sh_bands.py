"""The SH bands above DC while a scene is stylized (``stylize.higher_sh``): which bands a pass starts from, trains
and renders.

- ``zero``: the colour match zeroed them; they stay zero and the passes render at degree 0 (:func:`render_sh_degree`).
- ``frozen``: the original scene's bands, kept as they are.
- ``optimized``: the original's bands, trained at ``optim.lr_shN``.
- ``degree1``: band 1 of the original, trained; bands 2-3 zero and kept there (:func:`keep_bands_above_1_zero`).
"""

from __future__ import annotations

import torch

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel, fitted_rows
from abcgs.stylize.params import StylizeParams


def with_higher_sh(model: GaussianModel, original: GaussianModel, mode: str) -> GaussianModel:
    """``model`` with the SH bands above DC that ``stylize.higher_sh = mode`` starts from: ``zero`` leaves them as
    they are (the colour match zeroed them), ``frozen``/``optimized`` put the ``original``'s back, ``degree1`` puts
    back band 1 and zeroes bands 2–3. A re-fitted ``model`` takes the bands of the fitted Gaussian each of its
    Gaussians descends from (:func:`~abcgs.gaussians.fitted_rows`)."""
    if mode == "zero" or not model.shN.numel():
        return model
    if original.shN.shape[1:] != model.shN.shape[1:]:
        raise InputError(f"higher_sh={mode}: the original scene has SH shape {tuple(original.shN.shape)}, the colour-"
                         f"matched one {tuple(model.shN.shape)}; re-run the colormatch stage")
    out = model.detach()
    shn = original.shN.detach()[fitted_rows(model).to(original.device)]
    if mode == "degree1":
        shn[:, 3:] = 0.0
    out.shN = shn.contiguous()
    return out


def keep_bands_above_1_zero(model: GaussianModel, params: StylizeParams) -> None:
    """``degree1``: bands 2–3 get no gradient, so Adam leaves them at zero (a degree-1 scene in degree-3 storage)."""
    if params.higher_sh == "degree1" and model.shN.shape[1] > 3 and model.shN.requires_grad:
        model.shN.register_hook(lambda g: torch.cat([g[:, :3], torch.zeros_like(g[:, 3:])], dim=1))


def higher_sh_lr(params: StylizeParams, model: GaussianModel) -> float:
    """The higher SH bands' learning rate: ``optim.lr_shN`` when ``higher_sh`` optimises them (and the scene has them)."""
    return params.optim.lr_shN if params.higher_sh in ("optimized", "degree1") and model.shN.numel() else 0.0


def render_sh_degree(model: GaussianModel, lrs: dict[str, float]) -> int | None:
    """The SH degree a pass renders ``model`` at: 0 when its higher bands are all zero and not trained
    (``higher_sh: zero``), which gives the same colours and gradients without reading the 45 zeros of every Gaussian
    each render (0.5 GB a step at 3 M Gaussians); otherwise every stored band (``None``)."""
    if model.shN.numel() and lrs.get("shN", 0.0) == 0.0 and not bool(model.shN.detach().any()):
        return 0
    return None
