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
    "colormatch.refit_iterations": 20,
    "stylize.optim.iterations": 20,
}
"""Dotted params key → value: the shortened schedule of the regression runs."""


def reduce(params: dict) -> None:
    """Set the :data:`REDUCED` schedule in a parsed params file (in place)."""
    for dotted, value in REDUCED.items():
        set_dotted(params, dotted, value)
