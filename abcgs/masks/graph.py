"""The 3-D step of the labels: a graph over the Gaussians' nearest neighbours, and a label diffusion or a geodesic
labelling on it.

Lifting (Eq. 2) labels only the Gaussians that painted views see. The rest of an object, seen from no painted view,
takes its labels from a graph over the Gaussians:

- **Graph** (:func:`gaussian_graph`). Each Gaussian is joined to its ``k`` nearest neighbours (centres over the scene's
  extent, :func:`abcgs.masks.spread.surface_features`' scale), symmetrised. An edge weighs
  ``exp(-d²/(s_i s_j)) · exp(-(Δc/σ_c)²) · exp(-λ_n (1 - |n_i·n_j|))``: near in space for the density there (``s_i``:
  Gaussian i's distance to its k-th neighbour, the local scale of Zelnik-Manor and Perona's self-tuning affinity), alike in base colour (SH DC as RGB, Δc its Euclidean difference) and facing alike (``n``: the
  axis of the Gaussian's smallest scale, the normal of a flat splat), the last two floored at :data:`MIN_ALIKE`. A
  label so follows the surface it was painted on and slows where the colour or the surface turns; parts the k-NN
  graph leaves apart are joined by the shortest edges between them (:func:`bridges`).
- **Diffusion** (:func:`diffuse_labels`): Grady's random walker (2006) with the seeds as hard constraints. For each
  label ``l`` the probability ``x_l`` that a walk from a Gaussian first reaches a seed of label ``l`` solves the
  Dirichlet problem ``(L_UU + ε D_UU) x_l = W_US y_l`` (``L = D - W`` the graph Laplacian, ``U`` the unseeded and
  ``S`` the seeded Gaussians, ``y_l`` the seeds' one-hot labels). The small leak ``ε`` lets a walk die, so a part no
  seed reaches ends with no probability at all, not an even split. The systems are solved by SciPy's conjugate
  gradients (``scipy.sparse.linalg.cg``, Jacobi-preconditioned; the matrix is symmetric positive definite).
- **Geodesic step** (:func:`geodesic_labels`), the alternative to the diffusion that the labels use by default: each
  Gaussian takes the label of the source nearest to it along the graph (Dijkstra, SciPy's ``csgraph``), an edge as
  long as a hop in its ends' local scale plus γ × how unlike its ends are (:meth:`GaussianGraph.lengths`). A seed of
  one Gaussian claims all that is nearer to it than to any other source; in the walk a seed pulls in proportion to
  its size, so a small correction among large seeds moves little.
- **Decision** (:func:`decide_diffused`): a Gaussian takes the label of largest probability when that probability is
  at least ``min_reach`` (a seed reached it) and at least ``min_share`` of what reached it; otherwise it stays
  undecided, and the page shows it as such.

Label 0 is a label like the others here: a seed of 0 is the user's "no label" (the background brush), which spreads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from abcgs.gaussians import GaussianModel


@dataclass(frozen=True)
class GaussianGraph:
    """A symmetric weighted k-NN graph over ``N`` Gaussians.

    ``weights``: ``(N, N)`` ``scipy.sparse.csr_matrix`` float64, zero diagonal, ``w_ij = w_ji ≥ 0`` (module
    docstring). ``degree``: ``(N,)`` float64, its row sums. ``spatial`` and ``contrast``: ``(E,)`` float64, aligned
    with ``weights.data``: each edge's length in its ends' local scale, ``d / sqrt(s_i s_j)``, and how unlike its ends
    are, ``-log`` of the colour-normal(-feature) factor floored at :data:`MIN_ALIKE` (0 alike, at most
    ``-log MIN_ALIKE``); :meth:`lengths` makes the geodesic step's edge lengths of them."""

    weights: object
    degree: np.ndarray
    spatial: np.ndarray | None = None
    contrast: np.ndarray | None = None

    @property
    def num_nodes(self) -> int:
        return int(self.degree.shape[0])

    def lengths(self, contrast_weight: float) -> object:
        """``(N, N) csr_matrix`` of edge lengths ``spatial + γ · contrast`` (γ = ``contrast_weight``) on the weights'
        edges, each at least :data:`MIN_LENGTH` (SciPy's graph routines take a stored 0 for no edge)."""
        from scipy.sparse import csr_matrix

        if self.spatial is None or self.contrast is None:
            raise ValueError("this graph has no edge terms: build it with gaussian_graph")
        w = self.weights
        data = np.maximum(self.spatial + contrast_weight * self.contrast, MIN_LENGTH)
        return csr_matrix((data, w.indices, w.indptr), shape=w.shape)


def gaussian_normals(model: GaussianModel) -> Tensor:
    """``(N, 3) float64`` unit normals: each Gaussian's axis of smallest scale (world frame)."""
    from abcgs.render.projection import quat_to_rotmat

    rot = quat_to_rotmat(model.quats.detach().cpu().double())  # (N, 3, 3): columns are the local axes, world frame
    axis = model.log_scales.detach().cpu().argmin(1)
    return rot[torch.arange(len(axis)), :, axis]


MIN_ALIKE = 1e-3
"""Least colour-and-normal factor of an edge: a change of colour slows a label a thousandfold but does not wall a part
off, or a region whose every edge to the rest crosses a colour change (a hood's rim) would be reached by no label."""

MIN_LENGTH = 1e-9
"""Least length of an edge in the geodesic step: two Gaussians at one place and alike are still one hop apart."""

BRIDGE_WEIGHT = 1e-3
"""Least weight of an edge :func:`bridges` adds between two parts of the k-NN graph: weak against a neighbour's (up to
1), strong against the walk's leak, so a label crosses a gap only where nothing nearer claims the other side."""


def bridges(pts: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges that join the parts of the k-NN graph ``(rows, cols)`` over points ``pts (N, D)`` into one, as Borůvka's
    minimum spanning tree does: in rounds, every part but the largest is joined to the point nearest to it outside
    it, until one part is left. A clump of Gaussians apart from the rest (a floater, a patch of wall seen from few
    views) so still reaches a label. Returns the added edges' ends and lengths ``(E,)`` each."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(pts)
    tree = cKDTree(pts)
    out_r, out_c, out_d = [], [], []
    while True:
        links = coo_matrix((np.ones(len(rows) + sum(map(len, out_r))),
                            (np.concatenate([rows, *out_r]), np.concatenate([cols, *out_c]))), shape=(n, n))
        n_parts, part = connected_components(links, directed=False)
        if n_parts <= 1:
            break
        largest = np.bincount(part).argmax()
        for p in np.unique(part[part != largest]):
            members = np.flatnonzero(part == p)
            if len(members) > 64:  # a large part: a tree of the points outside it
                others = np.flatnonzero(part != p)
                d, j = cKDTree(pts[others]).query(pts[members], k=1)
                j = others[j]
            else:
                d, j = _nearest_outside(tree, pts, members, part, p)
            best = int(np.argmin(d))
            out_r.append(members[best : best + 1])
            out_c.append(np.asarray(j[best : best + 1], np.int64))
            out_d.append(np.asarray(d[best : best + 1], np.float64))
    if not out_r:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(out_r), np.concatenate(out_c), np.concatenate(out_d)


def _nearest_outside(tree, pts: np.ndarray, members: np.ndarray, part: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """For each of a small part's points, its distance to the nearest point outside the part and that point's index
    (the whole tree queried with a growing number of neighbours)."""
    k = 16
    while True:
        kk = min(k, len(pts))
        d, j = tree.query(pts[members], k=kk)
        outside = part[j] != p
        if outside.any() or kk == len(pts):
            d = np.where(outside, d, np.inf)
            first = d.argmin(1)
            rows = np.arange(len(members))
            return d[rows, first], j[rows, first]
        k *= 4


def gaussian_graph(model: GaussianModel, k: int = 10, colour_sigma: float = 0.15, normal_weight: float = 1.0,
                   features: np.ndarray | None = None, feature_weight: float = 0.0) -> GaussianGraph:
    """The k-NN graph of ``model``'s Gaussians with distance, colour and normal affinities (module docstring), and,
    with ``features``, a part affinity.

    Args:
        model: the fitted scene. k: neighbours per Gaussian (before symmetrising).
        colour_sigma: σ_c of the colour affinity, in RGB 0..1 (``inf``: colour is ignored).
        normal_weight: λ_n of the normal affinity (0: normals are ignored).
        features: ``(N, F)`` per-Gaussian features lifted from the views (:mod:`abcgs.masks.features`), each
            channel of unit variance over the Gaussians, or None.
        feature_weight: λ_f of the part affinity ``exp(-λ_f |f_i - f_j|² / F)`` (0: features are ignored).
    """
    from scipy.sparse import coo_matrix
    from scipy.spatial import cKDTree

    from abcgs.masks.spread import surface_features
    from abcgs.render import sh0_to_rgb

    n = model.num_gaussians
    pts = surface_features(model, 0.0)[:, :3].numpy()
    kk = min(k + 1, n)
    dist, nn = cKDTree(pts).query(pts, k=kk, workers=-1)
    dist, nn = np.asarray(dist).reshape(n, kk)[:, 1:], np.asarray(nn).reshape(n, kk)[:, 1:]
    rows = np.repeat(np.arange(n), nn.shape[1])
    cols, d = nn.ravel(), dist.ravel()
    local = np.maximum(dist[:, -1], 1e-12) if dist.size else np.ones(n)  # each Gaussian's own scale: its k-th neighbour
    rgb = normals = f = None
    if np.isfinite(colour_sigma):
        rgb = sh0_to_rgb(model.sh0.detach().cpu().double()[:, 0, :]).clamp(0.0, 1.0).numpy()
    if normal_weight > 0:
        normals = gaussian_normals(model).numpy()
    if features is not None and feature_weight > 0:
        f = np.asarray(features, np.float64)
        if f.shape[0] != n or not np.isfinite(f).all():
            raise ValueError(f"features must be finite and of {n} rows, got {f.shape}")

    def alike(r: np.ndarray, c: np.ndarray) -> np.ndarray:
        """The colour, normal and feature factor of the edges ``(r, c)``, before the floor."""
        out = np.ones(len(r))
        if rgb is not None:
            out *= np.exp(-(np.linalg.norm(rgb[r] - rgb[c], axis=1) / colour_sigma) ** 2)
        if normals is not None:
            out *= np.exp(-normal_weight * (1.0 - np.abs((normals[r] * normals[c]).sum(1))))
        if f is not None:
            out *= np.exp(-feature_weight * ((f[r] - f[c]) ** 2).sum(1) / max(f.shape[1], 1))
        return out

    w = np.exp(-(d**2) / (local[rows] * local[cols])) * np.maximum(alike(rows, cols), MIN_ALIKE)
    w = np.maximum(w, 1e-12)
    b_rows, b_cols, b_d = bridges(pts, rows, cols)
    rows, cols = np.concatenate([rows, b_rows]), np.concatenate([cols, b_cols])
    w = np.concatenate([w, np.maximum(np.exp(-(b_d**2) / (local[b_rows] * local[b_cols])), BRIDGE_WEIGHT)])
    mat = coo_matrix((w, (rows, cols)), shape=(n, n)).tocsr()
    mat = mat.maximum(mat.T).tocsr()  # symmetric: i near j or j near i
    mat.setdiag(0.0)
    mat.eliminate_zeros()
    r = np.repeat(np.arange(n), np.diff(mat.indptr))
    c = mat.indices
    spatial = np.linalg.norm(pts[r] - pts[c], axis=1) / np.sqrt(local[r] * local[c])
    contrast = -np.log(np.maximum(alike(r, c), MIN_ALIKE))
    return GaussianGraph(mat, np.asarray(mat.sum(1)).ravel(), spatial, contrast)


def diffuse_labels(graph: GaussianGraph, seeds: np.ndarray, n_labels: int, *, leak: float = 1e-5,
                   rtol: float = 1e-6, x0: np.ndarray | None = None, priors: np.ndarray | None = None) -> np.ndarray:
    """Random-walker probabilities ``(N, n_labels + 1) float64`` of labels 0..n_labels (module docstring).

    Args:
        graph: :func:`gaussian_graph`. seeds: ``(N,) int``: the label (0..n_labels) of each seeded Gaussian, -1 for
            the others. leak: ε, the share of a walk's degree lost at each step. rtol: the solver's relative
            tolerance. x0: a previous result ``(N, n_labels + 1)`` to start from (the page re-solves after each
            Segment with a few seeds changed). priors: ``(N, n_labels + 1)`` float ≥ 0 or None: the weight of an edge
            from each Gaussian to a terminal of each label (Grady's prior models, 2005): soft evidence that pulls a
            free Gaussian to a label in proportion, against its neighbours (its degree); seeds ignore theirs.

    Seeds keep their label with probability 1. A Gaussian no seed or prior reaches has probability 0 for every label.
    With priors, each label's system is ``(L_UU + ε D_UU + Λ_U) x_l = W_US y_l + λ_Ul`` (``Λ`` the diagonal of the
    priors' row sums, ``λ_l`` label l's column).
    """
    from scipy.sparse import diags
    from scipy.sparse.linalg import cg

    seeds = np.asarray(seeds, np.int64)
    if seeds.shape != (graph.num_nodes,):
        raise ValueError(f"seeds has shape {seeds.shape}, the graph {graph.num_nodes} nodes")
    if priors is not None:
        priors = np.asarray(priors, np.float64)
        if priors.shape != (graph.num_nodes, n_labels + 1) or not np.isfinite(priors).all() or (priors < 0).any():
            raise ValueError(f"priors must be finite, ≥ 0 and of shape {(graph.num_nodes, n_labels + 1)}, got "
                             f"{priors.shape}")
    probs = np.zeros((graph.num_nodes, n_labels + 1))
    seeded = seeds >= 0
    probs[np.flatnonzero(seeded), seeds[seeded]] = 1.0
    free = np.flatnonzero(~seeded)
    prior_u = None if priors is None else priors[free]
    labels = set(np.unique(seeds[seeded]).tolist())
    if prior_u is not None:
        labels |= set(np.flatnonzero(prior_u.sum(0) > 0).tolist())
    if not free.size or not labels:
        return probs
    w = graph.weights
    rows = w[free]
    diag = (1.0 + leak) * graph.degree[free] + (0.0 if prior_u is None else prior_u.sum(1))
    a = (diags(diag) - rows[:, free]).tocsr()
    w_us = rows[:, np.flatnonzero(seeded)]
    jacobi = diags(1.0 / np.maximum(a.diagonal(), 1e-300))
    for label in sorted(labels):
        b = w_us @ (seeds[seeded] == label).astype(np.float64)
        if prior_u is not None:
            b = b + prior_u[:, label]
        start = None if x0 is None else x0[free, label]
        x, info = cg(a, b, x0=start, rtol=rtol, atol=0.0, maxiter=10 * free.size, M=jacobi)
        if info > 0:
            raise RuntimeError(f"the label diffusion did not converge for label {label} ({info} iterations)")
        probs[free, label] = np.clip(x, 0.0, 1.0)
    return probs


def decide_diffused(probs: np.ndarray, *, min_reach: float = 0.05, min_share: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Labels ``(N,) int64`` and ``decided (N,) bool`` from :func:`diffuse_labels`' probabilities: the label of
    largest probability where it is at least ``min_reach`` and ``min_share`` of the Gaussian's total; else 0 and
    undecided."""
    best = probs.argmax(1)
    top = probs[np.arange(len(best)), best]
    decided = (top >= min_reach) & (top >= min_share * probs.sum(1))
    return np.where(decided, best, 0).astype(np.int64), decided


def geodesic_labels(graph: GaussianGraph, seeds: np.ndarray, n_labels: int, *, contrast_weight: float = 1.0,
                    evidence: np.ndarray | None = None, evidence_cost: float = 4.0, weak_evidence: float = 0.0,
                    weak_reach: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """The geodesic 3-D step: each Gaussian takes the label of the source nearest to it along the graph.

    An edge's length is :meth:`GaussianGraph.lengths` (a hop in the local scale, plus γ = ``contrast_weight`` times
    how unlike its ends are), so a label runs freely over a surface of one colour and pays to cross a change of colour
    or of facing. The sources of label ``l`` are its seeds (``seeds``: ``(N,) int``, the label 0..n_labels of each
    seeded Gaussian, -1 for the others), at distance 0, and, with ``evidence`` ``(N, n_labels + 1)`` in ``[0, 1]`` (a
    Gaussian's share of its cut votes per label), every unseeded Gaussian with evidence for ``l``, at distance
    ``evidence_cost × (1 - evidence)``: sure evidence is nearly a seed, weak evidence is taken over by a seed that is
    geodesically near.

    Unlike the random walk, where a seed pulls in proportion to its size, a seed of one Gaussian claims everything
    nearer to it than to any other source: a correction changes what lies near it and nothing else (adding a
    source can only change the Gaussians it is now nearest to). Seeds keep their label. Evidence under
    ``weak_evidence`` is a weak source: it claims only what lies within ``weak_reach`` of the graph's length (its
    starting distance included) and is nearer to it than to any other source; beyond, the other sources decide, as
    if it were not there. A faint colour region far from any stroke so labels the splats it covers and those next to
    them, not a stretch of the graph that no source of its own label is near.

    Returns ``labels (N,) int64`` and ``distance (N,) float64`` to the nearest source (``inf`` where none is
    reachable; those Gaussians get label 0 and are the caller's undecided).
    """
    n = graph.num_nodes
    seeds = np.asarray(seeds, np.int64)
    if seeds.shape != (n,):
        raise ValueError(f"seeds has shape {seeds.shape}, the graph {n} nodes")
    if not np.isfinite(contrast_weight) or contrast_weight < 0:
        raise ValueError(f"contrast_weight must be finite and ≥ 0, got {contrast_weight}")
    seeded = np.flatnonzero(seeds >= 0)
    src_label, src_node = [seeds[seeded]], [seeded]
    src_cost, src_weak = [np.zeros(len(seeded))], [np.zeros(len(seeded), bool)]
    if evidence is not None:
        evidence = np.asarray(evidence, np.float64)
        if evidence.shape != (n, n_labels + 1) or not np.isfinite(evidence).all() or (evidence < 0).any():
            raise ValueError(f"evidence must be finite, ≥ 0 and of shape {(n, n_labels + 1)}, got {evidence.shape}")
        node, label = np.nonzero((evidence > 0) & (seeds < 0)[:, None])
        src_label.append(label)
        src_node.append(node)
        src_cost.append(evidence_cost * (1.0 - np.clip(evidence[node, label], 0.0, 1.0)))
        src_weak.append(evidence[node, label] < weak_evidence)
    label, node, cost, weak = (np.concatenate(a) for a in (src_label, src_node, src_cost, src_weak))
    labels = np.zeros(n, np.int64)
    distance = np.full(n, np.inf)
    if not len(node):
        return labels, distance
    lengths = graph.lengths(contrast_weight).tocoo()
    dist, origin = _nearest_source(lengths, n, n_labels, label[~weak], node[~weak], cost[~weak], np.inf)
    if weak.any():  # the weak sources, within their reach, take what they are nearer to
        near, near_origin = _nearest_source(lengths, n, n_labels, label[weak], node[weak], cost[weak], weak_reach)
        take = near < dist
        dist, origin = np.where(take, near, dist), np.where(take, near_origin, origin)
    reached = np.isfinite(dist)
    labels[reached] = origin[reached]
    distance[reached] = dist[reached]
    labels[seeds >= 0] = seeds[seeds >= 0]
    return labels, distance


def _nearest_source(lengths, n: int, n_labels: int, label: np.ndarray, node: np.ndarray, cost: np.ndarray,
                    limit: float) -> tuple[np.ndarray, np.ndarray]:
    """Each of the ``n`` nodes' distance ``(n,)`` to the nearest source (``node``, of ``label``, starting at ``cost``)
    along the graph's edge ``lengths`` (COO, ``n × n``), ``inf`` past ``limit`` or where none is reachable, and that
    source's label ``(n,) int64`` (-1 there)."""
    from scipy.sparse import coo_matrix, csr_matrix
    from scipy.sparse.csgraph import dijkstra

    if not len(node):
        return np.full(n, np.inf), np.full(n, -1, np.int64)
    # one virtual source per label (nodes n .. n + n_labels), joined to its sources by their starting distance
    m = n + n_labels + 1
    start = coo_matrix((np.maximum(cost, MIN_LENGTH), (n + label, node)), shape=(m, m))
    full = csr_matrix(coo_matrix((np.concatenate([lengths.data, start.data]),
                                  (np.concatenate([lengths.row, start.row]), np.concatenate([lengths.col, start.col]))),
                                 shape=(m, m)))
    dist, _, origin = dijkstra(full, directed=True, indices=n + np.unique(label), min_only=True,
                               return_predecessors=True, limit=limit)
    dist = dist[:n]
    return dist, np.where(np.isfinite(dist), origin[:n] - n, -1).astype(np.int64)
