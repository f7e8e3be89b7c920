"""The ``masks`` section's schema: content masks (:mod:`abcgs.masks.content`) and their lifting (:mod:`abcgs.masks.lifting`).

Schema modules import nothing heavier than pydantic, so that reading ``params.yaml`` does not load the code
it configures (each stage's code dependencies stay its own: ``abcgs/dag.py``).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from abcgs.types import Backend

EdgeFilter = Literal["domain", "guided"]
"""How a view's rendered labels are refined against its photo (:mod:`abcgs.masks.edges`)."""

UNDECIDED = 255
"""Value, in a saved label PNG, of a pixel the cut left undecided (no cut, stroke or gap fill claimed it). Lifted, it
votes for nothing (:data:`abcgs.masks.lifting.NO_VOTE`): a gap the cut could not decide is not the user's "no label",
which only the background brush (value 0) says. Labels of a numbered PNG are therefore 1..254. Defined here, with
the section's schema, so that the preflight checks read it without loading the masks code."""


class LiftParams(BaseModel):
    """Thresholds of the label vote (``params.yaml``: ``masks.lift``)."""

    model_config = ConfigDict(extra="forbid")

    min_weight: float = Field(0.05, ge=0.0, description="least summed blending weight of the winning label")
    min_share: float = Field(0.5, gt=0.0, le=1.0, description="least share of the Gaussian's total weight")
    render_threshold: float = Field(
        0.5, ge=0.0, le=1.0, description="re-rendered masks: a pixel takes a label when the label's alpha share ≥ this"
    )
    propagate: Literal["auto", "always", "never"] = Field(
        "auto", description="Gaussians no masked view sees (the far side of an object lifted from one view) take the "
        "majority label of their nearest labelled Gaussians in 3-D; auto: for object-centred (orbit) captures with "
        "views that have no mask (on a forward-facing scene it guesses occluded surfaces wrong; the measurements: "
        "docs/MASKS.md, 'Object-centred captures')")
    propagate_k: int = Field(8, ge=1, description="neighbours in the propagation vote")
    propagate_along: Literal["position", "surface"] = Field(
        "position", description="position: the majority of the k nearest labelled Gaussians (world distance); "
        "surface: rounds of opacity-weighted k-NN votes from the decided Gaussians over centres scaled by the scene's "
        "extent and base colour, so that a label follows the surface it was painted on (abcgs/masks/spread.py)")
    propagate_colour_weight: float = Field(
        1.0, ge=0.0, description="propagate_along: surface: weight of the base colour (RGB 0..1) against the centres "
        "(scene extent = 1) in the neighbour graph; 0: position only")
    propagate_split: bool = Field(
        False, description="after the cross-view refinement, also give the Gaussians whose vote stayed split between "
        "labels (undecided; not a vote for 0) their 3-D neighbours' label, where propagation runs: on a 360° capture "
        "labelled from one view they are the seams left unlabelled between regions (docs/MASKS.md, bonsai)")


class FieldParams(BaseModel):
    """``masks.field``: the labels of the Gaussians from the painted views, as the page shows them and the stage
    writes them (:mod:`abcgs.masks.field`): strokes as hard constraints, the lifted cuts, and the 3-D step over the
    Gaussians' nearest neighbours (:mod:`abcgs.masks.graph`)."""

    model_config = ConfigDict(extra="forbid")

    k: int = Field(10, ge=1, le=64, description="neighbours per Gaussian in the graph")
    colour_sigma: float = Field(
        0.15, gt=0.0, description="σ of the colour affinity of an edge, base colours in RGB 0..1: the smaller, the "
        "harder a label crosses a change of colour")
    normal_weight: float = Field(
        1.0, ge=0.0, description="weight of the normal affinity exp(-w (1 - |n_i·n_j|)) of an edge (0: normals "
        "ignored)")
    solver: Literal["walk", "geodesic"] = Field(
        "geodesic", description="the 3-D step (abcgs.masks.graph): walk: Grady's random walker with the cuts' evidence as "
        "priors; geodesic: each Gaussian takes the label of the nearest stroke or cut evidence along the graph, so "
        "a correction changes what lies nearest to it and nothing else (docs/MASKS.md, miku's scripted user)")
    contrast: float = Field(
        4.0, ge=0.0, le=1000.0, description="solver: geodesic: what crossing a change of colour or facing costs, "
        "in hops of the graph per unit of -log(colour-normal affinity)")
    evidence_cost: float = Field(
        4.0, ge=0.0, le=1000.0, description="solver: geodesic: a Gaussian with cut evidence e for a label starts "
        "that label at distance evidence_cost × (1 - e), in hops: the larger, the more a stroke nearby overrides "
        "what the cuts say")
    weak_evidence: float = Field(
        0.25, ge=0.0, le=1.0, description="solver: geodesic: cut evidence under this share is weak: its label claims "
        "only what lies within weak_reach of it along the graph (0: none is weak; docs/MASKS.md, miku's scripted user)")
    weak_reach: float = Field(
        6.0, gt=0.0, le=1e6, description="solver: geodesic: how far a weak source's label reaches along the graph, in "
        "hops, its starting distance evidence_cost × (1 - e) included")
    evidence_of: Literal["decided", "view"] = Field(
        "view", description="cut_evidence: soft: a Gaussian's evidence for a label is its vote for the label over "
        "its blending weight in the pixels its views' cuts decided (decided), or in the whole of those views "
        "(view): a large splat that a correction's dot covers in part is then weak evidence, not a near-seed")
    occlusion: float = Field(
        0.2, ge=0.0, le=10.0, description="a Gaussian whose centre lies behind a painted view's surface by more than "
        "this share of the surface's depth takes no vote from that view's cut; its strokes still bind it, as hard "
        "constraints (abcgs.masks.lifting.occluded_gaussians; 0: every Gaussian takes the cut's vote with its "
        "blending weight; docs/MASKS.md, miku's scripted user)")
    cut_share: float = Field(
        0.5, ge=0.0, le=1.0, description="least share of a Gaussian's blending weight in a painted view that must "
        "lie on pixels the view's cut decided for that view to vote on it: a splat that a correction's region covers "
        "in part keeps what the other views say of it (0: every Gaussian the cut touches gets its vote)")
    leak: float = Field(
        1e-5, gt=0.0, le=1.0, description="share of a random walk lost at each step: a part no painted label "
        "reaches ends undecided, not split")
    min_reach: float = Field(
        0.05, ge=0.0, le=1.0, description="least probability of the winning label for the 3-D step to decide a "
        "Gaussian; below it stays undecided")
    stroke_weight: float = Field(
        0.1, gt=0.0, description="least blending weight (summed over a view's stroke pixels) for a Gaussian to take "
        "the stroke's label as a hard constraint")
    stroke_share: float = Field(
        0.5, ge=0.0, le=1.0, description="least share of a Gaussian's blending weight in a view that must lie under "
        "that view's strokes for them to bind it (0: any Gaussian that reaches stroke_weight); a large splat a stroke "
        "crosses is left to the cuts' evidence (docs/MASKS.md, miku's scripted user)")
    correction: Literal["strokes", "region", "cut"] = Field(
        "region", description="a Segment on a view once labels exist in 3-D: strokes: its strokes alone correct the "
        "labels (bound where they cover a Gaussian, evidence where they touch it); region: each stroke's region in "
        "the photo (its colour, within correction_reach, abcgs.masks.regions) is its evidence besides; cut: the view "
        "is cut again by GrabCut, seeded by its strokes and the labels in 3-D, and the cut is its evidence "
        "(docs/MASKS.md, miku's scripted user)")
    correction_reach: float = Field(
        0.1, gt=0.0, le=10.0, description="correction: cut: on a view the 3-D labels already reach, a stroke frees the "
        "rendered region of another label it touches within this share of the view's shorter side, for the cut to "
        "decide; correction: region: how far a stroke's region reaches (the same share)")
    region_tolerance: float = Field(
        12.0, gt=0.0, le=200.0, description="correction: region: the largest CIELAB distance (ΔE*ab) from a stroke's "
        "mean colour that its region takes in")
    click_reach: float = Field(
        0.2, gt=0.0, le=10.0, description="correction: region: how far the region of a click (a mark about as long as "
        "it is wide: a dot, which stands for the part it lies in) reaches, a share of the view's shorter side; a "
        "longer stroke's region reaches correction_reach (docs/MASKS.md, miku's scripted user)")
    click_tolerance: float = Field(
        12.0, gt=0.0, le=200.0, description="correction: region: the largest CIELAB distance (ΔE*ab) from a click's "
        "mean colour that its region takes in (16 floods a pale part's neighbours: docs/MASKS.md)")
    region_depth_step: float = Field(
        0.04, ge=0.0, le=1.0, description="correction: region: a stroke's region stops where the view's inverse depth, "
        "rendered from the Gaussians, steps between neighbouring pixels by more than this share (an object's outline "
        "against what lies behind it), so that a click on a pale part does not flood the wall or the bed of its "
        "colour; 0: its colour alone bounds it (docs/MASKS.md, miku's scripted user)")
    region_weight: float = Field(
        0.2, ge=0.0, le=1.0, description="correction: region: how much a stroke's region beyond the stroke's own "
        "pixels weighs as evidence, against a cut's pixel as near the view's strokes (1: as much); a colour region is "
        "less sure than a cut, so where the two disagree on a Gaussian the cut's evidence stays (docs/MASKS.md, "
        "miku's scripted user)")
    edge_filter: EdgeFilter = Field(
        "domain", description="how each view's labels rendered from the Gaussians are refined against its photo "
        "(abcgs.masks.edges): domain: the domain transform's normalized convolution, a label spreads along the photo "
        "over edge_radius and stops at changes of colour of several edge_colour; guided: a guided filter of radius "
        "edge_radius and regularisation edge_eps")
    edge_radius: float = Field(
        0.25, ge=0.0, le=1.0, description="how far a label spreads along the photo when refined, a share of the "
        "view's shorter side (domain: the spatial sigma; guided: the radius, e.g. 0.01; 0: not refined)")
    edge_colour: float = Field(
        80.0, gt=0.0, le=3000.0, description="edge_filter: domain: the colour sigma, in 8-bit levels: a step of "
        "colour whose RGB differences sum to this counts as edge_radius of distance")
    min_region: float = Field(
        0.003, ge=0.0, le=0.1, description="with edge_radius > 0: a region of one label in a view's refined labels "
        "smaller than this share of the view's pixels takes the label around it (abcgs.masks.edges.drop_specks; "
        "0: kept)")
    edge_eps: float = Field(
        1e-2, gt=0.0, le=1.0, description="edge_filter: guided: the filter's regularisation (photo in 0..1): an edge "
        "of contrast above about its square root holds a label's border")
    cut_evidence: Literal["soft", "hard"] = Field(
        "soft", description="soft: each painted view's cut is evidence weighted by how sure it is (near its own "
        "strokes, GrabCut's margin), a prior of the 3-D step that no cut can make override a stroke; hard: a "
        "Gaussian whose summed vote is clear (masks.lift) is a seed of its label, so a correction's cut outvotes "
        "what other views decided (docs/MASKS.md, miku's scripted user)")
    cut_weight: float = Field(
        1.0, gt=0.0, le=1e6, description="cut_evidence: soft: strength of a Gaussian's cut evidence against its "
        "neighbours in the 3-D step (× its degree in the graph)")
    cut_reach: float = Field(
        0.15, gt=0.0, le=10.0, description="cut_evidence: soft: a cut pixel's confidence falls as exp(-(d/r)²) with "
        "its distance d to the nearest stroke of its view, r this share of the view's shorter side")
    cut_margin: float = Field(
        0.25, ge=0.0, le=1.0, description="a pixel of the page's cut where GrabCut's two colour models differ by less "
        "than this (|2p - 1| of its foreground probability p) is left undecided: it votes for "
        "nothing and is saved so")


class RefineParams(BaseModel):
    """``masks.refine``: cross-view refinement (:mod:`abcgs.masks.refine`): each view without a given mask is cut
    again by GrabCut on its colours and rendered depth, seeded by the lifted labels, and the labels lifted from all."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(
        False, description="re-cut the views that have no mask and lift from all of them (97 views of miku: half an "
        "hour on 2 cores; it measures better on the tiny scene, which turns it on: docs/MASKS.md, python -m "
        "eval.bench.paint_iou); false: the labels of the masks page (masks.field: the given or automatic masks and "
        "their strokes lifted, the rest decided in 3-D), in seconds")
    seed_erode: float = Field(
        0.04, ge=0.0, le=0.25, description="each rendered label region is eroded by this share of the view's shorter "
                                           "side; its core seeds the cut, the rest is the cut's to decide")
    small_regions: Literal["drop", "core"] = Field(
        "drop", description="a rendered label region thinner than twice seed_erode: drop: eroded away, the cut "
        "decides it; core: it keeps its middle as a seed (each region is eroded by at most half its thickness), so a "
        "small part (a face, a hood's rim seen from afar) is not lost in a view (docs/MASKS.md, miku)")
    depth_weight: float = Field(
        1.0, ge=0.0, description="weight of the rendered inverse depth against colour in the cut (0: colour only)")
    iterations: int = Field(5, ge=1, le=50, description="GrabCut iterations per label")
    order: Literal["together", "nearest_first"] = Field(
        "together", description="together: every view is cut from the first lift (the given masks'); nearest_first: "
        "the views are cut one after another, nearest in viewing direction to a given view first, each seeded by the "
        "labels lifted from the given masks and the cuts before it (and propagated, where propagation runs), so "
        "labels travel round an object from view to view (docs/MASKS.md, miku)")
    output: Literal["render", "recut"] = Field(
        "render", description="the label map written for each view without a given mask: render: the final labels "
        "rendered from the Gaussians; recut: that view cut once more on its photo and rendered depth, seeded by the "
        "final labels' eroded cores, the render where the cut decides nothing (its edges follow the photo rather "
        "than the fitted geometry; docs/MASKS.md, miku)")


class GrabCutParams(BaseModel):
    """``masks.grabcut``: the object mask of the reference view by GrabCut."""

    model_config = ConfigDict(extra="forbid")

    box: tuple[float, float, float, float] = Field(
        (0.2, 0.15, 0.8, 0.85), description="x0, y0, x1, y1 as fractions of the view: outside is background")
    depth_seed: bool = Field(
        True, description="split the box's depths at Otsu's threshold: nearer = probable object (its eroded core "
                          "certain), farther = probable background; false: colour only")
    iterations: int = Field(5, ge=1, le=50)
    reference_view: int = Field(0, ge=0, description="index of the view that is segmented")

    @model_validator(mode="after")
    def _box_inside(self):
        x0, y0, x1, y1 = self.box
        if not (0.0 <= x0 < x1 <= 1.0 and 0.0 <= y0 < y1 <= 1.0):
            raise ValueError(f"masks.grabcut.box must be 0 <= x0 < x1 <= 1 and 0 <= y0 < y1 <= 1, got {self.box}")
        return self


class AutoMaskParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    n_labels: int = Field(3, ge=1, le=16, description="k-means clusters = content labels")
    depth_weight: float = Field(2.0, ge=0, description="weight of normalised depth against Lab colour")
    reference_view: int = Field(0, ge=0, description="index of the view that is clustered")
    seed: int = 0


class MaskParams(BaseModel):
    """``params.yaml``: ``masks``."""

    model_config = ConfigDict(extra="forbid")

    source: Literal["auto", "given", "clustering", "grabcut"] = Field(
        "auto", description="given: the scene's masks/ (error if none); clustering: k-means of colour + depth; "
                            "grabcut: object vs rest by GrabCut; auto: given if present, else clustering"
    )
    lift: LiftParams = Field(default_factory=LiftParams)
    field: FieldParams = Field(default_factory=FieldParams)
    refine: RefineParams = Field(default_factory=RefineParams)
    clustering: AutoMaskParams = Field(default_factory=AutoMaskParams)
    grabcut: GrabCutParams = Field(default_factory=GrabCutParams)
    holdout_every: int = Field(
        0, ge=0, description="given masks: every k-th (k ≥ 2) is left out of the lifting and only scored (per-label "
                             "IoU on held-out views); 0 lifts from all of them")
    lift_views: list[str] = Field(
        default_factory=list, description="given masks: lift from these views only (image stems, e.g. ['000']); the "
                                          "other given masks are held out and scored. Empty: see holdout_every")
    warn_unlabelled: float = Field(
        0.1, ge=0.0, le=1.0, description="a view whose re-rendered label map leaves more than this share of its "
                                         "pixels unlabelled (0) is named in a warning (log, masks.json, report)")
    backend: Backend = "auto"
