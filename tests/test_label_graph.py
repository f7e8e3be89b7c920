"""The 3-D step of the labels (abcgs/masks/graph.py): the k-NN graph's affinities and the random walker, checked against
a dense solve of the same Dirichlet problem."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from abcgs.gaussians import GaussianModel
from abcgs.masks.graph import (
    BRIDGE_WEIGHT,
    decide_diffused,
    diffuse_labels,
    gaussian_graph,
    gaussian_normals,
    geodesic_labels,
)
from abcgs.render.sh import rgb_to_sh0


def _model(points: np.ndarray, rgb: np.ndarray, quats: np.ndarray | None = None,
           scales: np.ndarray | None = None) -> GaussianModel:
    n = len(points)
    model = GaussianModel.from_points(torch.as_tensor(points, dtype=torch.float32),
                                      torch.as_tensor(rgb, dtype=torch.float32), 0, 0.5)
    with torch.no_grad():
        model.sh0.copy_(rgb_to_sh0(torch.as_tensor(rgb, dtype=torch.float32))[:, None, :])
        if quats is not None:
            model.quats.copy_(torch.as_tensor(quats, dtype=torch.float32))
        if scales is not None:
            model.log_scales.copy_(torch.log(torch.as_tensor(scales, dtype=torch.float32)))
    assert model.num_gaussians == n
    return model


def _two_blobs(seed: int = 0, n: int = 200) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = rng.normal(0, 0.15, (n, 3))
    b = rng.normal(0, 0.15, (n, 3)) + [1.0, 0, 0]
    rgb = np.concatenate([np.tile([0.9, 0.1, 0.1], (n, 1)), np.tile([0.1, 0.1, 0.9], (n, 1))])
    return np.concatenate([a, b]), rgb


def test_graph_is_symmetric_and_weighs_colour():
    pts, rgb = _two_blobs()
    g = gaussian_graph(_model(pts, rgb), k=8, colour_sigma=0.15, normal_weight=0.0)
    w = g.weights
    assert abs(w - w.T).max() < 1e-12
    assert w.diagonal().max() == 0.0
    np.testing.assert_allclose(g.degree, np.asarray(w.sum(1)).ravel())
    coo = w.tocoo()
    same = (coo.row < 200) == (coo.col < 200)
    assert coo.data[same].min() > 10 * coo.data[~same].max()  # red-blue edges are far weaker than red-red ones


def test_normals_are_the_axis_of_smallest_scale():
    pts = np.zeros((2, 3))
    # identity rotation, flat in z → normal z; 90° about x turns the local z axis to -y
    quats = np.array([[1, 0, 0, 0], [np.cos(np.pi / 4), np.sin(np.pi / 4), 0, 0]])
    scales = np.array([[1.0, 1.0, 0.01], [1.0, 1.0, 0.01]])
    n = gaussian_normals(_model(pts + [[0, 0, 0], [1, 0, 0]], np.full((2, 3), 0.5), quats, scales)).numpy()
    np.testing.assert_allclose(np.abs(n), [[0, 0, 1], [0, 1, 0]], atol=1e-6)


def test_diffusion_matches_a_dense_solve_of_the_dirichlet_problem():
    pts, rgb = _two_blobs(1, 60)
    g = gaussian_graph(_model(pts, rgb), k=6, colour_sigma=0.3, normal_weight=0.0)
    seeds = np.full(g.num_nodes, -1)
    seeds[[0, 5]] = 1
    seeds[[70, 80]] = 2
    seeds[[3]] = 0
    leak = 1e-2
    probs = diffuse_labels(g, seeds, 2, leak=leak, rtol=1e-12)
    w = g.weights.toarray()
    free, fixed = np.flatnonzero(seeds < 0), np.flatnonzero(seeds >= 0)
    a = np.diag((1 + leak) * w.sum(1))[np.ix_(free, free)] - w[np.ix_(free, free)]
    for label in (0, 1, 2):
        want = np.linalg.solve(a, w[np.ix_(free, fixed)] @ (seeds[fixed] == label))
        np.testing.assert_allclose(probs[free, label], want, atol=1e-8)
    np.testing.assert_array_equal(probs[fixed].argmax(1), seeds[fixed])
    assert np.all(probs.sum(1) <= 1 + 1e-9)  # the leak only loses probability


def test_each_blob_takes_its_seeds_label_and_a_clump_apart_is_bridged_to_the_nearest():
    from scipy.sparse.csgraph import connected_components

    pts, rgb = _two_blobs(2)
    far = np.random.default_rng(3).normal(0, 0.05, (30, 3)) + [6.0, 0, 0]  # beyond blob 2: no k-NN edge reaches it
    model = _model(np.concatenate([pts, far]), np.concatenate([rgb, np.full((30, 3), 0.5)]))
    g = gaussian_graph(model, k=8)
    assert connected_components(g.weights, directed=False)[0] == 1
    seeds = np.full(g.num_nodes, -1)
    seeds[0], seeds[200] = 1, 2
    labels, decided = decide_diffused(diffuse_labels(g, seeds, 2, leak=1e-5))
    assert (labels[:200] == 1).mean() > 0.99 and (labels[200:400] == 2).mean() > 0.99
    assert decided[400:].all() and (labels[400:] == 2).all()  # across the bridge from blob 2, the nearer
    # with a walk that dies fast, the bridge carries too little: the clump stays undecided
    labels, decided = decide_diffused(diffuse_labels(g, seeds, 2, leak=1e-1))
    assert not decided[400:].any() and (labels[400:] == 0).all()


def test_decision_needs_reach_and_a_majority():
    probs = np.array([[0.0, 0.9, 0.1], [0.0, 0.02, 0.01], [0.3, 0.35, 0.35], [0.0, 0.3, 0.2]])
    labels, decided = decide_diffused(probs, min_reach=0.05, min_share=0.5)
    np.testing.assert_array_equal(decided, [True, False, False, True])
    np.testing.assert_array_equal(labels, [1, 0, 0, 1])


@pytest.mark.parametrize("bad", [np.zeros(3, np.int64), np.full((5, 2), -1)])
def test_seeds_of_the_wrong_shape_are_refused(bad):
    pts, rgb = _two_blobs(4, 10)
    g = gaussian_graph(_model(pts, rgb), k=4)
    with pytest.raises(ValueError, match="seeds has shape"):
        diffuse_labels(g, bad, 1)


def test_diffusion_with_priors_matches_a_dense_solve_of_grady_s_prior_model():
    """Soft evidence: each free Gaussian joined to a terminal of each label with weight λ_il; the system
    (L_UU + ε D_UU + diag(Σ_l λ_il)) x_l = W_US y_l + λ_l, solved densely here."""
    pts, rgb = _two_blobs(2, 50)
    g = gaussian_graph(_model(pts, rgb), k=6, colour_sigma=0.3, normal_weight=0.0)
    rng = np.random.default_rng(3)
    seeds = np.full(g.num_nodes, -1)
    seeds[[0, 60]] = [1, 2]
    priors = np.zeros((g.num_nodes, 3))
    some = rng.choice(g.num_nodes, 30, replace=False)
    priors[some, rng.integers(0, 3, 30)] = rng.uniform(0.1, 2.0, 30)
    leak = 1e-2
    probs = diffuse_labels(g, seeds, 2, leak=leak, rtol=1e-12, priors=priors)
    w = g.weights.toarray()
    free, fixed = np.flatnonzero(seeds < 0), np.flatnonzero(seeds >= 0)
    a = np.diag((1 + leak) * w.sum(1) + priors.sum(1))[np.ix_(free, free)] - w[np.ix_(free, free)]
    for label in (0, 1, 2):
        want = np.linalg.solve(a, w[np.ix_(free, fixed)] @ (seeds[fixed] == label) + priors[free, label])
        np.testing.assert_allclose(probs[free, label], want, atol=1e-8)
    assert probs[fixed, seeds[fixed]].min() == 1.0  # seeds ignore their priors
    # evidence alone, no seed: still a solution, and a Gaussian with strong evidence follows it
    alone = diffuse_labels(g, np.full(g.num_nodes, -1), 2, leak=leak, rtol=1e-12, priors=priors * 100)
    strong = some[priors[some].max(1) > 1.0]
    np.testing.assert_array_equal(alone[strong].argmax(1), priors[strong].argmax(1))
    with pytest.raises(ValueError, match="priors must be finite"):
        diffuse_labels(g, seeds, 2, priors=-priors)


# ------------------------------------------------------------------------------------------ the geodesic step


def _floyd(lengths: np.ndarray) -> np.ndarray:
    """All-pairs shortest paths of a dense length matrix (0 = no edge), Floyd–Warshall: the reference."""
    d = np.where(lengths > 0, lengths, np.inf)
    np.fill_diagonal(d, 0.0)
    for k in range(len(d)):
        d = np.minimum(d, d[:, k : k + 1] + d[k : k + 1, :])
    return d


def test_edge_terms_are_aligned_with_the_weights_and_give_back_the_walk_s_weights():
    pts, rgb = _two_blobs(5, 40)
    g = gaussian_graph(_model(pts, rgb), k=6, colour_sigma=0.3, normal_weight=0.0)
    assert g.spatial.shape == g.contrast.shape == g.weights.data.shape
    # a k-NN edge's weight is exp(-spatial²) · exp(-contrast), a bridge's max(exp(-spatial²), BRIDGE_WEIGHT): the two
    # terms say what the weight says
    knn = np.isclose(g.weights.data, np.maximum(np.exp(-(g.spatial**2) - g.contrast), 1e-12), rtol=1e-9)
    bridge = np.isclose(g.weights.data, np.maximum(np.exp(-(g.spatial**2)), BRIDGE_WEIGHT), rtol=1e-9)
    assert (knn | bridge).all() and knn.mean() > 0.95
    lengths = g.lengths(2.0).toarray()
    assert abs(lengths - lengths.T).max() < 1e-12
    np.testing.assert_allclose(g.lengths(2.0).data, g.spatial + 2.0 * g.contrast, rtol=1e-12)


def _sources(n_evidence: int, seed: int):
    """The two-blob graph, two seeds and ``n_evidence`` random evidence entries in (0.05, 1)."""
    pts, rgb = _two_blobs(6, 40)
    g = gaussian_graph(_model(pts, rgb), k=6, colour_sigma=0.3, normal_weight=0.0)
    rng = np.random.default_rng(seed)
    seeds = np.full(g.num_nodes, -1)
    seeds[[0, 45]] = [1, 2]
    evidence = np.zeros((g.num_nodes, 3))
    some = rng.choice(g.num_nodes, n_evidence, replace=False)
    evidence[some, rng.integers(0, 3, n_evidence)] = rng.uniform(0.05, 1.0, n_evidence)
    return g, seeds, evidence


def _assert_nearest_source(g, seeds, evidence, labels, distance, *, contrast: float, cost: float,
                           weak: float = 0.0, reach: float = np.inf) -> None:
    """``labels`` and ``distance`` are those of the nearest source by Floyd–Warshall: per label, the least of its
    seeds' distances and of its evidence's ``cost × (1 - e)`` + path, evidence under ``weak`` only within ``reach``."""
    d = _floyd(g.lengths(contrast).toarray())
    best = np.full((g.num_nodes, 3), np.inf)  # per label: min over its sources of (start + path)
    for i in np.flatnonzero(seeds >= 0):
        best[:, seeds[i]] = np.minimum(best[:, seeds[i]], d[i])
    for i, lab in zip(*np.nonzero((evidence > 0) & (seeds < 0)[:, None])):
        far = cost * (1 - evidence[i, lab]) + d[i]
        if evidence[i, lab] < weak:
            far = np.where(far <= reach, far, np.inf)
        best[:, lab] = np.minimum(best[:, lab], far)
    free = seeds < 0
    np.testing.assert_allclose(distance[free], best[free].min(1), rtol=1e-9, atol=1e-6)
    clear = np.sort(best, 1)[:, 1] - np.sort(best, 1)[:, 0] > 1e-9  # ties may go either way
    np.testing.assert_array_equal(labels[free & clear], best[free & clear].argmin(1))
    np.testing.assert_array_equal(labels[~free], seeds[~free])


def test_geodesic_labels_match_the_nearest_source_by_floyd_warshall():
    g, seeds, evidence = _sources(25, 7)
    labels, distance = geodesic_labels(g, seeds, 2, contrast_weight=3.0, evidence=evidence, evidence_cost=5.0)
    _assert_nearest_source(g, seeds, evidence, labels, distance, contrast=3.0, cost=5.0)
    with pytest.raises(ValueError, match="evidence must be finite"):
        geodesic_labels(g, seeds, 2, evidence=-evidence)


def test_weak_evidence_claims_only_within_its_reach_as_floyd_warshall_says():
    """Evidence under ``weak_evidence`` is a source whose label reaches at most ``weak_reach`` (its start included):
    each Gaussian's distance and label are the nearest source's among the strong ones (anywhere) and the weak ones
    (within reach), by all-pairs shortest paths."""
    g, seeds, evidence = _sources(15, 11)
    labels, distance = geodesic_labels(g, seeds, 2, contrast_weight=3.0, evidence=evidence, evidence_cost=4.0,
                                       weak_evidence=0.6, weak_reach=2.5)
    _assert_nearest_source(g, seeds, evidence, labels, distance, contrast=3.0, cost=4.0, weak=0.6, reach=2.5)
    unlimited, _ = geodesic_labels(g, seeds, 2, contrast_weight=3.0, evidence=evidence, evidence_cost=4.0)
    assert (unlimited != labels).any()  # the reach matters here: some Gaussians went to a weak source's label


def test_a_faint_region_far_from_its_labels_sources_labels_what_it_covers_not_the_graph_beyond():
    """A bar of one colour: label 1 is seeded at the left end, label 2 at the right end; a faint region of label 2
    (evidence 0.1, as a click's colour region weighs) lies just right of the middle. Unlimited, it is a source as far as
    the graph goes and takes Gaussians up to half-way to the left seed; with a weak reach, it labels what it covers
    and what is next to it, and the rest stays with the seeds."""
    rng = np.random.default_rng(3)
    pts = rng.uniform([0, 0, 0], [4, 0.2, 0.2], (400, 3))
    g = gaussian_graph(_model(pts, np.full((400, 3), 0.5)), k=8, normal_weight=0.0)
    seeds = np.full(400, -1)
    seeds[pts[:, 0] < 0.1] = 1
    seeds[pts[:, 0] > 3.9] = 2
    evidence = np.zeros((400, 3))
    faint = (pts[:, 0] > 2.1) & (pts[:, 0] < 2.3)
    evidence[faint, 2] = 0.1
    free, _ = geodesic_labels(g, seeds, 2, evidence=evidence, evidence_cost=4.0)
    near, _ = geodesic_labels(g, seeds, 2, evidence=evidence, evidence_cost=4.0, weak_evidence=0.25, weak_reach=6.0)
    assert (near[faint] == 2).all() and (free[faint] == 2).all()
    left_of_it = (pts[:, 0] > 1.4) & (pts[:, 0] < 1.75)
    assert (free[left_of_it] == 2).mean() > 0.9  # unlimited, the faint source outruns label 1's seed
    assert (near[left_of_it] == 1).mean() > 0.9  # within its reach, it does not


def test_a_one_gaussian_correction_claims_its_part_where_the_walk_lets_the_big_seed_win():
    """Two parts of one colour, joined; the left part is covered by weak evidence for label 1 (a cut far from its
    strokes), the right end holds a large stroke of label 1. One seeded Gaussian of label 2 in the left part: the
    geodesic step gives it the left part; what it changes lies on its side only."""
    rng = np.random.default_rng(8)
    pts = np.concatenate([rng.uniform([0, 0, 0], [1, 0.2, 0.2], (150, 3)),
                          rng.uniform([1, 0, 0], [2, 0.2, 0.2], (150, 3))])
    g = gaussian_graph(_model(pts, np.full((300, 3), 0.5)), k=8, normal_weight=0.0)
    seeds = np.full(300, -1)
    seeds[np.flatnonzero(pts[:, 0] > 1.8)] = 1
    evidence = np.zeros((300, 3))
    evidence[pts[:, 0] < 1.0, 1] = 0.05
    before, _ = geodesic_labels(g, seeds, 2, evidence=evidence, evidence_cost=20.0)
    assert (before == 1).all()
    seeds[np.argmin(np.linalg.norm(pts - [0.3, 0.1, 0.1], axis=1))] = 2
    after, _ = geodesic_labels(g, seeds, 2, evidence=evidence, evidence_cost=20.0)
    assert (after[pts[:, 0] < 0.6] == 2).mean() > 0.9
    assert (after[pts[:, 0] > 1.2] == 1).all()  # the far side keeps its label
    changed = after != before
    assert pts[changed, 0].max() < 1.2
