"""A scene's labels from the views a user painted: what the masks page shows after each Segment and what the ``masks``
stage writes, by the same code.

For each painted view the page keeps its cut (the label map the page saved: 0..L, :data:`~abcgs.masks.lifting.NO_VOTE`
where the cut left a pixel undecided) and its strokes (a seed map: -1 none, 0 the background brush, k label k).
:meth:`LabelField.solve` turns them into one label per Gaussian:

1. **Strokes are hard constraints**: a Gaussian that blends at least ``stroke_weight`` into a view's stroke pixels,
   with at least ``stroke_share`` of its blending weight in that view under them, takes the stroke's label, whatever
   the cuts say (the largest such weight wins between strokes). No cut of any view flips it.
2. **Cuts are soft evidence** (``cut_evidence: soft``, the default). Every painted view's cut votes (Eq. 2), each
   Gaussian for the labels of the pixels it blends into, each pixel weighted by how sure the cut is there
   (:func:`cut_confidence`): near the strokes of its own view fully, falling off with the distance to them
   (``cut_reach``); where GrabCut's two colour models differ little (``cut_margin``) the page's cut leaves the pixel
   undecided. A correction's colour regions (``correction: region``) lie over the view's cut, if it has one, and
   beyond their strokes weigh ``region_weight`` of that where the cut gave another label: a flood of a stroke's colour
   is less sure than a cut (:func:`~abcgs.masks.regions.view_evidence`). A Gaussian's evidence for label l is its
   confident vote for l over its blending weight in the whole view (``evidence_of: view``; ``decided``: in the pixels
   the cut decided), so a large splat a correction covers in part is weak evidence; under ``cut_share`` of that weight
   on decided pixels, the view casts no vote on it at all, and the splat keeps what the other views say of it. What lies
   behind the view's surface (by more than ``occlusion`` of its depth) takes no vote from its cut
   (:func:`~abcgs.masks.lifting.occluded_gaussians`): a large splat that paints a part seen from the far side of the
   object is not given the label of the part in front of it.
3. **The 3-D step** (:mod:`abcgs.masks.graph`, ``solver``): ``geodesic`` (the default) gives each Gaussian the label
   of the stroke or the evidence nearest to it along the Gaussians' neighbour graph, evidence e starting at
   ``evidence_cost × (1 - e)``; ``walk`` is a random walk over the same graph with the strokes as seeds and the cuts'
   evidence as priors (Grady's random walker with prior models: each Gaussian is also joined, with ``cut_weight`` ×
   its degree × its evidence, to a terminal of each label). A correction (its strokes, each stroke's colour region
   with ``correction: region``, or with ``correction: cut`` its view's cut again) so changes what it binds, what
   its view is sure of and what lies nearest to it in 3-D, not what the other views are sure of. ``cut_evidence:
   hard`` is the earlier rule: a Gaussian whose summed vote is clear (:func:`~abcgs.masks.lifting.decide_labels`) is a
   seed of its label.

Each view's votes are computed once, when its cut or strokes change, so a Segment on one view re-lifts one view and
re-solves the graph. Rendering the labels into every view is the caller's (the stage renders full-size maps, the page
a strip of small ones, :mod:`abcgs.masks.page.strip`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import cv2
import numpy as np
import torch

from abcgs.cameras import Camera
from abcgs.gaussians import GaussianModel
from abcgs.io.images import resized_labels
from abcgs.masks.graph import GaussianGraph, decide_diffused, diffuse_labels, gaussian_graph, geodesic_labels
from abcgs.masks.lifting import (
    NO_VOTE,
    area_weights,
    blend_votes,
    decide_labels,
    lift_camera,
    occluded_gaussians,
    one_hot_labels,
    pixel_area,
    rendered_depth,
)
from abcgs.masks.params import FieldParams, LiftParams
from abcgs.types import Backend

log = logging.getLogger(__name__)


SOURCES = ("undecided", "stroke", "lifted", "graph")
""":attr:`FieldResult.source`'s values by index: how each Gaussian's label was decided."""


@dataclass
class FieldResult:
    """Per-Gaussian labels and how they were decided.

    ``labels`` ``(N,) int64`` 0..L (0 also where undecided); ``decided`` ``(N,) bool``; ``probs`` ``(N, L + 1)``
    float64 the random walk's label probabilities (1 at seeds; the geodesic step's: 1 at the decided label);
    ``source`` ``(N,) uint8``: 0 undecided, 1 a stroke, 2 the lifted cuts, 3 the 3-D step. ``seconds``: lifting the
    changed views and solving."""

    labels: np.ndarray
    decided: np.ndarray
    probs: np.ndarray
    source: np.ndarray
    n_labels: int
    seconds: float

    def counts(self) -> dict[str, int]:
        """How many Gaussians each step decided (``stroke``, ``lifted``, ``graph``) and how many it left
        ``undecided``."""
        return {n: int((self.source == i).sum()) for i, n in enumerate(SOURCES)}

    def changes_from(self, before: FieldResult) -> dict[str, int]:
        """How many Gaussians carry another label (or another decidedness) than in ``before``, the result of the same
        Gaussians one Segment earlier, counted by the step that decided each now (:data:`SOURCES`)."""
        if before.labels.shape != self.labels.shape:
            raise ValueError(f"{self.labels.shape[0]} Gaussians now, {before.labels.shape[0]} before")
        moved = (self.labels != before.labels) | (self.decided != before.decided)
        return {n: int((moved & (self.source == i)).sum()) for i, n in enumerate(SOURCES)}


@dataclass
class _View:
    cut: np.ndarray | None  # (H, W) int64, NO_VOTE undecided: the view's cut
    strokes: np.ndarray | None  # (H, W) int64 seed map, -1 none
    regions: np.ndarray | None = None  # (H, W) int64, NO_VOTE undecided: its corrections' regions, over the cut
    votes: torch.Tensor | None = None  # (N, L_v + 1) the cut's Eq. 2 votes, each pixel weighted by its confidence
    cover: torch.Tensor | None = None  # (N,) blending weight in the cut's decided pixels
    seen: torch.Tensor | None = None  # (N,) blending weight in the whole view
    stroke_votes: torch.Tensor | None = None  # (N, L_v + 1) blending weight in each label's stroke pixels, if bound


def _evidence_map(cut: np.ndarray | None, regions: np.ndarray | None) -> np.ndarray | None:
    """A view's evidence ``(H, W) int64``: ``regions`` where they decide, ``cut`` elsewhere (NO_VOTE where neither
    does); None if both are None."""
    if regions is None:
        return cut
    return regions if cut is None else np.where(regions >= 0, regions, cut)


def cut_confidence(shape: tuple[int, int], strokes: np.ndarray | None, reach: float) -> np.ndarray:
    """How sure a view's cut is at each pixel, ``(H, W) float32`` in ``(0, 1]``: ``exp(-(d / r)²)`` of the distance
    ``d`` (pixels) to the nearest stroke of the view, ``r`` = ``reach`` × the view's shorter side. A view without
    strokes (a label map given as it is) is sure everywhere."""
    if strokes is None or not (strokes >= 0).any():
        return np.ones(shape, np.float32)
    d = cv2.distanceTransform((strokes < 0).astype(np.uint8), cv2.DIST_L2, 5)
    r = max(reach * min(shape), 1e-6)
    return np.exp(-((d / r) ** 2)).astype(np.float32)


@dataclass
class LabelField:
    """The labels of ``model`` from painted views of ``cameras`` (module docstring).

    ``graph`` is built on first use (:func:`~abcgs.masks.graph.gaussian_graph`, ``params``' graph settings) and kept:
    the Gaussians do not move while the user paints."""

    model: GaussianModel
    cameras: list[Camera]
    params: FieldParams = field(default_factory=FieldParams)
    lift: LiftParams = field(default_factory=LiftParams)
    backend: Backend = "auto"
    _views: dict[int, _View] = field(default_factory=dict)
    _graph: GaussianGraph | None = None
    _last: FieldResult | None = None
    _depths: dict[int, np.ndarray] = field(default_factory=dict)

    @property
    def graph(self) -> GaussianGraph:
        if self._graph is None:
            t0 = time.perf_counter()
            p = self.params
            self._graph = gaussian_graph(self.model, p.k, p.colour_sigma, p.normal_weight)
            log.info("label graph: %d Gaussians, %d edges, %.2f s", self._graph.num_nodes,
                     self._graph.weights.nnz // 2, time.perf_counter() - t0)
        return self._graph

    def use_graph(self, graph: GaussianGraph) -> None:
        """Solve on ``graph`` (of this model's Gaussians) instead of the one ``params`` build, e.g. one with other
        affinities (``eval/bench/graph_features.py``); the next :meth:`solve` starts from zero."""
        if graph.num_nodes != self.model.num_gaussians:
            raise ValueError(f"the graph has {graph.num_nodes} nodes, the model {self.model.num_gaussians} Gaussians")
        self._graph, self._last = graph, None

    def depth_of(self, index: int) -> np.ndarray | None:
        """View ``index``'s rendered depth ``(h, w) float32`` at its lifting size
        (:func:`~abcgs.masks.lifting.rendered_depth`), which bounds its strokes' regions
        (:func:`~abcgs.masks.regions.view_evidence`), rendered once per view; None where no region is made
        (``correction`` other than ``region``) or none is bounded by depth (``region_depth_step`` 0)."""
        if self.params.correction != "region" or self.params.region_depth_step <= 0:
            return None
        if index not in self._depths:
            self._depths[index] = rendered_depth(self.model, self.cameras[index], backend=self.backend)
        return self._depths[index]

    @property
    def painted(self) -> list[int]:
        """The camera indices with a cut or strokes, ascending."""
        return sorted(self._views)

    def cut_of(self, index: int) -> np.ndarray | None:
        """View ``index``'s cut alone ``(H, W) int64`` (0..L, NO_VOTE undecided), or None if it has none."""
        view = self._views.get(index)
        return None if view is None else view.cut

    def evidence_map(self, index: int) -> np.ndarray | None:
        """View ``index``'s evidence ``(H, W) int64`` (0..L, NO_VOTE undecided): its corrections' regions where they
        decide, its cut elsewhere; None if it has neither."""
        view = self._views.get(index)
        return None if view is None else _evidence_map(view.cut, view.regions)

    def saved_of(self, index: int) -> np.ndarray | None:
        """What the masks page saves of view ``index`` ``(H, W) int64`` (0..L, NO_VOTE undecided), from which, with
        the view's strokes and photo, the ``masks`` stage sets the same view (:meth:`set_view`): its cut, or where it
        has none its corrections' regions; None if it has neither."""
        view = self._views.get(index)
        return None if view is None else (view.cut if view.cut is not None else view.regions)

    def set_view(self, index: int, cut: np.ndarray | None, strokes: np.ndarray | None = None, *,
                 regions: np.ndarray | None = None) -> None:
        """Set (or, with all None, remove) view ``index``'s cut ``(H, W) int`` (0..L, NO_VOTE), stroke seed map
        ``(H, W) int`` (-1 none, 0..L) and its corrections' regions ``(H, W) int`` (0..L, NO_VOTE;
        :func:`~abcgs.masks.regions.correction_regions`). The regions overrule the cut where they decide, and there,
        beyond the strokes, where the cut had not already their label, weigh ``region_weight``: a correction on a view
        once cut keeps the rest of its cut (:func:`~abcgs.masks.regions.view_evidence` makes the pair). Its votes are
        computed at the next :meth:`solve`."""
        if cut is None and strokes is None and regions is None:
            self._views.pop(index, None)
            return
        cam = self.cameras[index]
        for what, arr in (("cut", cut), ("strokes", strokes), ("regions", regions)):
            if arr is not None and tuple(arr.shape) != (cam.height, cam.width):
                raise ValueError(f"the {what} of view {cam.name} is {arr.shape[1]}x{arr.shape[0]}, the view "
                                 f"{cam.width}x{cam.height}")
        self._views[index] = _View(*(None if a is None else np.asarray(a, np.int64) for a in (cut, strokes, regions)))

    def _cut_votes(self, view: _View, cam: Camera) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One view's votes ``(N, L_v + 1)`` from its evidence map (:meth:`evidence_map`), each pixel weighted by its
        confidence (1 with ``cut_evidence: hard``; × ``region_weight`` where a correction's region beyond the strokes
        gives a label the cut did not), each Gaussian's blending weight in the map's decided pixels ``(N,)`` and in
        the whole view ``(N,)``."""
        cut = _evidence_map(view.cut, view.regions)
        if self.params.cut_evidence == "soft":
            conf = cut_confidence(cut.shape, view.strokes, self.params.cut_reach)
        else:
            conf = np.ones(cut.shape, np.float32)
        if view.regions is not None:  # a region's own say: beyond its strokes, where the cut gave another label
            flood = view.regions >= 0
            if view.cut is not None:
                flood &= view.cut != view.regions
            if view.strokes is not None:
                flood &= view.strokes < 0
            conf = np.where(flood, conf * self.params.region_weight, conf).astype(np.float32)
        small = lift_camera(cam)
        conf_small = torch.from_numpy(area_weights(conf[..., None], small))
        area = torch.full((small.height, small.width, 1), pixel_area(cut.shape, small))
        hot = one_hot_labels(cut, int(cut.max(initial=0)), small)
        decided = hot.sum(-1, keepdim=True)
        w = blend_votes(self.model, small, torch.cat([hot * conf_small / area, decided, area], -1),
                        backend=self.backend)
        return w[:, :-2], w[:, -2], w[:, -1]

    def _stroke_votes(self, strokes: np.ndarray, cam: Camera) -> torch.Tensor:
        """One view's stroke weights ``(N, L_v + 1)``: per Gaussian and label, its blending weight in the label's
        stroke pixels, kept only for the Gaussians that lie enough under the strokes to be bound by them (at least
        ``stroke_share`` of their blending weight in the view), so that a large splat behind or across a dot is not."""
        seeds = np.where(strokes >= 0, strokes, NO_VOTE)
        small = lift_camera(cam)
        hot = one_hot_labels(seeds, int(seeds.max(initial=0)), small)
        area = torch.full((small.height, small.width, 1), pixel_area(seeds.shape, small))
        w = blend_votes(self.model, small, torch.cat([hot, area], -1), backend=self.backend)
        votes, total = w[:, :-1], w[:, -1]
        under = votes.sum(1) >= self.params.stroke_share * total.clamp_min(1e-12)
        return votes * under[:, None]

    def _votes(self, n_labels: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Summed cut votes ``(N, n_labels + 1)``, blending weight in decided cut pixels ``(N,)`` and in the cut
        views as a whole ``(N,)``, and stroke weights ``(N, n_labels + 1)`` of every painted view (each view's own
        computed once)."""
        n = self.model.num_gaussians
        votes, cover, seen = torch.zeros(n, n_labels + 1), torch.zeros(n), torch.zeros(n)
        strokes = torch.zeros(n, n_labels + 1)
        for i, v in self._views.items():
            cam = self.cameras[i]
            if (v.cut is not None or v.regions is not None) and v.votes is None:
                v.votes, v.cover, v.seen = self._cut_votes(v, cam)
                keep = v.cover >= self.params.cut_share * v.seen  # the splats its cut decided cut_share of
                if self.params.occlusion > 0:  # what the view's surface hides casts no vote there
                    keep &= ~occluded_gaussians(self.model, cam, self.params.occlusion, backend=self.backend)
                if not bool(keep.all()):
                    keep = keep.float()
                    v.votes, v.cover, v.seen = v.votes * keep[:, None], v.cover * keep, v.seen * keep
            if v.strokes is not None and v.stroke_votes is None:
                v.stroke_votes = self._stroke_votes(v.strokes, cam)
            for acc, part in ((votes, v.votes), (strokes, v.stroke_votes)):
                if part is not None:
                    acc[:, : part.shape[1]] += part
            if v.cover is not None:
                cover += v.cover
                seen += v.seen
        return votes, cover, seen, strokes

    def n_labels(self) -> int:
        """The largest label any painted view's cut or strokes holds."""
        return max([0] + [int(a.max(initial=0)) for v in self._views.values() for a in (v.cut, v.strokes, v.regions)
                          if a is not None])

    def solve(self) -> FieldResult:
        """Apply the strokes, weigh the cuts and run the 3-D step (module docstring)."""
        t0 = time.perf_counter()
        n_labels = self.n_labels()
        votes, cover, seen, stroke_w = self._votes(n_labels)
        n = self.model.num_gaussians
        seeds = np.full(n, -1, np.int64)
        source = np.zeros(n, np.uint8)
        p = self.params
        soft = p.cut_evidence == "soft"
        if self._views:
            if not soft:
                lifted = decide_labels(votes, self.lift)
                cut_seed = lifted.decided.numpy()
                seeds[cut_seed] = lifted.labels.numpy()[cut_seed]
                source[cut_seed] = 2
            best_w, best = stroke_w.max(1)
            stroked = (best_w >= self.params.stroke_weight).numpy()
            seeds[stroked] = best.numpy()[stroked]
            source[stroked] = 1
        evidence = None
        evident = np.zeros(n, bool)
        if soft and self._views:
            whole = cover if p.evidence_of == "decided" else seen
            evidence = (votes / (whole + self.lift.min_weight)[:, None]).double().numpy()
            evident = cover.numpy() >= self.lift.min_weight
        if p.solver == "geodesic":
            labels, distance = geodesic_labels(
                self.graph, seeds, n_labels, contrast_weight=p.contrast,
                evidence=None if evidence is None else evidence * evident[:, None], evidence_cost=p.evidence_cost,
                weak_evidence=p.weak_evidence, weak_reach=p.weak_reach)
            decided = np.isfinite(distance)
            probs = np.zeros((n, n_labels + 1))
            probs[np.flatnonzero(decided), labels[decided]] = 1.0
        else:
            priors = None if evidence is None else p.cut_weight * self.graph.degree[:, None] * evidence
            x0 = self._last.probs if self._last is not None and self._last.probs.shape == (n, n_labels + 1) else None
            probs = diffuse_labels(self.graph, seeds, n_labels, leak=p.leak, x0=x0, priors=priors)
            labels, decided = decide_diffused(probs, min_reach=p.min_reach, min_share=self.lift.min_share)
        labels[seeds >= 0], decided[seeds >= 0] = seeds[seeds >= 0], True
        source[(seeds < 0) & decided] = np.where(evident, 2, 3)[(seeds < 0) & decided]
        self._last = FieldResult(labels, decided, probs, source, n_labels, time.perf_counter() - t0)
        log.info("labels of %d Gaussians from %d painted view(s) in %.2f s: %s", n, len(self._views),
                 self._last.seconds, self._last.counts())
        return self._last


def correction_seeds(rendered: np.ndarray, strokes: np.ndarray, erode_px: int, reach_px: int) -> np.ndarray:
    """The seed map ``(H, W) int64`` (-1 none, 0..L) of a painted view's cut once labels exist in 3-D: the eroded
    cores of the labels rendered into the view (``rendered``, -1 where undecided; regions thinner than the erosion
    keep their middle), except, round each stroke, the rendered region of another label it touches within
    ``reach_px`` of it (the stroke corrects that region; the cut decides it), and the strokes (``strokes``, -1 none)
    on top."""
    from abcgs.masks.refine import eroded_cores

    claimed = rendered.copy()
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach_px + 1, 2 * reach_px + 1))
    for k in np.unique(strokes[strokes >= 0]):
        near = cv2.dilate((strokes == k).astype(np.uint8), disc).astype(bool)
        for other in np.unique(rendered[(strokes == k) & (rendered >= 0) & (rendered != k)]):
            _, comp = cv2.connectedComponents((rendered == other).astype(np.uint8), connectivity=8)
            hit = np.unique(comp[(strokes == k) & (rendered == other)])
            claimed[np.isin(comp, hit[hit > 0]) & near] = -1
    seeds = np.full(rendered.shape, -1, np.int64)
    for v in np.unique(claimed[claimed >= 0]):
        seeds[eroded_cores(claimed == v, erode_px, keep_small=True)] = v
    return np.where(strokes >= 0, strokes, seeds)


def cut_painted_view(field: LabelField, result: FieldResult | None, index: int, photo: np.ndarray, strokes: np.ndarray,
                     *, erode: float = 0.04, reach: float = 0.1, iterations: int = 5,
                     min_margin: float = 0.0) -> np.ndarray:
    """The page's cut of view ``index`` (``(H, W) int64``, 0..L, :data:`NO_VOTE` undecided) on its ``photo``
    ``(H, W, 3)``: from its ``strokes`` seed map alone while no label exists in 3-D (``result`` None), else from
    :func:`correction_seeds` of the labels ``result`` renders into it (erosion: ``erode``, a stroke's reach:
    ``reach``, both × the view's shorter side), on colour and rendered depth. A pixel where GrabCut's colour models
    differ by less than ``min_margin`` (:attr:`abcgs.masks.grabcut.Segmentation.margin`) is left undecided: the cut
    is not sure of it, and the page saves it so, for the ``masks`` stage to read the same evidence."""
    from abcgs.masks.grabcut import segment
    from abcgs.masks.lifting import LiftResult
    from abcgs.masks.refine import render_seeds

    cam = field.cameras[index]
    depth = None
    seeds = strokes
    if result is not None and result.decided.any():
        lifted = LiftResult(torch.as_tensor(result.labels), torch.empty(0), torch.as_tensor(result.decided))
        _, rendered, depth = render_seeds(field.model, lifted, result.n_labels, cam, 0, backend=field.backend)
        short = min(cam.height, cam.width)
        seeds = correction_seeds(rendered, strokes, int(round(erode * short)), int(round(reach * short)))
    seg = segment(photo, seeds, iterations=iterations, depth=depth)
    return np.where(seg.claimed & (seg.margin >= min_margin), seg.labels, NO_VOTE).astype(np.int64)


def refine_labels(weights: np.ndarray, alpha: np.ndarray, photo: np.ndarray, params: FieldParams) -> np.ndarray:
    """A view's labels ``(H, W) int64`` from its rendered label weights ``(H, W, L + 2)`` and alpha ``(H, W, 1)``
    (:func:`~abcgs.masks.lifting.render_label_weights`), refined against its ``photo`` ``(H, W, 3) uint8`` as
    ``params`` say (``edge_filter``, ``edge_radius``, ``edge_colour``, ``edge_eps``:
    :func:`abcgs.masks.edges.refine_to_photo`) and rid of regions under ``min_region`` of the view
    (:func:`abcgs.masks.edges.drop_specks`)."""
    from abcgs.masks.edges import drop_specks, refine_to_photo

    out = refine_to_photo(weights, alpha, photo, method=params.edge_filter, radius=params.edge_radius,
                          colour=params.edge_colour, eps=params.edge_eps)
    return drop_specks(out, int(params.min_region * out.size))


def render_field(field: LabelField, result: FieldResult, index: int, *, threshold: float = 0.0,
                 cut_where_painted: bool = True, photo: np.ndarray | None = None) -> np.ndarray:
    """The labels of view ``index`` ``(H, W) int64``: rendered from ``result`` (a pixel takes the label of largest
    blending weight, if it holds at least ``threshold`` of its alpha; 0 where none does, where nothing is rendered,
    and where undecided Gaussians win); with the view's ``photo`` ``(H, W, 3) uint8`` and ``edge_radius`` > 0,
    refined against the photo instead (:func:`refine_labels`: borders on the photo's edges, undecided pixels given
    the label around them, specks dropped); a view larger than :data:`~abcgs.masks.lifting.LIFT_PIXELS` is rendered
    and refined at that size and its labels brought to its own along the photo's edges
    (:func:`~abcgs.masks.edges.upsample_labels`); and, on a painted view with ``cut_where_painted``, its cut
    wherever the cut decided (a painted view keeps what the user saw and accepted on the page), which the refinement
    also starts from there (:func:`with_cut`)."""
    from abcgs.masks.edges import upsample_labels
    from abcgs.masks.lifting import pick_labels, render_label_weights

    cam = field.cameras[index]
    small = lift_camera(cam)
    img, alpha = render_label_weights(field.model, torch.as_tensor(result.labels), result.n_labels, small,
                                      decided=torch.as_tensor(result.decided), backend=field.backend)
    cut = field.evidence_map(index) if cut_where_painted else None
    if photo is not None and field.params.edge_radius > 0:
        photo_small = photo if small is cam else cv2.resize(photo, (small.width, small.height),
                                                            interpolation=cv2.INTER_AREA)
        weights = img.numpy() if cut is None else with_cut(img.numpy(), resized_labels(cut, (small.height, small.width)))
        out = refine_labels(weights, alpha.numpy(), photo_small, field.params)
        if small is not cam:
            out = upsample_labels(out, np.ones(out.shape, bool), photo)[0]
    else:
        out = pick_labels(img, alpha, threshold, undecided=0).numpy().astype(np.int64)
        if small is not cam:
            out = resized_labels(out, (cam.height, cam.width))
    return out if cut is None else np.where(cut >= 0, cut, out)


def with_cut(weights: np.ndarray, cut: np.ndarray) -> np.ndarray:
    """A painted view's rendered label weights ``(H, W, L + 2)`` with its ``cut`` ``(H, W)`` (0..L, NO_VOTE) put in
    where the cut decided: there the cut's label has the full weight 1 and every other channel 0, so that the
    refinement (:func:`refine_labels`) carries what the user painted along the photo over the part it lies in, as
    far as the part's colour goes, instead of the few pixels the cut covers."""
    out = np.array(weights, np.float32, copy=True)
    ys, xs = np.nonzero((cut >= 0) & (cut < out.shape[-1] - 1))
    out[ys, xs] = 0.0
    out[ys, xs, cut[ys, xs]] = 1.0
    return out
