"""Pluggable densification strategies (the shape of gsplat's ``Strategy`` API).

A strategy owns no parameters. The trainer calls two hooks around each optimisation step::

    state = strategy.initialize_state(model)
    for step in 1..T:
        image, alpha, meta = render(model, camera)
        strategy.step_pre_backward(model, optimizers, state, step, meta)   # e.g. meta.means2d.retain_grad()
        loss.backward(); [opt.step() for opt in optimizers.values()]
        strategy.step_post_backward(model, optimizers, state, step, meta)  # grow / prune / reset

``model`` is a :class:`~abcgs.gaussians.GaussianModel` whose fields are ``nn.Parameter`` s and
``optimizers`` maps each field name to the optimiser that updates it. Hooks that add or remove
Gaussians do so through the functional operations below (:func:`duplicate`, :func:`split`,
:func:`remove`, :func:`reset_opacity`), which replace the model's tensors and keep every optimiser's
per-parameter state (Adam's ``exp_avg``/``exp_avg_sq``) the same length as its parameter.

:class:`DefaultStrategy` is the adaptive density control of 3DGS (Kerbl et al. 2023, Sec. 5.2);
:class:`NoDensification` keeps the set of Gaussians fixed (stylization).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import torch
from torch import Tensor

from abcgs.fit.params import StrategyParams
from abcgs.gaussians import PARAM_NAMES, GaussianModel
from abcgs.render import RenderMeta, quat_to_rotmat

Optimizers = dict[str, torch.optim.Optimizer]
"""One optimiser per parameter name (:data:`abcgs.gaussians.PARAM_NAMES`); missing names are frozen."""

State = dict[str, Any]
"""A strategy's running statistics; per-Gaussian tensors in it are kept in step with the model."""

SPLIT_SCALE_DIVISOR = 1.6
"""3DGS shrinks split children by 0.8·N with N = 2 samples."""


# ================================================================================================
# Functional operations on a model + its optimisers
# ================================================================================================


@torch.no_grad()
def update_params(
    model: GaussianModel,
    optimizers: Optimizers,
    param_fn: Callable[[str, Tensor], Tensor],
    optimizer_fn: Callable[[str, Tensor], Tensor],
    names: tuple[str, ...] = PARAM_NAMES,
) -> None:
    """Replace ``model.<name>`` by ``Parameter(param_fn(name, old))`` and remap the optimiser state.

    Every per-parameter optimiser state tensor shaped like the parameter (Adam's ``exp_avg``,
    ``exp_avg_sq``) becomes ``optimizer_fn(key, old_state)``; scalars such as Adam's ``step`` are kept.
    """
    for name in names:
        old = getattr(model, name)
        new = torch.nn.Parameter(param_fn(name, old.detach()).contiguous(), requires_grad=old.requires_grad)
        opt = optimizers.get(name)
        if opt is not None:
            for group in opt.param_groups:
                for i, p in enumerate(group["params"]):
                    if p is old:
                        group["params"][i] = new
                        st = opt.state.pop(p, None)
                        if st is not None:
                            opt.state[new] = {
                                k: optimizer_fn(k, v) if isinstance(v, Tensor) and v.shape == old.shape else v
                                for k, v in st.items()
                            }
        setattr(model, name, new)


def _extend_state(state: State, n_old: int, keep: Tensor | None, n_new: int) -> None:
    """Per-Gaussian state tensors: rows ``keep`` (all if None), then ``n_new`` zero rows."""
    for k, v in state.items():
        if isinstance(v, Tensor) and v.dim() > 0 and v.shape[0] == n_old:
            base = v if keep is None else v[keep]
            state[k] = torch.cat([base, v.new_zeros((n_new, *v.shape[1:]))])


@torch.no_grad()
def duplicate(model: GaussianModel, optimizers: Optimizers, state: State, mask: Tensor) -> int:
    """Clone the Gaussians in ``mask`` ``(N,)`` bool; copies are appended at the end. Returns the count.

    The copies start with zero optimiser moments (3DGS's ``densification_postfix``).
    """
    sel = torch.where(mask)[0]
    n_old = model.num_gaussians
    update_params(
        model, optimizers,
        lambda _, p: torch.cat([p, p[sel]]),
        lambda _, v: torch.cat([v, v.new_zeros((len(sel), *v.shape[1:]))]),
    )
    _extend_state(state, n_old, None, len(sel))
    return len(sel)


@torch.no_grad()
def split(
    model: GaussianModel,
    optimizers: Optimizers,
    state: State,
    mask: Tensor,
    *,
    samples: int = 2,
    generator: torch.Generator | None = None,
) -> int:
    """Replace each Gaussian in ``mask`` by ``samples`` children drawn from it. Returns the number split.

    Child means are samples of the parent's 3-D Gaussian ``N(μ, R S² Rᵀ)`` (so the children's mean
    equals the parent's in expectation); child scales are the parent's divided by 0.8·samples
    (1.6 for two); rotation, opacity and colour are copied. Survivors keep their order and optimiser
    state; the children are appended with zero moments.
    """
    sel = torch.where(mask)[0]
    rest = torch.where(~mask)[0]
    n_old = model.num_gaussians
    scales = torch.exp(model.log_scales[sel])
    rot = quat_to_rotmat(model.quats[sel])
    noise = torch.randn((samples, len(sel), 3), generator=generator, dtype=scales.dtype, device=scales.device)
    offsets = torch.einsum("nij,bnj->bni", rot, scales * noise)  # (samples, S, 3)
    divisor = 0.8 * samples

    def param_fn(name: str, p: Tensor) -> Tensor:
        if name == "means":
            children = (p[sel] + offsets).reshape(-1, 3)
        elif name == "log_scales":
            children = torch.log(scales / divisor).repeat(samples, 1)
        else:
            children = p[sel].repeat(samples, *([1] * (p.dim() - 1)))
        return torch.cat([p[rest], children])

    update_params(
        model, optimizers, param_fn,
        lambda _, v: torch.cat([v[rest], v.new_zeros((samples * len(sel), *v.shape[1:]))]),
    )
    _extend_state(state, n_old, rest, samples * len(sel))
    return len(sel)


@torch.no_grad()
def remove(model: GaussianModel, optimizers: Optimizers, state: State, mask: Tensor) -> int:
    """Delete the Gaussians in ``mask`` ``(N,)`` bool (parameters, optimiser moments, state rows)."""
    keep = torch.where(~mask)[0]
    n_old = model.num_gaussians
    update_params(model, optimizers, lambda _, p: p[keep], lambda _, v: v[keep])
    _extend_state(state, n_old, keep, 0)
    return n_old - len(keep)


@torch.no_grad()
def reset_opacity(model: GaussianModel, optimizers: Optimizers, value: float) -> None:
    """Clamp every opacity to at most ``value`` and zero the opacity optimiser moments (3DGS reset)."""
    cap = math.log(value / (1.0 - value))
    update_params(
        model, optimizers,
        lambda _, p: p.clamp_max(cap),
        lambda _, v: torch.zeros_like(v),
        names=("opacity_logits",),
    )


# ================================================================================================
# Strategies
# ================================================================================================


@dataclass
class RefineReport:
    """What one refinement did (returned by ``step_post_backward`` on refinement steps)."""

    step: int
    n_duplicated: int = 0
    n_split: int = 0
    n_pruned: int = 0
    n_gaussians: int = 0
    opacity_reset: bool = False
    capped: bool = False


@runtime_checkable
class Strategy(Protocol):
    """Densification hooks called by the trainer (see the module docstring)."""

    def initialize_state(self, model: GaussianModel) -> State: ...

    def step_pre_backward(
        self, model: GaussianModel, optimizers: Optimizers, state: State, step: int, meta: RenderMeta
    ) -> None: ...

    def step_post_backward(
        self, model: GaussianModel, optimizers: Optimizers, state: State, step: int, meta: RenderMeta
    ) -> RefineReport | None: ...


class NoDensification:
    """Keep the set of Gaussians fixed (no statistics, no growth, no pruning, no opacity reset)."""

    def initialize_state(self, model: GaussianModel) -> State:
        return {}

    def step_pre_backward(self, model, optimizers, state, step, meta) -> None:
        return None

    def step_post_backward(self, model, optimizers, state, step, meta) -> RefineReport | None:
        return None




@dataclass
class DefaultStrategy:
    """3DGS adaptive density control.

    Statistics (steps < ``refine_stop``): for Gaussians visible in the rendered view, accumulate the norm of
    the view-space positional gradient converted to NDC units (``∂L/∂x_px · W/2``, ``∂L/∂y_px · H/2``) and a
    visibility count; track the largest screen radius (px).

    Every ``refine_every`` steps after ``refine_start``: Gaussians whose mean gradient exceeds
    ``grow_grad2d`` are cloned when small (max scale ≤ ``grow_scale3d``·extent) and split into
    ``split_samples`` children when large; then Gaussians with opacity < ``prune_opacity`` are removed,
    and — after the first opacity reset — those larger than ``prune_scale3d``·extent in world space or
    ``prune_screen_px`` on screen. Every ``reset_every`` steps opacities are clamped to ``reset_opacity``.

    ``max_gaussians`` caps growth: when the candidates would exceed it, only the highest-gradient ones
    grow (pruning is unaffected).

    Args:
        params: :class:`StrategyParams`. scene_extent: scene radius in world units (3DGS: 1.1 × the largest
        camera distance from the cameras' centroid). max_gaussians: growth cap (None = unlimited).
        generator: RNG for split samples (default: torch's global RNG).
    """

    params: StrategyParams = field(default_factory=StrategyParams)
    scene_extent: float = 1.0
    max_gaussians: int | None = None
    generator: torch.Generator | None = None

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
            for k in ("grad2d", "count", "max_radii"):
                state[k] = torch.zeros(model.num_gaussians, device=model.device)
        if step % p.reset_every == 0:
            reset_opacity(model, optimizers, p.reset_opacity)
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
        sel = meta.visible
        g = grad[sel].clone()
        g[:, 0] *= meta.width / 2.0
        g[:, 1] *= meta.height / 2.0
        state["grad2d"][sel] += g.norm(dim=-1)
        state["count"][sel] += 1.0
        radii = meta.radii[sel].max(dim=-1).values.to(state["max_radii"].dtype)
        state["max_radii"][sel] = torch.maximum(state["max_radii"][sel], radii)

    @torch.no_grad()
    def _grow(self, model: GaussianModel, optimizers: Optimizers, state: State) -> tuple[int, int, bool]:
        p = self.params
        grads = state["grad2d"] / state["count"].clamp_min(1.0)
        high = grads > p.grow_grad2d
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
        return remove(model, optimizers, state, prune) if prune.any() else 0


def scene_extent(camera_centers: Tensor | Any, points: Tensor | Any | None = None) -> float:
    """3DGS's ``cameras_extent``: 1.1 × the largest distance of a camera centre from their centroid.

    Falls back to the point cloud's spread (same formula) for a single camera or co-located cameras, and
    to 1 when both are degenerate.
    """
    for pts in (camera_centers, points):
        if pts is None:
            continue
        c = torch.as_tensor(pts, dtype=torch.float64).reshape(-1, 3)
        if len(c) > 1:
            radius = float((c - c.mean(0)).norm(dim=-1).max()) * 1.1
            if radius > 1e-9 and math.isfinite(radius):
                return radius
    return 1.0
