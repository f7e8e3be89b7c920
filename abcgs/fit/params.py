"""The ``fit`` section's schema: the baseline 3DGS fit (:mod:`abcgs.fit.training`) and its densification
strategy (:mod:`abcgs.fit.strategy`).

Schema modules import nothing heavier than pydantic, so that reading ``params.yaml`` does not load the code
it configures (each stage's code dependencies stay its own: ``abcgs/dag.py``).
"""

from __future__ import annotations

from dataclasses import replace
from typing import ClassVar, Literal

from pydantic import Field, field_validator, model_validator

from abcgs.sections import LEARNING_RATE, MAX_THREADS, RESOLUTION_SCALE, SEED, Bound, Bounded, unbounded_field

MIN_RESET_EVERY = 3000
"""The fewest steps between two opacity resets of a schedule left to follow the run's length: 3DGS's own interval.
Resets only fall while densifying (until half the run), so runs of up to 6000 steps reset none. Closer resets cost
the tiny scene's fit held-out PSNR at every length measured: one reset at step 1000 of 3000 holds it out at 34.7 dB,
none at 36.3 dB; two (1000 and 2000 of 6000) at 31.8 dB, none at 35.5 dB (``python -m eval run fit_schedule``,
docs/SCALING.md "The fit's schedule")."""

MAX_FIT_ITERATIONS = 2_000_000
"""The most fit steps a params file asks for without ``unbounded: [iterations]``: 67 times 3DGS's 30 000-step
reference fit (``1000000000000``, a typo, passed every check and started a fit)."""
MIN_CHECKED_ITERATIONS = 35
"""The fewest fit steps while the fit check's PSNR floor is on (``fit.min_psnr`` > 0): the embedded tiny scene, the
easiest scene measured, first holds out over the default 15 dB floor at 35 steps (11.6 dB after 1 step, 13.2 dB
after 10, 14.7 dB after 30; 15.1 dB after 35, 15.9 dB after 50), so a shorter fit is refused by the check after it
ran."""
MIN_REFINE_EVERY = 10
"""The fewest steps between two densifications a params file sets: the schedule that follows the run's length never
densifies more often (:meth:`StrategyParams.resolved`); densifying every step clones and splits on one step's
gradient (the colour re-fit of the tiny scene, every step: 54 773 → 470 409 Gaussians while its PSNR fell)."""
MIN_SET_RESET_EVERY = 100
"""The fewest steps between two opacity resets a params file sets: a reset clamps every opacity to
``reset_opacity``, and the densification needs hundreds of steps to regrow what it then prunes (3DGS: 3000)."""


def _steps(lo: int = 0, low: str = "") -> Bound:
    """The soft range of a step number or interval of a fit: ``lo`` .. :data:`MAX_FIT_ITERATIONS` (``low``: why not
    fewer)."""
    return Bound(lo, MAX_FIT_ITERATIONS, f"a fit has at most {MAX_FIT_ITERATIONS} steps (the range of fit.iterations)",
                 low=low, soft=True, unit="steps")


class StrategyParams(Bounded, extra="forbid"):
    """Knobs of :class:`DefaultStrategy`. Steps count from 1.

    The four step fields default to ``null``: the schedule then follows the run's length (:meth:`resolved`) in the
    proportions of the 3DGS reference schedule (30 000 steps: densify from step 500 every 100 steps until step
    15 000, opacities reset every 3 000 steps while densifying), so that a run of any length ends on many steps
    without a reset. Shorter runs keep it in step counts where a proportion would leave too few steps: densification
    starts after a tenth of the run (at most step 500) and gathers at least 10 steps of statistics, and opacities are
    reset at most every :data:`MIN_RESET_EVERY` steps, the time the densification needs to regrow what a reset
    prunes. A step field that is set is kept as it is; :meth:`recovery_problem` says when the last reset
    leaves too few steps to recover.
    """

    refine_start: int | None = Field(
        None, ge=0, description="no densification at or before this step (null: a tenth of the run, at most 500)")
    refine_stop: int | None = Field(
        None, ge=0, description="statistics, densification and resets stop at this step (null: half the run)")
    refine_every: int | None = Field(
        None, ge=1, description="densify every this many steps (null: a thirtieth of the run, from 10 to 100)")
    reset_every: int | None = Field(
        None, ge=1, description="clamp opacities to reset_opacity every this many steps while densifying (null: a "
        f"tenth of the run, at least {MIN_RESET_EVERY}: runs of up to {2 * MIN_RESET_EVERY} steps reset none)")
    grow_grad2d: float = Field(0.0002, gt=0.0, description="mean view-space gradient (NDC units) to densify")
    grow_scale3d: float = Field(
        0.01, gt=0.0, description="percent_dense: clone if max scale <= this × scene extent, else split"
    )
    split_samples: int = Field(2, ge=2, le=8, description="children per split Gaussian")
    prune_opacity: float = Field(0.005, gt=0.0, lt=1.0, description="prune below this opacity")
    prune_scale3d: float = Field(0.1, gt=0.0, description="after the first reset: prune if max scale > this × extent")
    prune_screen_px: float = Field(20.0, gt=0.0, description="after the first reset: prune if screen radius > this (px)")
    reset_opacity: float = Field(0.01, gt=0.0, lt=1.0, description="opacity cap applied at each reset")
    unbounded: list[str] = unbounded_field()

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "refine_start": _steps(),
        "refine_stop": _steps(),
        "refine_every": _steps(MIN_REFINE_EVERY, low=(
            f"densifying more often than every {MIN_REFINE_EVERY} steps clones and splits on a step's or two's "
            "gradient, not the statistics of many views (the schedule that follows fit.iterations never does; the "
            "tiny scene's colour re-fit densifying every step grew 54 773 Gaussians to 470 409 while its PSNR "
            "fell)")),
        "reset_every": _steps(MIN_SET_RESET_EVERY, low=(
            "each reset clamps every opacity to reset_opacity, and the densification needs hundreds of steps to "
            "regrow what it then prunes (3DGS resets every 3000)")),
        "grow_grad2d": Bound(0.0, 1.0, "a mean view-space gradient in NDC units (3DGS: 0.0002); above 1 nothing "
                             "ever densifies: set fit.densify: false for that"),
        "grow_scale3d": Bound(0.0, 1.0, "a fraction of the scene's extent (3DGS: 0.01)"),
        "prune_scale3d": Bound(0.0, 10.0, "a multiple of the scene's extent (3DGS: 0.1); a Gaussian 10 times the "
                               "scene's size is never kept anyway"),
        "prune_screen_px": Bound(0.0, 100_000.0, "a screen radius in pixels (3DGS: 20), at most a view's size",
                                 unit="px"),
    }

    @model_validator(mode="after")
    def _check(self) -> StrategyParams:
        if self.prune_opacity >= self.reset_opacity:
            raise ValueError(
                f"prune_opacity ({self.prune_opacity}) must be below reset_opacity ({self.reset_opacity}), "
                "or every reset would prune the whole scene"
            )
        return self

    def resolved(self, iterations: int) -> StrategyParams:
        """The schedule of a run of ``iterations`` steps: every unset step field from the run's length (at 30 000
        steps exactly the 3DGS values), every set one kept."""
        defaults = {
            "refine_start": min(500, iterations // 10),
            "refine_stop": iterations // 2,
            "refine_every": max(10, min(100, iterations // 30)),
            "reset_every": max(MIN_RESET_EVERY, iterations // 10),
        }
        return self.model_copy(update={k: v for k, v in defaults.items() if getattr(self, k) is None})

    def last_reset(self, iterations: int) -> int | None:
        """The step of the run's last opacity reset (None: the run has none). Resets fall on the multiples of
        ``reset_every`` before ``refine_stop`` (:class:`DefaultStrategy`)."""
        p = self.resolved(iterations)
        last = min(p.refine_stop - 1, iterations) // p.reset_every * p.reset_every
        return last if last > 0 else None

    def recovery_problem(self, iterations: int) -> str | None:
        """Why this schedule ends a run of ``iterations`` steps with its opacities still near ``reset_opacity``,
        or None. A reset clamps every opacity to ``reset_opacity``; the Gaussians need the last
        :data:`MIN_RECOVERY` of the run without one to learn their opacities back."""
        last = self.last_reset(iterations)
        if last is None or iterations - last >= MIN_RECOVERY * iterations:
            return None
        p = self.resolved(iterations)
        latest = int((1.0 - MIN_RECOVERY) * iterations)
        return (f"the last opacity reset falls on step {last} of {iterations} (strategy.reset_every {p.reset_every}, "
                f"strategy.refine_stop {p.refine_stop}), leaving {iterations - last} steps to learn the opacities "
                f"back, under {MIN_RECOVERY:.0%} of the run; set strategy.refine_stop to at most {latest}, or remove "
                "strategy.reset_every and strategy.refine_stop to follow fit.iterations")


MIN_RECOVERY = 0.2
"""Share of a fit's steps that must follow its last opacity reset (3DGS's reference schedule leaves 60 %)."""

REFERENCE_ITERATIONS = 30000
"""The iteration count the 3DGS densification schedule was designed for (:meth:`StrategyParams.resolved`)."""


class FitParams(Bounded, extra="forbid"):
    """Options of the ``fit`` stage. Learning rates are per step; ``lr_means*`` are multiplied by the scene extent."""

    iterations: int = Field(30000, ge=1)
    sh_degree: int = Field(0, ge=0, le=3, description="highest SH band (ABC-GS trains its scenes with 0)")
    sh_degree_interval: int = Field(1000, ge=1, description="enable one more SH band every this many steps")
    ssim_lambda: float = Field(0.2, ge=0.0, le=1.0)
    init_opacity: float = Field(0.1, gt=0.0, lt=1.0)
    lr_means: float = Field(1.6e-4, gt=0.0, description="initial means learning rate × scene extent")
    lr_means_final: float = Field(1.6e-6, gt=0.0, description="final means learning rate × scene extent")
    lr_sh0: float = Field(2.5e-3, ge=0.0)
    lr_shN: float = Field(2.5e-3 / 20.0, ge=0.0)
    lr_opacity: float = Field(5e-2, ge=0.0)
    lr_scales: float = Field(5e-3, ge=0.0)
    lr_quats: float = Field(1e-3, ge=0.0)
    test_every: int = Field(8, ge=0, description="hold out views 0, n, 2n, … (LLFF: 8); 0 = train on all")
    resolution_scale: float = Field(1.0, gt=0.0, le=1.0, description="train at this fraction of the image size")
    seed: int = 0
    backend: Literal["auto", "cpu", "reference", "gsplat"] = "auto"
    background: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="RGB in [0, 1] behind the Gaussians")
    random_background: bool = Field(False, description="a random background colour each step (3DGS option)")
    densify: bool = Field(True, description="False = keep the initial Gaussians (NoDensification)")
    alpha_weight: float = Field(
        1.0, ge=0.0, description="an object's RGBA dataset: weight of the mean |α − α_gt| between the render's alpha "
        "and the dataset's, added to the photometric loss, so that empty space is learnt empty rather than as haze of "
        "the background colour (no effect on scenes without alpha maps)")
    color_only: bool = Field(False, description="optimise only the colours (sh0, shN): means, scales, rotations and "
                             "opacities stay bit-identical, and nothing densifies (the colour match's re-fit under "
                             "stylize.color_only)")
    strategy: StrategyParams = Field(default_factory=StrategyParams)
    max_gaussians: int | None = Field(None, ge=1, description="stop growing beyond this many Gaussians")
    eval_every: int = Field(0, ge=0, description="also evaluate held-out views every this many steps (0 = end only)")
    threads: int = Field(
        1, ge=0,
        description="torch CPU threads during the fit (0 = torch's default, all cores). 1 is the default: with "
        "other processes on the cores, intra-op threads spin and a step runs up to ~15x slower",
    )
    min_psnr: float = Field(
        15.0, ge=0.0, description="the fit stage fails when its held-out views (its training views, when nothing is "
        "held out) score under this mean PSNR (dB), naming the likely causes, so that nothing is painted on a broken "
        "fit (abcgs/fit/plausibility.py); 0 turns the floor off")
    max_psnr_gap: float = Field(
        12.0, gt=0.0, description="the fit stage fails when its held-out views score more than this many dB under its "
        "training views: it learnt the photos, not the scene")
    import_min_psnr: float = Field(
        16.0, ge=0.0, description="a scene that names a trained splat imports it instead of fitting; below this mean "
        "PSNR (dB) of its renders against the photos the import fails, naming the likely cause (frame, axes, scale, SH "
        "layout), instead of stylizing a misaligned scene")
    import_max_gaussians: int | None = Field(
        None, ge=1, description="preview of a large imported splat: keep only this many of its Gaussians (the most "
        "opaque and largest, abcgs/splats/preview.py); null keeps them all")
    rasterizer_threads: int = Field(
        0, ge=0,
        description="threads of the C++ rasterizer's own loops (0 = every core), independent of `threads`: they are "
        "plain threads joined after each loop, so they do not spin; results are bit-identical for any count",
    )
    unbounded: list[str] = unbounded_field()

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "iterations": Bound(
            MIN_CHECKED_ITERATIONS, MAX_FIT_ITERATIONS, soft=True, unit="steps", why=(
                f"{MAX_FIT_ITERATIONS} steps are 67 times 3DGS's 30000-step reference fit, days on a photo scene: a "
                "typo?"), low=(
                f"under {MIN_CHECKED_ITERATIONS} steps no fit has met the fit check's PSNR floor fit.min_psnr (the "
                f"embedded tiny scene, the easiest measured, first holds out over 15 dB at {MIN_CHECKED_ITERATIONS} "
                "steps, 14.7 dB at 30), so the fit stage would refuse what it fitted; set fit.min_psnr: 0 for a "
                "shorter smoke run")),
        "sh_degree_interval": _steps(),
        "lr_means": LEARNING_RATE, "lr_means_final": LEARNING_RATE, "lr_sh0": LEARNING_RATE,
        "lr_shN": LEARNING_RATE, "lr_opacity": LEARNING_RATE, "lr_scales": LEARNING_RATE, "lr_quats": LEARNING_RATE,
        "test_every": Bound(0, 20_000, "every n-th view held out; a capture has at most 20000 views (the readers' "
                            "limit)"),
        "resolution_scale": RESOLUTION_SCALE,
        "seed": SEED,
        "background": Bound(0.0, 1.0, "an RGB colour, each channel in [0, 1]"),
        "alpha_weight": Bound(0.0, 100.0, "a weight relative to the photometric loss, itself at most 1 a pixel"),
        "max_gaussians": Bound(1, 100_000_000, soft=True, why=(
            "100 M Gaussians hold 24 GB of parameters before Adam's two moments, and the .spz reader stops at "
            "100 M")),
        "eval_every": _steps(),
        "threads": Bound(0, MAX_THREADS, "torch CPU threads, 0 for torch's default"),
        "min_psnr": Bound(0.0, 60.0, unit="dB", why=(
            "a PSNR floor no fit can clear above 60 dB (an RMS error of 0.1 % of the range; the tiny scene's "
            "training views score 36-41 dB after 1000-6000 steps); 0 turns the floor off")),
        "max_psnr_gap": Bound(1.0, 60.0, unit="dB", why=(
            "held-out views score under the training views in every trained fit (the tiny scene: 2.7-6.0 dB at "
            "1000-6000 steps, its object on nothing 4.1-8.5 dB), so a gap under 1 dB would refuse every fit; above "
            "60 dB the check never fails")),
        "import_min_psnr": Bound(0.0, 60.0, unit="dB", why=(
            "a PSNR floor no splat's renders clear above 60 dB (an RMS error of 0.1 % of the range); 0 turns it "
            "off")),
        "import_max_gaussians": Bound(1, 100_000_000, soft=True, why=(
            "a preview of more than 100 M Gaussians is no preview (the .spz reader stops at 100 M)")),
        "rasterizer_threads": Bound(0, MAX_THREADS, "threads of the C++ rasterizer, 0 for every core"),
    }

    def bounds(self) -> dict[str, Bound]:
        """:attr:`BOUNDS`, ``iterations`` floored at 1 instead of :data:`MIN_CHECKED_ITERATIONS` while the fit
        check's PSNR floor is off (``min_psnr`` 0: a smoke run)."""
        if self.min_psnr > 0:
            return self.BOUNDS
        return {**self.BOUNDS, "iterations": replace(self.BOUNDS["iterations"], lo=1)}

    @field_validator("test_every")
    @classmethod
    def _test_every(cls, v: int) -> int:
        if v == 1:
            raise ValueError("test_every = 1 would hold out every view; use 0 (no hold-out) or >= 2")
        return v

    @model_validator(mode="after")
    def _check_schedule(self) -> FitParams:
        if self.densify and not self.color_only and (problem := self.strategy.recovery_problem(self.iterations)):
            raise ValueError(problem)  # the error's location names the fit section
        return self

    def strategy_params(self) -> StrategyParams:
        """The strategy parameters this run uses: :meth:`StrategyParams.resolved` for ``iterations``."""
        return self.strategy.resolved(self.iterations)
