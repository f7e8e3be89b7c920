"""The adaptive density control of 3DGS (Kerbl et al. 2023, Sec. 5.2; gsplat's ``strategy/default.py``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from abcgs.fit.params import REFERENCE_ITERATIONS, StrategyParams
from abcgs.fit.strategy.base import RefineReport
from abcgs.fit.strategy.ops import Optimizers, State, duplicate, remove, reset_opacity, split
from abcgs.gaussians import FROZEN, GaussianModel
from abcgs.render import RenderMeta


@dataclass
class DefaultStrategy:
    """3DGS adaptive density control.

    Statistics (steps < ``refine_stop``): for Gaussians visible in the rendered view, accumulate the norm of
    the view-space positional gradient converted to NDC units (``∂L/∂x_px · W/2``, ``∂L/∂y_px · H/2``) and a
    visibility count; track the largest screen radius (px). A step that renders C views (batched ``meta``)
    adds each view's norm and counts each view.

    Every ``refine_every`` steps after ``refine_start``: Gaussians whose mean gradient exceeds
    ``grow_grad2d`` are cloned when small (max scale ≤ ``grow_scale3d``·extent) and split into
    ``split_samples`` children when large; then Gaussians with opacity < ``prune_opacity`` are removed,
    and — after the first opacity reset — those larger than ``prune_scale3d``·extent in world space or
    ``prune_screen_px`` on screen. Every ``reset_every`` steps opacities are clamped to ``reset_opacity``.

    Gaussians marked :data:`~abcgs.gaussians.FROZEN` are never cloned, split, pruned or reset.

    ``max_gaussians`` caps growth: when the candidates would exceed it, only the highest-gradient ones
    grow (pruning is unaffected).

    Args:
        params: :class:`StrategyParams`, its schedule resolved for the run (:meth:`StrategyParams.resolved`; step
        fields left unset take the 3DGS reference schedule's values). scene_extent: scene radius in world units (3DGS: 1.1 × the largest
        camera distance from the cameras' centroid). max_gaussians: growth cap (None = unlimited).
        generator: RNG for split samples (default: torch's global RNG).
    """

    params: StrategyParams = field(default_factory=StrategyParams)
    scene_extent: float = 1.0
    max_gaussians: int | None = None
    generator: torch.Generator | None = None

    def __post_init__(self) -> None:
        self.params = self.params.resolved(REFERENCE_ITERATIONS)

    def initialize_state(self, model: GaussianModel) -> State:
        n, dev = model.num_gaussians, model.device
        return {
            "grad2d": torch.zeros(n, device=dev),
            "count": torch.zeros(n, device=dev),
            "max_radii": torch.zeros(n, device=dev),
        }

    def step_pre_backward(self, model, optimizers, state, step, meta: RenderMeta) -> None:
        if step < self.params.refine_stop and meta.means2d.requires_grad:
            meta.means2d.retain_grad()

    def step_post_backward(
        self, model: GaussianModel, optimizers: Optimizers, state: State, step: int, meta: RenderMeta
    ) -> RefineReport | None:
        p = self.params
        if step >= p.refine_stop:
            return None
        self._update_state(state, meta, model.num_gaussians)
        report = None
        if step > p.refine_start and step % p.refine_every == 0:
            report = RefineReport(step)
            report.n_duplicated, report.n_split, report.capped = self._grow(model, optimizers, state)
            report.n_pruned = self._prune(model, optimizers, state, step)
            state.update(self.initialize_state(model))
        if step % p.reset_every == 0:
            reset_opacity(model, optimizers, p.reset_opacity, keep=model.attributes.get(FROZEN))
            report = report or RefineReport(step)
            report.opacity_reset = True
        if report is not None:
            report.n_gaussians = model.num_gaussians
        return report

    # ------------------------------------------------------------------ internals
    @torch.no_grad()
    def _update_state(self, state: State, meta: RenderMeta, n: int) -> None:
        grad = meta.means2d.grad
        if grad is None:
            raise RuntimeError(
                "DefaultStrategy: meta.means2d has no gradient; call step_pre_backward before loss.backward()"
            )
        if state["grad2d"].shape[0] != n:
            raise RuntimeError(f"DefaultStrategy: state has {state['grad2d'].shape[0]} rows but the model {n} Gaussians")
        # a batched render (C cameras) counts each view it is visible in, its gradient per view (gsplat's rule)
        batched = grad.dim() == 3
        sel = meta.visible if batched else meta.visible[None]
        ids = sel.nonzero()[:, 1]
        g = (grad if batched else grad[None])[sel].clone()
        g[:, 0] *= meta.width / 2.0
        g[:, 1] *= meta.height / 2.0
        state["grad2d"].index_add_(0, ids, g.norm(dim=-1).to(state["grad2d"].dtype))
        state["count"].index_add_(0, ids, torch.ones_like(ids, dtype=state["count"].dtype))
        radii = (meta.radii if batched else meta.radii[None])[sel].max(dim=-1).values.to(state["max_radii"].dtype)
        state["max_radii"].scatter_reduce_(0, ids, radii, "amax")

    @torch.no_grad()
    def _grow(self, model: GaussianModel, optimizers: Optimizers, state: State) -> tuple[int, int, bool]:
        p = self.params
        grads = state["grad2d"] / state["count"].clamp_min(1.0)
        high = grads > p.grow_grad2d
        if FROZEN in model.attributes:
            high &= ~model.attributes[FROZEN]
        small = torch.exp(model.log_scales).max(dim=-1).values <= p.grow_scale3d * self.scene_extent
        is_dup, is_split = high & small, high & ~small
        capped = False
        if self.max_gaussians is not None:
            budget = max(0, self.max_gaussians - model.num_gaussians)
            cand = torch.where(is_dup | is_split)[0]
            if len(cand) > budget:
                capped = True
                keep = cand[torch.argsort(grads[cand], descending=True, stable=True)[:budget]]
                allowed = torch.zeros_like(high)
                allowed[keep] = True
                is_dup, is_split = is_dup & allowed, is_split & allowed
        n_dup = duplicate(model, optimizers, state, is_dup) if is_dup.any() else 0
        # the clones just appended are not split in the same round
        is_split = torch.cat([is_split, is_split.new_zeros(n_dup)])
        n_split = (
            split(model, optimizers, state, is_split, samples=p.split_samples, generator=self.generator)
            if is_split.any() else 0
        )
        return n_dup, n_split, capped

    @torch.no_grad()
    def _prune(self, model: GaussianModel, optimizers: Optimizers, state: State, step: int) -> int:
        p = self.params
        prune = torch.sigmoid(model.opacity_logits) < p.prune_opacity
        if step > p.reset_every:
            prune |= torch.exp(model.log_scales).max(dim=-1).values > p.prune_scale3d * self.scene_extent
            prune |= state["max_radii"] > p.prune_screen_px
        if FROZEN in model.attributes:
            prune &= ~model.attributes[FROZEN]
        return remove(model, optimizers, state, prune) if prune.any() else 0
