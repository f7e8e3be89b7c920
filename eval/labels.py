"""Label maps in the masks benchmarks and studies: scored against reference maps, and drawn over their photos.

    s = score_labels(maps, refs, n_labels)      # maps and refs by view (a stem or an index); refs' views are scored
    s.iou["DSCF5648"]                            # {"1": 0.93, "2": 0.88}: per label, by its number as text
    s.mean_iou, s.worst_iou, s.view_mean        # over the (view, label) pairs, and per view
    s.as_record()                               # those five as a record holds them
    s.worst_per_label(absent=float("nan"))      # per label, its worst view
    s.per_label_summary(), s.mean_agreement(empty_views="skip")

:func:`score_labels` is the one label scoring of ``eval/`` (``eval.bench.strokes``, ``eval.bench.scripted_user``,
``eval.bench.graph_features``, ``eval.bench.paint_iou``, ``eval.studies.mask_lifting``). Each view's map is scored
against its reference by :func:`abcgs.masks.content.label_iou`, the stage's own held-out score: over the pixels the
reference assigns (> 0; its 0, undecided and ``NO_VOTE`` pixels are not scored), a label absent from the map and the
reference both is not scored in that view, one absent from either side scores 0. Where the records sum up over the
views by different conventions, the convention is an argument: a label no view scores (:meth:`worst_per_label`'s
``absent``), and a reference that assigns no pixel (:meth:`mean_agreement`'s ``empty_views``).

:func:`overlay` and :func:`stroke_overlay` draw label maps over a photo for the figures.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from abcgs.masks.content import label_iou


@dataclass(frozen=True)
class LabelScores:
    """The scores of label maps against their references, by view (in the references' order).

    Attributes:
        n_labels: the labels 1..n_labels that were scored.
        iou: per view, per label (its number as text, ascending): the IoU of the view's map and its reference.
        unlabelled: per view, the share of the map's pixels at 0.
        agreement: per view, the share of the reference's assigned pixels (> 0) where the map holds the same label;
            nan where the reference assigns none.
    """

    n_labels: int
    iou: dict[Hashable, dict[str, float]]
    unlabelled: dict[Hashable, float]
    agreement: dict[Hashable, float]

    @property
    def pairs(self) -> list[float]:
        """The IoU of every scored (view, label) pair, view by view, labels ascending."""
        return [v for d in self.iou.values() for v in d.values()]

    @property
    def mean_iou(self) -> float:
        """The mean IoU over the (view, label) pairs."""
        return float(np.mean(self.pairs))

    @property
    def worst_iou(self) -> float:
        """The worst IoU of any (view, label) pair."""
        return float(min(self.pairs))

    @property
    def view_mean(self) -> dict[Hashable, float]:
        """Per view, the mean IoU over its scored labels (nan where it scores none)."""
        return {s: float(np.mean(list(d.values()))) for s, d in self.iou.items()}

    def as_record(self) -> dict:
        """The scores as a record holds them (``eval.bench.scripted_user``'s steps): ``iou`` and ``unlabelled`` per
        view, ``view_mean``, and ``worst_iou`` and ``mean_iou`` over the (view, label) pairs."""
        return {"iou": self.iou, "unlabelled": self.unlabelled, "view_mean": self.view_mean,
                "worst_iou": self.worst_iou, "mean_iou": self.mean_iou}

    def worst_per_label(self, absent: float) -> dict[str, float]:
        """Per label 1..n_labels (by its number as text), its worst IoU over the views that score it; ``absent`` for a
        label no view scores (``eval.bench.strokes`` records nan for a case, 1.0 for the geometry's bound)."""
        return {str(k): min((d[str(k)] for d in self.iou.values() if str(k) in d), default=absent)
                for k in range(1, self.n_labels + 1)}

    def per_label(self) -> dict[int, list[float]]:
        """Per label that some view scores (ascending), its IoU in each view that scores it, in view order."""
        out: dict[int, list[float]] = {}
        for d in self.iou.values():
            for k, v in d.items():
                out.setdefault(int(k), []).append(v)
        return dict(sorted(out.items()))

    def per_label_summary(self) -> dict[str, dict]:
        """Per label that some view scores (by its number as text), the mean and the worst of its IoUs over the views
        that score it, and their count."""
        return {str(k): {"mean": float(np.mean(v)), "min": float(np.min(v)), "n_views": len(v)}
                for k, v in self.per_label().items()}

    def mean_agreement(self, empty_views: Literal["skip", "count"]) -> float | None:
        """The mean of the views' :attr:`agreement`. A view whose reference assigns no pixel is left out with
        ``empty_views="skip"`` (None when no view is left; ``eval.studies.mask_lifting``, as the stage's held-out
        score), and makes the mean nan with ``"count"`` (``eval.bench.paint_iou``)."""
        if empty_views == "count":
            return float(np.mean(list(self.agreement.values())))
        kept = [v for v in self.agreement.values() if not np.isnan(v)]
        return float(np.mean(kept)) if kept else None


def score_labels(maps: Mapping[Hashable, np.ndarray] | Sequence[np.ndarray], refs: Mapping[Hashable, np.ndarray],
                 n_labels: int) -> LabelScores:
    """Each view of ``refs`` scored: its map in ``maps`` against its reference (see the module's docstring).

    Args:
        maps: the label maps ``(H, W) int`` by view (a mapping, or a list indexed by view); it may hold more views
            than ``refs``.
        refs: the reference maps ``(H, W) int`` (0 none, 1..n_labels; other values, e.g. undecided, are not
            assigned) of the views to score, by view.
        n_labels: labels 1..n_labels are scored.
    """
    iou, unlabelled, agreement = {}, {}, {}
    for s, ref in refs.items():
        lab = maps[s]
        iou[s] = {str(k): v for k, v in label_iou(lab, ref, n_labels).items()}
        unlabelled[s] = float((lab == 0).mean())
        assigned = ref > 0
        agreement[s] = float((lab == ref)[assigned].mean()) if assigned.any() else float("nan")
    return LabelScores(n_labels, iou, unlabelled, agreement)


def overlay(img: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Half the view, half the label colours (unassigned pixels keep the view)."""
    from abcgs.viz import colorize_labels

    col = colorize_labels(labels).astype(np.float32) / 255.0
    out = img.astype(np.float32).copy()
    on = labels > 0
    out[on] = 0.45 * out[on] + 0.55 * col[on]
    return out


def stroke_overlay(img: np.ndarray, labels: np.ndarray, strokes: list | None = None) -> np.ndarray:
    """The view under the label colours, undecided (and ``NO_VOTE``) pixels white and ``strokes`` (a list of
    :class:`abcgs.masks.strokes.Stroke`) black."""
    from abcgs.masks.params import UNDECIDED
    from abcgs.masks.strokes import rasterize_strokes
    from abcgs.viz import colorize_labels

    lab = np.where(labels < 0, 0, np.where(labels == UNDECIDED, 0, labels))
    out = 0.45 * img + 0.55 * colorize_labels(lab) / 255.0
    out[(labels == UNDECIDED) | (labels < 0)] = 1.0  # undecided: white
    if strokes:
        out[rasterize_strokes(strokes, labels.shape) > 0] = 0.0
    return out.astype(np.float32)
