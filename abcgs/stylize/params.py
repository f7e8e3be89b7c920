"""The ``stylize`` and ``colormatch`` sections' schema (:mod:`abcgs.stylize.loop`, :mod:`abcgs.stylize.colormatch`).

Schema modules import nothing heavier than pydantic, so that reading ``params.yaml`` does not load the code
it configures (each stage's code dependencies stay its own: ``abcgs/dag.py``).
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import ConfigDict, Field, model_validator

from abcgs.losses.params import FastParams
from abcgs.sections import LEARNING_RATE, MAX_THREADS, RESOLUTION_SCALE, SEED, Bound, Bounded, unbounded_field
from abcgs.types import Backend

LR_PRESETS: dict[str, dict[str, float]] = {
    # this project's first rates (colour 4× INRIA's, geometry 5× slower, means free); the default until the
    # quality study measured both on three paintings (docs/FIDELITY.md "The authors' learning rates")
    "ours": {"lr_sh0": 0.01, "lr_means": 1.6e-5, "lr_scales": 1e-3, "lr_opacity": 1e-2, "lr_quats": 1e-3},
    # INRIA 3DGS ``training_setup`` as the authors' StyleTrainer uses it: f_dc 0.0025, opacity 0.05, scaling 0.005,
    # rotation 0.001; xyz 1.6e-4 × spatial_lr_scale, which stays 0 for a GaussianModel loaded from a PLY → frozen.
    "authors_code": {"lr_sh0": 0.0025, "lr_means": 0.0, "lr_scales": 5e-3, "lr_opacity": 5e-2, "lr_quats": 1e-3},
}
"""Learning-rate presets of the stylization optimiser (Adam, eps 1e-15), per parameter group."""

MAX_STYLIZE_ITERATIONS = 30_000
"""The most steps of a stylization pass (main or colour pass) a params file asks for without ``unbounded``: 50
times the authors' 600 (``1000000000``, a typo, started a pass whose bar said 110 904 hours)."""
MAX_REFIT_ITERATIONS = 30_000
"""The most steps of the colour match's re-fit without ``unbounded``: 3DGS's whole 30 000-step fit from scratch
(the authors' re-fit: 400)."""
MIN_REFIT_REFINE_EVERY = 10
"""The fewest re-fit steps between two densifications (``colormatch.refine_every``, 0 aside): every step grew the
tiny scene from 54 773 to 470 409 Gaussians while its PSNR fell; the fit's own schedule never densifies more often
(abcgs/fit/params.py ``MIN_REFINE_EVERY``)."""
WEIGHT = Bound(0.0, 10_000.0, "a λ of Eq. 8 (paper: 0.005 to 2); over 10 000 one term drowns the others")
"""The range of every ``stylize.weights`` entry."""


HigherSH = Literal["zero", "frozen", "optimized", "degree1"]
"""What stylization does to the SH bands above the DC term of a degree 1–3 scene (docs/SPLATS.md "SH bands"):
``zero``: set to zero, the stylized colour is the same from every side (the colour match zeroes them; the file keeps
its degree); ``frozen``: the original's bands kept unchanged, only the DC colour stylized (SGSST); ``optimized``: the
original's bands kept and optimised with the DC colour (the authors' code); ``degree1``: band 1 kept and optimised,
bands 2–3 zeroed (StylizedGS's degree 1)."""


class StyleWeights(Bounded):
    """``params.yaml``: ``stylize.weights``, the λ of Eq. 8 (paper {2, 0.005, 0.02, 0.01, 1, 1}); 0 drops a term."""

    model_config = ConfigDict(extra="forbid")

    style: float = Field(2.0, ge=0, description="λ_FAST: stylization strength")
    content: float = Field(
        0.0005, ge=0, description="λ_c: content preservation (paper 0.005; with the Keras/Oxford VGG features here "
        "that value pins the colour-matched start, see docs/FIDELITY.md 'λ balance')")
    tv: float = Field(0.02, ge=0, description="λ_tv: total variation of the render")
    structure: float = Field(0.0, ge=0, description="λ_st: MSE of the render's luminance gradients (Sobel) to the "
                             "content image's, the fine structure the relu3 content term sees blurred "
                             "(abcgs.losses.terms.structure_loss; docs/FIDELITY.md 'Detail per label')")
    depth: float = Field(0.01, ge=0, description="λ_dep: MSE to the original scene's depth")
    scale: float = Field(1.0, ge=0, description="λ_sca: mean ‖Δ scale‖ from the start (main pass, geometry optimised)")
    opacity: float = Field(1.0, ge=0, description="λ_opa: mean |Δ opacity| from the start (main pass, geometry "
                           "optimised)")
    silhouette: float = Field(10.0, ge=0, description="object scenes: mean |α − α_ref| between the render's alpha and "
                              "the original scene's (abcgs.silhouette); holds the object's outline")
    background: float = Field(10.0, ge=0, description="object scenes: mean |render − background| over the pixels "
                              "the original scene leaves empty; keeps empty space empty")

    BOUNDS: ClassVar[dict[str, Bound]] = {k: WEIGHT for k in (
        "style", "content", "structure", "tv", "depth", "scale", "opacity", "silhouette", "background")}


class StylizeOptim(Bounded):
    """``params.yaml``: ``stylize.optim``, the schedule and the Adam learning rates (eps 1e-15, as 3DGS) per
    Gaussian parameter group; densification stays off."""

    model_config = ConfigDict(extra="forbid")

    iterations: int | None = Field(
        None, ge=0, description="main pass steps (authors: 600 on LLFF); null: by the views' size, 150 for small "
        "views, 300 for photos (the schedule every measurement in docs/FIDELITY.md used; abcgs/stylize/schedule.py)")
    color_pass_iterations: int | None = Field(
        None, ge=0, description="authors' post-process after the main pass: re-render, colour-match again, re-fit "
        "colours and rotations with L1 + D-SSIM (authors: 400; 200 measured on fern: Gram distance 0.315 → 0.267, "
        "docs/FIDELITY.md); 0 turns it off; null: by the views' size, 50 for small views, 200 for photos")
    color_pass_rotations: bool = Field(
        True, description="the colour pass re-fits rotations too (the authors' post-process); false freezes its "
        "geometry, and the CPU colour pass then replays each view's recorded blending map (docs/SCALING.md)")
    optimize_geometry: bool = Field(True, description="also optimise xyz/scale/opacity/rotation in the main pass")
    lr_preset: Literal["authors_code", "ours"] = Field(
        "authors_code", description="learning rates: 'authors_code' (INRIA's training_setup rates with xyz frozen, as "
        "the authors' code runs; the default, measured on fern × 3 paintings: docs/FIDELITY.md) or 'ours' (this "
        "project's first rates, see LR_PRESETS); an explicit lr_* key overrides its preset value")
    lr_sh0: float = Field(LR_PRESETS["authors_code"]["lr_sh0"], ge=0)
    lr_means: float = Field(LR_PRESETS["authors_code"]["lr_means"], ge=0, description="0 freezes the means")
    lr_scales: float = Field(LR_PRESETS["authors_code"]["lr_scales"], ge=0)
    lr_opacity: float = Field(LR_PRESETS["authors_code"]["lr_opacity"], ge=0)
    lr_quats: float = Field(LR_PRESETS["authors_code"]["lr_quats"], ge=0)
    lr_shN: float = Field(LR_PRESETS["authors_code"]["lr_sh0"] / 20.0, ge=0,
                          description="learning rate of the higher SH bands when stylize.higher_sh is optimized or "
                          "degree1 (INRIA: the DC rate / 20)")
    unbounded: list[str] = unbounded_field()

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "iterations": Bound(0, MAX_STYLIZE_ITERATIONS, soft=True, unit="steps", why=(
            f"{MAX_STYLIZE_ITERATIONS} steps are 50 times the authors' 600, hours to days a scene: a typo?")),
        "color_pass_iterations": Bound(0, MAX_STYLIZE_ITERATIONS, soft=True, unit="steps", why=(
            f"{MAX_STYLIZE_ITERATIONS} steps are 75 times the authors' 400-step colour pass: a typo?")),
        **{k: LEARNING_RATE for k in ("lr_sh0", "lr_means", "lr_scales", "lr_opacity", "lr_quats", "lr_shN")},
    }

    @model_validator(mode="before")
    @classmethod
    def _apply_lr_preset(cls, data):
        """Fill the ``lr_*`` keys the user did not give from ``lr_preset``."""
        if isinstance(data, dict):
            preset = data.get("lr_preset", "authors_code")
            if preset in LR_PRESETS:
                data = {**LR_PRESETS[preset], **data}
        return data


class StylizeCompute(Bounded):
    """``params.yaml``: ``stylize.compute``, where and how the loop runs and how often it logs; no effect on the
    numbers but through the rasterizer chosen."""

    model_config = ConfigDict(extra="forbid")

    backend: Backend = Field("auto", description="rasterizer (abcgs.render)")
    threads: int = Field(0, ge=0, description="torch CPU threads for this stage (0: torch's default, all cores); "
                         "with `dvc queue start -j N` on C cores, C // N (README 'Benchmarks at scale')")
    log_every: int = Field(10, ge=1, description="a row of stylize_history.csv every this many steps (and the last)")

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "threads": Bound(0, MAX_THREADS, "torch CPU threads, 0 for torch's default"),
        "log_every": Bound(1, 1_000_000, "steps between two rows of the history; the last step is always logged"),
    }


MOVED_KEYS: dict[str, str] = {
    **{f"lambda_{k}": f"weights.{k}" for k in ("style", "content", "tv", "depth", "scale", "opacity")},
    **{k: f"optim.{k}" for k in ("iterations", "color_pass_iterations", "optimize_geometry", "lr_preset", "lr_sh0",
                                 "lr_means", "lr_scales", "lr_opacity", "lr_quats", "lr_shN")},
    **{k: f"compute.{k}" for k in ("backend", "threads", "log_every")},
}
"""Flat ``stylize.<key>`` of earlier params files → its place in the sections (``stylize.<section>.<key>``)."""


class StylizeParams(Bounded):
    """``params.yaml``: ``stylize``."""

    model_config = ConfigDict(extra="forbid")

    layers: list[str] = Field(default_factory=lambda: ["relu3_1", "relu3_2", "relu3_3"],
                              description="VGG-16 taps of the style and content features")
    style_height: int = Field(256, ge=16, description="style images are resized to this height")
    downsample_render: bool = Field(True, description="render ×0.5 before VGG (authors' code)")
    resolution_scale: float = Field(1.0, gt=0, le=1.0, description="stylize at this fraction of the view size")
    higher_sh: HigherSH = Field(
        "zero", description="the SH bands above DC of a degree 1-3 scene: zero | frozen | optimized | degree1 (HigherSH; "
        "measured on a degree-3 scene in docs/SPLATS.md); no effect on a degree-0 scene")
    preserve_color: bool = Field(False, description="keep the scene's colours: transfer luminance only")
    color_only: bool = Field(
        False, description="change only the colours (sh0 and the higher SH bands): means, scales, rotations and "
        "opacities stay bit-identical to the fitted scene through the colour match's re-fit, the main pass and the "
        "colour pass, as in the optimisation-free stylizers; for shapes that must be kept exactly")
    seed: int = 0
    grid_views: list[str] | None = Field(
        None, min_length=1, description="the views grid.png shows, by file name or stem, in this order: those of them "
        "the scene has (names of other scenes' views may be listed too); a scene with none of them fails naming its "
        "views. null: the first 3 views in name order")
    weights: StyleWeights = Field(default_factory=StyleWeights)
    fast: FastParams = Field(default_factory=FastParams)
    optim: StylizeOptim = Field(default_factory=StylizeOptim)
    compute: StylizeCompute = Field(default_factory=StylizeCompute)

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "style_height": Bound(16, 4096, unit="px", why=(
            "the painting's height before VGG (the authors: 256); VGG's memory grows with its square")),
        "resolution_scale": RESOLUTION_SCALE,
        "seed": SEED,
    }

    def with_schedule(self, iterations: int | None = None, color_pass_iterations: int | None = None) -> StylizeParams:
        """A copy with ``optim.iterations`` / ``optim.color_pass_iterations`` set where given (≥ 0)."""
        update = {k: v for k, v in (("iterations", iterations), ("color_pass_iterations", color_pass_iterations))
                  if v is not None}
        return self.model_copy(update={"optim": StylizeOptim.model_validate({**self.optim.model_dump(), **update})})

    @model_validator(mode="before")
    @classmethod
    def _moved_keys(cls, data):
        """A flat key of the earlier layout fails naming its new place (before the generic unknown-key error)."""
        if isinstance(data, dict):
            moved = [f"stylize.{k} moved to stylize.{MOVED_KEYS[k]}" for k in data if k in MOVED_KEYS]
            if moved:
                raise ValueError("; ".join(moved))
        return data


class ColorMatchParams(Bounded):
    """``params.yaml``: ``colormatch``."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(True, description="False = stylize the scene's own colours")
    refit_iterations: int | None = Field(
        None, ge=0, description="re-fit steps on the recoloured images (authors: 400); null: by the views' size, 100 "
        "for small views, 400 for photos (abcgs/stylize/schedule.py)")
    refine_every: int = Field(
        0, ge=0, description="densify every this many re-fit steps, to the end of the re-fit (authors: 50; new "
        "Gaussians keep the content label of the one they come from); 0: the re-fit keeps the fitted Gaussians, "
        "measured cheaper and closer to the content (docs/FIDELITY.md, row 7)")
    resolution_scale: float = Field(1.0, gt=0, le=1.0)
    seed: int = 0
    backend: Backend = "auto"
    threads: int = Field(0, ge=0, description="torch CPU threads for this stage (0: torch's default, all cores); "
                         "with `dvc queue start -j N` on C cores, C // N (README 'Benchmarks at scale')")
    unbounded: list[str] = unbounded_field()

    BOUNDS: ClassVar[dict[str, Bound]] = {
        "refit_iterations": Bound(0, MAX_REFIT_ITERATIONS, soft=True, unit="steps", why=(
            f"a re-fit of {MAX_REFIT_ITERATIONS} steps is as long as 3DGS's whole fit from scratch (the authors "
            "re-fit 400 steps): a typo?")),
        "refine_every": Bound(MIN_REFIT_REFINE_EVERY, MAX_REFIT_ITERATIONS, off=0, soft=True, unit="steps", why=(
            f"the re-fit has at most {MAX_REFIT_ITERATIONS} steps"), low=(
            f"densifying more often than every {MIN_REFIT_REFINE_EVERY} steps clones and splits on a step's or two's "
            "gradient (every step grew the tiny scene's 54 773 Gaussians to 470 409 while its PSNR fell; the "
            "authors densify every 50)")),
        "resolution_scale": RESOLUTION_SCALE,
        "seed": SEED,
        "threads": Bound(0, MAX_THREADS, "torch CPU threads, 0 for torch's default"),
    }
