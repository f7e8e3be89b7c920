"""Baseline 3DGS fitting (Kerbl et al. 2023): losses, densification strategies, the trainer and metrics."""

from abcgs.fit.losses import LossTerms, dssim, l1, reconstruction_loss, ssim
from abcgs.fit.strategy import (
    DefaultStrategy,
    NoDensification,
    RefineReport,
    Strategy,
    StrategyParams,
    scene_extent,
)
from abcgs.fit.trainer import Evaluation, FitParams, FitResult, Views, evaluate, fit, fit_and_save, load_views

__all__ = [
    "DefaultStrategy",
    "Evaluation",
    "FitParams",
    "FitResult",
    "LossTerms",
    "NoDensification",
    "RefineReport",
    "Strategy",
    "StrategyParams",
    "Views",
    "dssim",
    "evaluate",
    "fit",
    "fit_and_save",
    "l1",
    "load_views",
    "reconstruction_loss",
    "scene_extent",
    "ssim",
]
