"""The strip of every view's labels on the masks page: small label maps of all views, re-blended in milliseconds after
each Segment, and how doubtful each view's labels are.

The Gaussians do not move while the user paints, so each view's small render is a fixed sparse linear map of the
Gaussians' colours (:mod:`abcgs.render.frozen`): :meth:`Strip.record` records it once per view when the page opens,
and :meth:`Strip.labels` blends the labels' one-hot "colours" (one channel per label and one for undecided) through
every view's map and takes each pixel's largest channel.

A view's **doubt** (:meth:`Strip.doubt`), which orders the strip, is the share of its rendered pixels that are
undecided plus the share whose photo colour (CIELAB, in the thumbnail) is nearer the mean colour of another label in
that view than of its own: where labels and colours disagree, the cut or the 3-D step is likely wrong.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from abcgs.cameras import Camera
from abcgs.gaussians import GaussianModel
from abcgs.masks.lifting import label_colours, pick_labels
from abcgs.masks.params import UNDECIDED
from abcgs.render.frozen import FrozenView, blend_frozen, record_view

STRIP_SIDE = 160
"""Longest side of a view in the strip (pixels)."""


@dataclass
class Strip:
    """Every view's frozen label map at strip size (:func:`record_view`), the views' photos at that size
    ``(h, w, 3) uint8`` (None: no doubt from colour) and their CIELAB ``(h * w, 3) float32`` for the doubt."""

    views: list[FrozenView]
    photos: list[np.ndarray] | None
    seconds: float
    cielab: list[np.ndarray] | None = None

    def __post_init__(self) -> None:
        if self.photos is not None and self.cielab is None:
            self.cielab = [cv2.cvtColor(p, cv2.COLOR_RGB2LAB).reshape(-1, 3).astype(np.float32) for p in self.photos]

    @classmethod
    def record(cls, model: GaussianModel, cameras: list[Camera], photos: list[np.ndarray] | None = None,
               side: int = STRIP_SIDE) -> Strip:
        """Record each camera's map at ``side`` pixels on its longest side; ``photos``: the views' images (any
        size, resized here)."""
        t0 = time.perf_counter()
        act = {k: v.detach().cpu().float().contiguous() for k, v in model.activated().items()}
        empty = torch.zeros(model.num_gaussians, 0, 3)
        views, small = [], []
        for i, cam in enumerate(cameras):
            c = cam.scaled(side / max(cam.width, cam.height))
            views.append(record_view(act["means"], act["quats"], act["scales"], act["opacities"], empty, 0,
                                     c.torch_viewmat(), c.torch_K(), c.width, c.height))
            if photos is not None:
                small.append(cv2.resize(photos[i], (c.width, c.height), interpolation=cv2.INTER_AREA))
        return cls(views, small if photos is not None else None, time.perf_counter() - t0)

    def labels(self, labels: np.ndarray, decided: np.ndarray, n_labels: int, threshold: float = 0.0, *,
               previous: list[np.ndarray] | None = None, changed: np.ndarray | None = None) -> list[np.ndarray]:
        """Each view's label map ``(h, w) int64``: the label of largest weight where it holds at least ``threshold``
        of a pixel's alpha (:func:`abcgs.masks.field.render_field`'s rule);
        :data:`UNDECIDED` where undecided Gaussians win, 0 where nothing is rendered or no label holds enough.

        With the ``previous`` maps (of the same ``n_labels`` and ``threshold``) and ``changed`` ``(N,) bool``, the
        Gaussians whose label or decision changed since, only the views that one of them blends into are blended
        again; the others keep their map (a correction moves the labels of a few parts, seen in a few views)."""
        colours = label_colours(torch.as_tensor(labels), n_labels, torch.as_tensor(decided))
        out = []
        for i, view in enumerate(self.views):
            if previous is not None and changed is not None and not changed[view.ids.numpy()].any():
                out.append(previous[i])
                continue
            img, alpha = blend_frozen(view, colours[view.ids].contiguous())
            out.append(pick_labels(img, alpha, threshold).numpy().astype(np.int64))
        return out

    def doubt(self, maps: list[np.ndarray]) -> list[float]:
        """Per view (module docstring): the undecided share of its rendered pixels plus the share of its labelled
        pixels whose colour is nearer another label's mean colour in the view."""
        out = []
        for i, lab in enumerate(maps):
            shown = lab > 0
            if not shown.any():
                out.append(1.0)
                continue
            undecided = float((lab == UNDECIDED).sum() / shown.sum())
            out.append(undecided + (self._colour_disagreement(self.cielab[i], lab) if self.cielab else 0.0))
        return out

    @staticmethod
    def _colour_disagreement(cie: np.ndarray, lab: np.ndarray) -> float:
        """The share of the labelled pixels of ``lab`` ``(h, w)`` whose colour ``cie`` ``(h * w, 3)`` is nearer
        another label's mean colour in the view than its own's (0 with fewer than two labels)."""
        flat = lab.ravel()
        keep = (flat > 0) & (flat < UNDECIDED)
        ids, own = np.unique(flat[keep], return_inverse=True)
        if len(ids) < 2:
            return 0.0
        colours = cie[keep]
        counts = np.bincount(own, minlength=len(ids))[:, None]
        means = (np.stack([np.bincount(own, colours[:, c], len(ids)) for c in range(3)], 1) / counts).astype(np.float32)
        # |x - m|² less |x|², the same for every label of a pixel
        dist = (means**2).sum(1)[None] - 2.0 * colours @ means.T
        return float((dist.argmin(1) != own).mean())
