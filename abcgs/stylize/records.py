"""What a stylization records: the logged steps of its passes (``stylize_history.csv``), the main pass's timings
and FAST counters, and the run's numbers for ``stylize.json`` (:class:`StylizeResult`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from abcgs.features import knn
from abcgs.gaussians import GaussianModel
from abcgs.losses.fast import FastStats
from abcgs.losses.params import FastParams

TIMED_PARTS = ("render", "vgg", "style_loss", "backward", "step")
"""The parts of a main-pass step timed in ``stylize.json``'s ``seconds_per_iteration``."""


@dataclass(frozen=True)
class LoggedStep:
    """One logged step of a stylization pass: a row of ``stylize_history.csv``."""

    step: int
    """The step number; the colour pass counts on from the main pass's ``iterations``."""
    seconds: float
    """Wall seconds since the pass began."""
    pass_name: Literal["main", "color"]
    loss: float
    """The step's total loss."""
    terms: dict[str, float]
    """Each loss term as it is added to ``loss`` (weighted by its λ): in the main pass those switched on of style,
    content, tv, depth, scale, opacity; in the colour pass the reconstruction's ``l1``."""

    def row(self) -> dict[str, float | int | str]:
        """The step as a table row: ``step``, ``seconds``, ``loss``, ``pass`` and the terms."""
        return {"step": self.step, "seconds": self.seconds, "loss": self.loss, "pass": self.pass_name, **self.terms}


@dataclass
class PassLog:
    """What the main pass records besides the model."""

    steps: list[LoggedStep] = field(default_factory=list)
    """Every ``stylize.compute.log_every``-th step and the last."""
    timings: dict[str, float] = field(default_factory=dict)
    """Wall seconds per part of a step (:data:`TIMED_PARTS`) summed over the steps, and ``iterations`` (the count)."""
    fast: FastStats = field(default_factory=FastStats)
    """The FAST solves' counters."""

    def add_step_times(self, ticks: list[float]) -> None:
        """Add one step's ``perf_counter`` readings at the bounds of :data:`TIMED_PARTS` to :attr:`timings`."""
        for key, t_begin, t_end in zip(TIMED_PARTS, ticks, ticks[1:]):
            self.timings[key] = self.timings.get(key, 0.0) + (t_end - t_begin)
        self.timings["iterations"] = self.timings.get("iterations", 0) + 1


@dataclass
class StylizeResult:
    """A stylization run: the stylized model and what it logged (``stylize_history.csv``, ``stylize.json``)."""

    model: GaussianModel
    history: list[LoggedStep]
    """The logged steps of the main pass, then of the colour pass."""
    timings: dict[str, float]
    fast_stats: dict
    seconds: float
    color_pass_seconds: float = 0.0
    projected_search: dict | None = None
    color_timings: dict[str, float] = field(default_factory=dict)
    """The colour pass's split (:func:`abcgs.stylize.passes.color_pass`)."""
    schedule: dict | None = None
    """The step counts run and why (:meth:`abcgs.stylize.schedule.Schedule.to_dict`)."""

    def record(self) -> dict:
        """The run's numbers for ``stylize.json``: wall time, per-iteration timings, FAST counters, size."""
        n_it = max(1, int(self.timings.get("iterations", 1)))
        return {
            "stylize_seconds": self.seconds, "iterations": int(self.timings.get("iterations", 0)),
            "seconds_per_iteration": {k: v / n_it for k, v in self.timings.items() if k != "iterations"},
            "fast": self.fast_stats, "n_gaussians": self.model.num_gaussians,
            "projected_search": self.projected_search, "schedule": self.schedule,
        }


def projected_search_record(fast_params: FastParams) -> dict | None:
    """The approximate neighbour search as it runs here (``projection_products: auto`` resolved on this CPU), or
    None when it is off; it applies to CPU searches of at least ``min_similarities`` only."""
    proj = knn.projection_of(fast_params)
    if proj is None:
        return None
    return {"rank": proj.rank, "candidates": proj.candidates, "min_similarities": proj.min_similarities,
            "products": "bfloat16" if proj.bf16_products() else "float32"}
