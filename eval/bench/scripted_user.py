"""The scripted user of the interactive-segmentation benchmarks (NoC@IoU, as GaussianCut, SAGA and SA3D count it) on a
capture round an object, with the labels the masks page shows (:mod:`abcgs.masks.field`).

    python -m eval run scripted_user --scene miku --work /work/bench/miku \\
        --json docs/measurements/miku_scripted_user.json --figure docs/img/masks/miku_scripted_user.jpg

``--scene S`` reads ``eval/data/S/strokes.json`` and ``reference/`` as :mod:`eval.bench.strokes` does (the fitted
scene under ``--work``). The user starts from the test strokes on one view (``test``) and the page's cut of them
(:func:`abcgs.masks.field.cut_painted_view`). After each Segment every view's labels are rendered from the Gaussians
(:meth:`abcgs.masks.field.LabelField.solve`). Each next stroke goes on the reference view that is worst now (lowest
mean IoU over its labels): a dot of the reference label at the interior-most pixel (largest distance to the region's
edge) of the largest connected region whose label is wrong; that view is then cut again as the page cuts it (its
strokes, and the labels rendered into it as seeds) and the field solved. Every reference view is scored, the stroked
front view included: IoU per label against the reference (its undecided pixels not scored) and the share of pixels
left unlabelled. The labels scored are the stage's: refined against each view's photo
(:func:`abcgs.masks.edges.refine_to_photo`), a painted view's cut where it decided; beside them, the labels rendered
from the Gaussians alone. Printed per stroke: the worst and mean IoU over all (view, label) pairs, the worst view's
share of unlabelled pixels, and the seconds from Segment to every view's labels (cut, solve, the strip of all views the
page shows, :class:`abcgs.masks.page.strip.Strip`, and the painted view's labels). Beside them, the bounds the fitted
geometry sets (:func:`eval.bench.strokes.geometry_bound`: all reference maps lifted together and rendered back, as
they are and refined the same way); the goal's pairs are held against the refined one. At the end, the ``masks``
stage's labels from what the page saved (:func:`stage_maps`), scored the same way.

With ``--target pair`` each next mark goes to the largest wrong region of the (view, label) pair furthest below its
goal instead, until every pair meets it; with ``--target gain`` to the wrong region that costs its pair the most IoU,
on whichever reference view it lies, the painted ones included (:data:`eval.bench.marks.Target`).

With ``--clicks stroke`` each next mark is a straight brush stroke across that wrong region instead of a dot
(:func:`~eval.bench.marks.line_inside`, at most :data:`~eval.bench.marks.STROKE_LENGTH` of the view's shorter side), as a user paints on the page. With
``--clicks ideal`` each dot also brings the whole wrong region it lies in, with its reference label, as the view's
evidence (:data:`~eval.bench.marks.Clicks`): what a perfect part mask per click would give the 3-D step.

Every stroke is also a regression check: the change of the mean IoU and of each reference view's mean from the Segment
before, and how many Gaussians that Segment changed, by the step that decided each (``delta``); the worst drop of either
mean over the run (``regression``), which the figure's title shows.

The goal (``GOAL``): mean IoU ≥ 0.75, every pair ≥ min(0.60, bound − 0.05) and ≤ 2 % unlabelled pixels on every
reference view, within 10 strokes after the test strokes; no stroke lowers the mean by more than 0.01 or a reference
view's mean by more than 0.03. ``verdict`` in the record says which of these the run met.
"""

from __future__ import annotations

import json
import logging
import statistics
import tempfile
import time
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs.io.images import load_image, save_image, to_uint8
from abcgs.masks.field import SOURCES, FieldResult, LabelField, render_field
from abcgs.masks.lifting import NO_VOTE, blend_votes, lift_labels, occluded_gaussians, one_hot_labels
from abcgs.masks.page.field_session import FieldSession
from abcgs.masks.page.strip import Strip
from abcgs.masks.params import FieldParams, LiftParams
from abcgs.masks.strokes import Stroke, rasterize_strokes
from eval.bench.marks import GOAL, STROKE_LENGTH, Clicks, Target, dot_inside, line_inside, next_region, pair_goal
from eval.bench.strokes import DATA, FittedCase, geometry_bound, load_case, view_strokes
from eval.labels import score_labels, stroke_overlay
from eval.record import bench_parser, write_record


def regression(steps: list[dict], bound: dict | None = None) -> dict:
    """The worst drop over a run: of the mean IoU from one Segment to the next, and of any reference view's mean
    (positive numbers are drops; each with the number of strokes after which it happened, for a view which, and the
    Gaussians that Segment changed by the step that decided them, ``delta.changed``, where the steps hold it). The
    view's drop names the pairs that fell in it by more than 0.01 (``fell``: label → IoU before and after, and with
    ``bound`` (:func:`~eval.bench.strokes.geometry_bound`) the pair's bound: a pair above its bound was right by a
    mislabel that the Gaussians' labels, once right in the other views, cannot keep)."""
    mean = {"drop": 0.0, "strokes": None, "changed": None}
    view = {"drop": 0.0, "strokes": None, "view": None, "changed": None, "fell": {}}
    for prev, cur in zip(steps, steps[1:]):
        changed = cur.get("delta", {}).get("changed")
        if prev["mean_iou"] - cur["mean_iou"] > mean["drop"]:
            mean = {"drop": prev["mean_iou"] - cur["mean_iou"], "strokes": cur["strokes"], "changed": changed}
        for v, m in cur["view_mean"].items():
            if prev["view_mean"][v] - m > view["drop"]:
                fell = {k: {"before": prev["iou"][v][k], "after": iou} for k, iou in cur["iou"][v].items()
                        if prev["iou"][v].get(k, iou) - iou > 0.01}
                if bound is not None:
                    for k, f in fell.items():
                        f["bound"] = bound["per_view"][v][k]
                view = {"drop": prev["view_mean"][v] - m, "strokes": cur["strokes"], "view": v, "changed": changed,
                        "fell": fell}
    return {"mean": mean, "view": view}


def verdict(steps: list[dict], bound: dict) -> dict:
    """Which parts of ``GOAL`` the run met: the mean, every pair against its bound, the unlabelled share (all at the
    last step) and the drops (over the run)."""
    last = steps[-1]
    low = {f"{v}/{k}": iou for v, d in last["iou"].items() for k, iou in d.items() if iou < pair_goal(bound, v, k)}
    drops = regression(steps)
    return {"mean_iou": last["mean_iou"] >= GOAL["mean_iou"], "pairs_below": low,
            "pairs": not low, "unlabelled": max(last["unlabelled"].values()) <= GOAL["unlabelled"],
            "mean_drop": drops["mean"]["drop"] <= GOAL["mean_drop"], "view_drop": drops["view"]["drop"] <= GOAL["view_drop"]}


class ScriptedUser:
    """The page's state for one run (:class:`abcgs.masks.page.field_session.FieldSession`, one page item per camera) and
    each painted view's strokes."""

    def __init__(self, model, scene, refs: dict[str, np.ndarray], by_stem: dict[str, int], params: FieldParams,
                 strip: Strip | None = None, clicks: Clicks = "dot"):
        self.scene, self.refs, self.by_stem, self.clicks = scene, refs, by_stem, clicks
        self.strokes: dict[int, list[Stroke]] = {}
        self.ideal: dict[int, np.ndarray] = {}  # clicks: ideal: each view's clicked wrong regions, -1 elsewhere
        photos = [to_uint8(load_image(p)) for p in scene.image_paths]
        self.photos = {s: photos[by_stem[s]] for s in refs}
        strip = strip if strip is not None else Strip.record(model, scene.cameras, photos)
        self.session = FieldSession(LabelField(model, scene.cameras, params), strip,
                                    {i: i for i in range(len(scene.cameras))})
        print(f"strip of {len(strip.views)} views recorded in {strip.seconds:.1f} s, neighbour graph built in "
              f"{self.session.graph_seconds:.1f} s", flush=True)

    def segment(self, index: int) -> dict:
        """What the page does on Segment for view ``index`` (:meth:`FieldSession.segment`); the seconds, split. With
        ideal clicks, the view's clicked regions over its cut (not the marks' colour regions) then become its evidence
        (:meth:`FieldSession.set_evidence`, not timed: no page does it)."""
        cam = self.scene.cameras[index]
        t0 = time.perf_counter()
        seeds = rasterize_strokes(self.strokes[index], (cam.height, cam.width))
        photo = to_uint8(load_image(self.scene.image_paths[index]))
        self.session.segment(index, photo, seeds, started=t0)
        state = self.session.state
        seconds = {**state.phases, "total": state.seconds}  # the page's Segment
        if index in self.ideal:  # the clicked regions instead of the marks' colour regions, over the view's cut
            cut = self.session.field.cut_of(index)
            cut = np.full(seeds.shape, NO_VOTE, np.int64) if cut is None else cut
            self.session.set_evidence(index, np.where(self.ideal[index] >= 0, self.ideal[index], cut), seeds)
        return seconds

    def maps(self, rendered: bool = False) -> dict[str, np.ndarray]:
        """Each reference view's labels as the stage writes them (refined against the view's photo, a painted view's
        cut where it decided), or, with ``rendered``, as rendered from the Gaussians alone."""
        f, r = self.session.field, self.session.result
        return {s: render_field(f, r, self.by_stem[s], cut_where_painted=not rendered,
                                photo=None if rendered else self.photos[s]) for s in self.refs}


def attribute(user: ScriptedUser, n_labels: int, test_stem: str) -> dict:
    """Where the Gaussians-alone labels of the reference views go wrong at the end of a run, and why.

    ``wrong_pixels``: of the wrong pixels (label ≠ reference, where the reference decided) of every reference view, the
    share rendered mostly from Gaussians of each :data:`SOURCES` step (each source rendered as a label).
    ``wrong_gaussians``: the Gaussians with a blending weight of at least 0.05 in the references other than the test
    view, and at least half of it on wrong pixels (``right``: under a tenth). For those the cuts decided: ``test_ref``,
    the share whose label is the one the test view's reference alone gives them (lifted, Eq. 2); ``test_ref_is_all``,
    the share where that label is the one all references lifted together give them. A low ``test_ref_is_all`` says the
    views' references disagree on those Gaussians: the test view sees them as one part, the others as another. Beside
    them, how the test view saw each group: the median blending weight there, the median share of it on the cut's
    label, and the share hidden behind its surface (:func:`abcgs.masks.lifting.occluded_gaussians`, tolerance 0.3)."""
    f, r = user.session.field, user.session.result
    model, cams = f.model, f.cameras
    as_labels = FieldResult(r.source.astype(np.int64), np.ones_like(r.decided), r.probs, r.source, len(SOURCES) - 1, 0)
    wrong_by = np.zeros(len(SOURCES))
    on_wrong, on_valid = torch.zeros(model.num_gaussians), torch.zeros(model.num_gaussians)
    for s, ref in user.refs.items():
        i = user.by_stem[s]
        valid = ref >= 0
        wrong = (render_field(f, r, i, cut_where_painted=False) != ref) & valid
        np.add.at(wrong_by, render_field(f, as_labels, i, cut_where_painted=False)[wrong], 1)
        if s != test_stem:
            w = blend_votes(model, cams[i], torch.from_numpy(np.stack([wrong, valid], -1).astype(np.float32)))
            on_wrong, on_valid = on_wrong + w[:, 0], on_valid + w[:, 1]
    share = (on_wrong / on_valid.clamp_min(1e-12)).numpy()
    seen = on_valid.numpy() >= 0.05
    groups = {"wrong": seen & (share >= 0.5), "right": seen & (share < 0.1)}
    test = lift_labels(model, [cams[user.by_stem[test_stem]]], [user.refs[test_stem]], n_labels, LiftParams())
    every = lift_labels(model, [cams[user.by_stem[s]] for s in user.refs], list(user.refs.values()), n_labels, LiftParams())
    t_lab, t_dec, a_lab = test.labels.numpy(), test.decided.numpy(), every.labels.numpy()
    front = cams[user.by_stem[test_stem]]
    cut = f.evidence_map(user.by_stem[test_stem])
    w = blend_votes(model, front, torch.cat([one_hot_labels(cut, int(cut.max(initial=0))),
                                             torch.ones(*cut.shape, 1)], -1))
    weight = w[:, -1].numpy()  # each Gaussian's blending weight in the test view
    evidence = (w[:, :-1].max(1).values / w[:, -1].clamp_min(1e-12)).numpy()  # its cut's largest label share there
    hidden = occluded_gaussians(model, front, 0.3).numpy()
    out = {"wrong_pixels": dict(zip(SOURCES, (wrong_by / max(1.0, wrong_by.sum())).round(4).tolist())),
           "wrong_gaussians": {}}
    for name, m in groups.items():
        m = m & (r.source == SOURCES.index("lifted"))
        stats = {"test_ref": t_dec & (t_lab == r.labels), "test_ref_is_all": t_dec & (t_lab == a_lab),
                 "test_view_weight": weight, "test_cut_share": evidence, "hidden_in_test_view": hidden}
        out["wrong_gaussians"][name] = {"lifted": int(m.sum()), **{  # shares are means, the rest medians; nan if none
            k: float("nan") if not m.any() else float(np.median(v[m]) if v.dtype != bool else v[m].mean())
            for k, v in stats.items()}}
    return out


def stage_maps(user: ScriptedUser, params: FieldParams) -> dict[str, np.ndarray]:
    """Each reference view's labels as the ``masks`` stage computes them from what the page saved at the end: every
    painted view's label PNG (its cut, undecided where the field took none) and strokes written to a folder, then
    :func:`abcgs.masks.content.make_content_masks` on it, as ``stages/masks.py`` runs it."""
    from abcgs.io.images import save_labels, save_stroke_map, stroke_map_path
    from abcgs.masks.content import label_paths_in, make_content_masks
    from abcgs.masks.params import UNDECIDED, MaskParams

    with tempfile.TemporaryDirectory(prefix="abcgs-scripted-user-") as tmp:
        masks = Path(tmp)
        for i in user.session.field.painted:
            stem = Path(user.scene.cameras[i].name).stem
            saved = user.session.field.saved_of(i)
            save_labels(masks / f"{stem}.png", np.where(saved >= 0, saved, UNDECIDED))
            cam = user.scene.cameras[i]
            save_stroke_map(stroke_map_path(masks, stem), rasterize_strokes(user.strokes[i], (cam.height, cam.width)))
        result = make_content_masks(user.session.field.model, user.scene.cameras,
                                    label_paths_in(masks, user.scene.cameras),
                                    MaskParams(source="given", field=params), user.scene.image_paths,
                                    show_progress=False)
    return {s: result.view_labels[user.by_stem[s]] for s in user.refs}


def run(user: ScriptedUser, front: int, first: list[Stroke], n_labels: int, max_strokes: int, radius: float, *,
        target: Target = "view", bound: dict | None = None) -> list[dict]:
    """The test strokes, then up to ``max_strokes`` scripted ones, each where ``target`` says (:func:`next_region`;
    ``bound`` for ``pair``); a record per Segment."""
    user.strokes[front] = list(first)
    steps = []
    seconds, before = user.segment(front), None
    while True:
        maps = user.maps()
        s = score_labels(maps, user.refs, n_labels).as_record()
        step = {"strokes": sum(len(v) for v in user.strokes.values()), "seconds": seconds, **s,
                "rendered": score_labels(user.maps(rendered=True), user.refs, n_labels).as_record(),
                "counts": user.session.result.counts()}
        if steps:
            step["delta"] = {"mean": s["mean_iou"] - steps[-1]["mean_iou"],
                             "views": {v: m - steps[-1]["view_mean"][v] for v, m in s["view_mean"].items()},
                             "changed": user.session.result.changes_from(before)}
        steps.append(step)
        drop = "" if "delta" not in step else (f", Δ mean {step['delta']['mean']:+.3f}, worst Δ view "
                                               f"{min(step['delta']['views'].values()):+.3f} "
                                               f"({sum(step['delta']['changed'].values())} Gaussians changed)")
        print(f"{step['strokes']:3d} strokes: worst IoU {s['worst_iou']:.3f}, mean {s['mean_iou']:.3f} (Gaussians alone "
              f"{step['rendered']['mean_iou']:.3f}){drop}, "
              f"unlabelled ≤ {max(s['unlabelled'].values()):.1%}, Segment → every view {seconds['total']:.2f} s "
              f"(cut {seconds['cut']:.2f}, solve {seconds['solve']:.2f}, strip {seconds['strip']:.2f}, the view "
              f"{seconds['view']:.2f})", flush=True)
        if len(steps) > max_strokes:
            return steps
        picked = next_region(maps, user.refs, s["iou"], target, bound)
        if picked is None:
            return steps
        worst, (k, region) = picked
        idx = user.by_stem[worst]
        if user.clicks == "stroke":  # the region is the view's size: its shorter side is the view's
            stroke = line_inside(k, region, radius, STROKE_LENGTH * min(region.shape))
        else:
            stroke = dot_inside(k, region, radius)
        if user.clicks == "ideal":
            user.ideal.setdefault(idx, np.full(region.shape, -1, np.int64))[region] = k
        user.strokes.setdefault(idx, []).append(stroke)
        steps[-1]["next"] = {"view": worst, "label": stroke.label, "at": stroke.points[0].tolist()}
        before = user.session.result
        seconds = user.segment(idx)


def figure(user: ScriptedUser, steps: list[dict], path: Path) -> None:
    """Each reference view: its photo with the final labels (strokes black) and the reference; the title row gives
    the mean IoU from the first Segment to the last and the worst drop of the run (:func:`regression`)."""
    from abcgs.viz import image_grid

    maps = user.maps()
    rows = []
    for s, ref in user.refs.items():
        i = user.by_stem[s]
        img = load_image(user.scene.image_paths[i])
        rows.append([stroke_overlay(img, maps[s], user.strokes.get(i)), stroke_overlay(img, np.where(ref < 0, 0, ref))])
    drops = regression(steps)
    labels = (f"labels after {steps[-1]['strokes']} strokes (black): mean IoU {steps[0]['mean_iou']:.3f} -> "
              f"{steps[-1]['mean_iou']:.3f}")
    reference = f"reference; worst drop of the mean {drops['mean']['drop']:.3f}, of a view {drops['view']['drop']:.3f}"
    save_image(path, image_grid(rows, [labels, reference], height=user.scene.cameras[0].height))


def run_setting(case: FittedCase, params: FieldParams, max_strokes: int, radius: float,
                strip: Strip | None = None, clicks: Clicks = "dot", target: Target = "view") -> tuple[dict, ScriptedUser]:
    """One scripted run on ``case`` at ``params``: the bounds, the steps, the ``masks`` stage's score; its record
    (without provenance) and the user, for the figure. ``strip``: a recorded strip to reuse (the Gaussians are the
    same); ``target``: where the marks go (:data:`~eval.bench.marks.Target`, against the refined bound)."""
    spec, scene, model, by_stem, refs = case.spec, case.scene, case.model, case.by_stem, case.refs
    n_labels = len(spec["labels"])
    front_stem, items = spec["test"]["view"], spec["test"]["strokes"]
    front = by_stem[front_stem]
    bound = geometry_bound(model, scene.cameras, by_stem, refs, list(refs), n_labels)
    user = ScriptedUser(model, scene, refs, by_stem, params, strip, clicks)
    refined_bound = geometry_bound(model, scene.cameras, by_stem, refs, list(refs), n_labels, user.photos,
                                   params)
    print(f"bound (six reference maps lifted): mean IoU {bound['mean_iou']:.3f} rendered from the Gaussians, "
          f"{refined_bound['mean_iou']:.3f} refined against the photos", flush=True)
    t0 = time.perf_counter()
    steps = run(user, front, view_strokes(items, spec, scene.cameras[front]), n_labels, max_strokes, radius,
                target=target, bound=refined_bound)
    stage = score_labels(stage_maps(user, params), refs, n_labels).as_record()
    why = attribute(user, n_labels, front_stem)
    g = why["wrong_gaussians"]
    print(f"wrong pixels by the step that labelled them: {why['wrong_pixels']}; of the Gaussians wrong in the other "
          f"references that the cuts decided ({g['wrong']['lifted']}), {g['wrong']['test_ref']:.0%} carry the test view's "
          f"reference label, which all references lifted together give {g['wrong']['test_ref_is_all']:.0%} of them "
          f"(right ones: {g['right']['test_ref_is_all']:.0%}); in the test view, wrong / right ones: median weight "
          f"{g['wrong']['test_view_weight']:.2f} / {g['right']['test_view_weight']:.2f}, on the cut's label "
          f"{g['wrong']['test_cut_share']:.2f} / {g['right']['test_cut_share']:.2f}, hidden behind its surface "
          f"{g['wrong']['hidden_in_test_view']:.0%} / {g['right']['hidden_in_test_view']:.0%}", flush=True)
    print(f"the masks stage on what the page saved: mean IoU {stage['mean_iou']:.3f} (the page: "
          f"{steps[-1]['mean_iou']:.3f})", flush=True)
    record = {"scene": spec["title"], "n_gaussians": model.num_gaussians, "views": len(scene.cameras),
              "labels": spec["labels"], "reference_views": list(refs), "field": params.model_dump(), "clicks": clicks,
              "target": target,
              "goal": GOAL,
              "geometry_bound": bound, "refined_bound": refined_bound, "steps": steps, "stage": stage,
              "regression": regression(steps, refined_bound), "verdict": verdict(steps, refined_bound),
              "attribution": why,
              "median_segment_seconds": statistics.median(s["seconds"]["total"] for s in steps),
              "seconds": time.perf_counter() - t0}
    print(json.dumps({"regression": record["regression"], "verdict": record["verdict"],
                      "median_segment_seconds": record["median_segment_seconds"]}))
    return record, user


def summary(name: str, overrides: dict, record: dict) -> dict:
    """One row of the settings table: a run's setting, its first and last mean IoU (the stage's maps and the
    Gaussians alone), its worst drops (``regression``), its unlabelled share, its median Segment, the stage's score and
    which parts of the goal it met (``verdict``)."""
    first, last = record["steps"][0], record["steps"][-1]
    return {"setting": name, "overrides": overrides, "field": record["field"],
            "first_mean_iou": first["mean_iou"], "last_mean_iou": last["mean_iou"],
            "first_rendered_mean_iou": first["rendered"]["mean_iou"],
            "last_rendered_mean_iou": last["rendered"]["mean_iou"], "last_worst_iou": last["worst_iou"],
            "worst_mean_drop": record["regression"]["mean"]["drop"],
            "worst_view_drop": record["regression"]["view"]["drop"],
            "max_unlabelled": max(last["unlabelled"].values()),
            "first_segment_seconds": first["seconds"]["total"],
            "median_segment_seconds": record["median_segment_seconds"], "stage_mean_iou": record["stage"]["mean_iou"],
            "regression": record["regression"], "verdict": record["verdict"]}


def main(argv: list[str] | None = None) -> int:
    ap = bench_parser(__doc__)
    ap.add_argument("--scene", default="miku", help="eval/data/<scene>/ (strokes.json, reference/)")
    ap.add_argument("--work", type=Path, nargs="+", required=True,
                    help="where eval.bench.fit left the fitted scene; with --settings, several fits (one run per fit "
                         "and setting: another seed or machine gives another fit)")
    ap.add_argument("--max-strokes", type=int, default=GOAL["strokes"], help="scripted strokes after the test ones")
    ap.add_argument("--radius", type=float, default=4.0, help="the scripted marks' largest radius (pixels)")
    ap.add_argument("--clicks", choices=["dot", "stroke", "ideal"], default="dot",
                    help="each scripted mark: a dot; a straight stroke across the wrong region; ideal: a dot that "
                         "also gives its whole wrong region as the view's evidence (Clicks)")
    ap.add_argument("--target", choices=["view", "pair", "gain"], default="view",
                    help="where each mark goes: the worst view's largest wrong region; pair: the largest wrong region "
                         "of the pair furthest below its goal first; gain: the wrong region that is the largest share "
                         "of its pair's union, on any view (eval.bench.marks.Target)")
    ap.add_argument("--field", default="{}", help="masks.field settings as JSON (default: the masks section's)")
    ap.add_argument("--settings", type=Path,
                    help="a YAML file of named masks.field settings (name: {key: value}, over --field): one run "
                         "each, and --json gets the table of them (eval/data/miku/field_settings.yaml)")
    ap.add_argument("--figure", type=Path, help="write the final labels beside the references here")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    base = json.loads(args.field)
    if args.settings is None:
        if len(args.work) > 1:
            ap.error("one --work without --settings (a record is one run)")
        case = load_case(DATA / args.scene, args.scene, args.work[0])
        record, user = run_setting(case, FieldParams(**base), args.max_strokes, args.radius, clicks=args.clicks,
                                   target=args.target)
        if args.json:
            write_record(args.json, record, argv)
        if args.figure:
            figure(user, record["steps"], args.figure)
        return 0
    import yaml

    settings = yaml.safe_load(args.settings.read_text(encoding="utf-8"))
    rows, fits = [], []
    for work in args.work:
        case, strip = load_case(DATA / args.scene, args.scene, work), None
        for name, overrides in settings.items():
            print(f"== {work}: {name}: {json.dumps(overrides or {})}", flush=True)
            record, user = run_setting(case, FieldParams(**{**base, **(overrides or {})}), args.max_strokes,
                                       args.radius, strip, args.clicks, args.target)
            strip = user.session.strip
            rows.append({"fit": str(work), **summary(name, overrides or {}, record)})
        fits.append({"fit": str(work), "n_gaussians": case.model.num_gaussians,
                     "geometry_bound": record["geometry_bound"], "refined_bound": record["refined_bound"]})
    if args.json:
        write_record(args.json, {"what": f"eval.bench.scripted_user on {case.spec['title']}, one run per fit and "
                                         f"masks.field setting of {args.settings.name}", "scene": case.spec["title"],
                                 "n_gaussians": fits[0]["n_gaussians"], "geometry_bound": fits[0]["geometry_bound"],
                                 "refined_bound": fits[0]["refined_bound"], "fits": fits, "runs": rows}, argv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
