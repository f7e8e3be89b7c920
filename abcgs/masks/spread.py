"""Spreading lifted labels along the Gaussians' surfaces: the far side of an object labelled from one side.

Lifting (Eq. 2) labels only the Gaussians the labelled views see. On a 360° capture labelled on one view the back of
the tree, and whatever the labelled view left undecided, has no vote. :func:`spread_labels` fills those Gaussians
from the decided ones in rounds, like a flood fill over a k-nearest-neighbour graph of the Gaussians:

- **Graph.** Each Gaussian is a point of :func:`surface_features`: its centre divided by the scene's extent, and its
  base colour (SH DC, RGB in 0..1) times ``colour_weight``. Neighbours are near in space *and* alike in colour, so
  a label follows the surface it was painted on (the pink canopy, the brown pot) and stops where the colour changes.
- **Rounds.** In each round every Gaussian still to fill that has labelled neighbours takes the label with the
  largest summed weight ``opacity_j · exp(-(d_ij / σ)²)`` over them (σ: the median distance to the k-th neighbour);
  the labels it took count from the next round on. The rounds stop when none changes; a Gaussian no chain of
  neighbours reaches keeps its label (0).

Seeds vote with their label, 0 included: a decided 0 is the user's "no label" (the background brush), which spreads
like any label. A Gaussian left undecided (seen only in pixels the cut left undecided, or never seen) is no seed, so
a gap the page could not decide is filled from the labels round it, never with "no label" by default.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from abcgs.gaussians import GaussianModel
from abcgs.render import sh0_to_rgb


def surface_features(model: GaussianModel, colour_weight: float) -> Tensor:
    """``(N, 6) float64``: centres over the scene's extent (the median distance of the centres from their median,
    world units → 1) and ``colour_weight`` × base colour (SH DC as RGB, clamped to 0..1)."""
    means = model.means.detach().cpu().double()
    centre = means.median(0).values
    extent = float((means - centre).norm(dim=1).median().clamp_min(1e-12))
    rgb = sh0_to_rgb(model.sh0.detach().cpu().double()[:, 0, :]).clamp(0.0, 1.0)
    return torch.cat([(means - centre) / extent, colour_weight * rgb], dim=1)


def spread_labels(features: Tensor, labels: Tensor, seeds: Tensor, fill: Tensor, weights: Tensor | None = None,
                  k: int = 8, max_rounds: int = 1000) -> tuple[Tensor, int]:
    """Fill the labels of ``fill`` Gaussians from the ``seeds`` by rounds of k-NN votes (module docstring).

    Args:
        features: ``(N, D)`` points of the graph (:func:`surface_features`). labels: ``(N,) int64``, 0..L.
        seeds: ``(N,) bool``, the Gaussians whose label votes from the start. fill: ``(N,) bool``, those to label
            (a seed is never refilled). weights: ``(N,)`` each Gaussian's vote weight (its opacity); None: 1.
        k: neighbours per Gaussian. max_rounds: a bound on the rounds.

    Returns:
        the labels (those of ``fill`` Gaussians no chain reaches are kept) and the number of rounds run.
    """
    from scipy.spatial import cKDTree

    out = labels.clone()
    fill = fill & ~seeds
    if not bool(fill.any()) or not bool(seeds.any()):
        return out, 0
    pts = features.detach().cpu().double().numpy()
    kk = min(k + 1, len(pts))
    dist, nn = cKDTree(pts).query(pts, k=kk)  # the first neighbour is the point itself
    dist, nn = np.asarray(dist).reshape(len(pts), kk)[:, 1:], np.asarray(nn).reshape(len(pts), kk)[:, 1:]
    if nn.shape[1] == 0:
        return out, 0
    sigma = max(float(np.median(dist[:, -1])), 1e-12)
    w = np.ones(len(pts)) if weights is None else weights.detach().cpu().double().numpy()
    edge = w[nn] * np.exp(-((dist / sigma) ** 2))  # (N, k) vote weight of neighbour j for point i
    lab = out.numpy().copy()
    known = seeds.numpy().copy()
    todo = np.flatnonzero(fill.numpy())
    n_labels = int(lab.max()) + 1
    rounds = 0
    while len(todo) and rounds < max_rounds:
        rounds += 1
        nb = nn[todo]
        vote = np.where(known[nb], edge[todo], 0.0)
        reached = vote.sum(1) > 0
        if not reached.any():
            break
        tally = np.zeros((len(todo), n_labels))
        np.add.at(tally, (np.repeat(np.arange(len(todo)), nb.shape[1]), lab[nb].ravel()), vote.ravel())
        new = todo[reached]
        lab[new] = tally[reached].argmax(1)
        known[new] = True
        todo = todo[~reached]
    return torch.as_tensor(lab, dtype=labels.dtype), rounds
