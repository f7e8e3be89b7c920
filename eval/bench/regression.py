"""The tiny-scene regression protocol shared by the end-to-end test and the seed-spread study.

``tests/test_pipeline_e2e.py`` runs ``dvc repro`` on the embedded scene with :data:`REDUCED` iteration counts and
gates :data:`GATED` against ``tests/baselines/tiny_seed_spread.json``, whose tolerances
``python -m eval run seed_spread`` measures with the same settings.
"""

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs.dotted import set_dotted

GATED = ("ssim", "short_rmse", "long_rmse")
"""Metrics (keys of ``out/<experiment>/eval.json``) whose regression fails CI."""

REDUCED = {
    "fit.iterations": 300,
    "fit.strategy.refine_every": 20,
    "colormatch.refit_iterations": 20,
    "stylize.optim.iterations": 20,
}
"""Dotted params key → value: the shortened schedule of the regression runs. The 300-step fit densifies every 20
steps, where the schedule that follows the run's length would densify every 10: on the tiny scene that grew 120 751
Gaussians (23.9 dB held out, 31 s) against 18 664 (25.6 dB, 8 s), and every stage after the fit, the report's
software-WebGL viewer most, paid for them (``python -m eval run fit_schedule --iterations 300 --scenes tiny --variant
'{}' --variant '{"strategy": {"refine_every": 20}}'``, ``docs/measurements/fit_schedule_300.json``)."""


def reduce(params: dict) -> None:
    """Set the :data:`REDUCED` schedule in a parsed params file (in place)."""
    for dotted, value in REDUCED.items():
        set_dotted(params, dotted, value)
