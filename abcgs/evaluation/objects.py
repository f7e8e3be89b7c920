"""An object scene's own metrics: how well the stylization kept the object's shape and its empty space.

For a scene whose :class:`~abcgs.types.Background` says ``object`` (:mod:`abcgs.silhouette`), the original scene's
alpha ``α_ref`` in each evaluated view splits the frame into object pixels (``α_ref ≥ 0.5``) and empty pixels
(``α_ref < 0.02``). On those:

- ``ssim_object``: the content SSIM (Wang et al.'s map) averaged over the object pixels, per view, then over views;
- ``short_rmse_object`` / ``long_rmse_object``: the consistency pairs' warp RMSE over the pixels of view ``i`` that
  are both valid for the pair and on the object;
- ``background_change``: the share of empty pixels, pooled over the views, whose stylized colour moved from the
  original by more than :data:`CHANGE_THRESHOLD` in any channel (a headline number: 0 when empty space stayed empty);
- ``silhouette_iou``: the intersection over union of ``α_ref ≥ 0.5`` and the stylized scene's ``α ≥ 0.5``, pooled
  over the views.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from abcgs.evaluation.consistency import Consistency
from abcgs.evaluation.content import masked_rmse, nan_mean, ssim_map_wang
from abcgs.silhouette import EMPTY_ALPHA, OBJECT_ALPHA

CHANGE_THRESHOLD = 0.05
"""An empty pixel counts as changed when a channel moved by more than this (values in [0, 1])."""


@dataclass(frozen=True)
class ObjectScores:
    """The object metrics of one stylization (module docstring); per view lists in the evaluated views' order."""

    ssim_object: float
    short_rmse_object: float
    long_rmse_object: float
    background_change: float
    silhouette_iou: float
    per_view_ssim: tuple[float, ...]
    per_view_background_change: tuple[float, ...]
    per_view_silhouette_iou: tuple[float, ...]
    object_fraction: float
    """Mean share of a view's pixels on the object."""

    def record(self) -> dict:
        """The numbers ``eval.json`` keeps (the per-view ones go to ``eval_views.csv``)."""
        return {"ssim_object": self.ssim_object, "short_rmse_object": self.short_rmse_object,
                "long_rmse_object": self.long_rmse_object, "background_change": self.background_change,
                "silhouette_iou": self.silhouette_iou, "object_fraction": self.object_fraction,
                "object_definition": {"object_alpha": OBJECT_ALPHA, "empty_alpha": EMPTY_ALPHA,
                                      "change_threshold": CHANGE_THRESHOLD}}


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def masked_ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """Wang et al.'s SSIM map of ``a`` and ``b`` ``(H, W, 3)`` (channels averaged) over the ``mask`` ``(H, W)`` pixels
    where a full window fits; NaN when none does."""
    smap = ssim_map_wang(a, b)[0].mean(0).numpy(force=True)
    top, left = (mask.shape[0] - smap.shape[0]) // 2, (mask.shape[1] - smap.shape[1]) // 2
    m = mask[top: top + smap.shape[0], left: left + smap.shape[1]]
    return float(smap[m].mean()) if m.any() else float("nan")


def _pair_rmse_on_object(c: Consistency | None, stylized: Sequence[np.ndarray], on_object: Sequence[np.ndarray]) -> float:
    if c is None:
        return float("nan")
    return nan_mean([masked_rmse(stylized[r.i], r.warped, r.mask & on_object[r.i]) for r in c.pairs])


def object_scores(originals: Sequence[np.ndarray], stylized: Sequence[np.ndarray], ref_alphas: Sequence[np.ndarray],
                  alphas: Sequence[np.ndarray], short: Consistency | None = None,
                  long: Consistency | None = None) -> ObjectScores:
    """The object metrics from the original and stylized renders ``(H, W, 3)`` (on the scene's background), the
    original and stylized alphas ``(H, W)`` or ``(H, W, 1)``, and the consistency pairs already measured (without
    them the object RMSEs are NaN)."""
    ref = [np.asarray(a, np.float32).reshape(np.shape(o)[:2]) for a, o in zip(ref_alphas, originals)]
    sty = [np.asarray(a, np.float32).reshape(np.shape(o)[:2]) for a, o in zip(alphas, originals)]
    on_object = [a >= OBJECT_ALPHA for a in ref]
    ssim = [masked_ssim(o, s, m) for o, s, m in zip(originals, stylized, on_object)]
    changed, empty_counts = [], []
    for o, s, a in zip(originals, stylized, ref):
        empty = a < EMPTY_ALPHA
        moved = (np.abs(np.asarray(s, np.float32) - np.asarray(o, np.float32)) > CHANGE_THRESHOLD).any(axis=-1)
        changed.append(int((moved & empty).sum()))
        empty_counts.append(int(empty.sum()))
    ious = [_iou(m, s >= OBJECT_ALPHA) for m, s in zip(on_object, sty)]
    pooled_iou = _iou(np.concatenate([m.ravel() for m in on_object]),
                      np.concatenate([(s >= OBJECT_ALPHA).ravel() for s in sty]))
    return ObjectScores(
        ssim_object=nan_mean(ssim),
        short_rmse_object=_pair_rmse_on_object(short, stylized, on_object),
        long_rmse_object=_pair_rmse_on_object(long, stylized, on_object),
        background_change=float(sum(changed) / sum(empty_counts)) if sum(empty_counts) else 0.0,
        silhouette_iou=pooled_iou,
        per_view_ssim=tuple(ssim),
        per_view_background_change=tuple(c / e if e else 0.0 for c, e in zip(changed, empty_counts)),
        per_view_silhouette_iou=tuple(ious),
        object_fraction=float(np.mean([m.mean() for m in on_object])),
    )
