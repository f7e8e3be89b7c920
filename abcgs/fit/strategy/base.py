"""The hooks a densification strategy gives the training loop, what a refinement reports, and the strategy that
changes nothing (gsplat's ``strategy/base.py``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from abcgs.fit.strategy.ops import Optimizers, State
from abcgs.gaussians import GaussianModel
from abcgs.render import RenderMeta


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
    """Densification hooks called by the trainer (see :mod:`abcgs.fit.strategy`)."""

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
