"""Detail on objects under a strong painting: what the content and structure terms keep of a face.

    python -m eval run object_detail --work W --json docs/measurements/miku_face_detail.json \\
        --figure docs/img/fidelity/miku_face_detail.jpg \\
        --setting today=content=0.0005,structure=0 --setting face=2.content=0.005,2.structure=1

A compositional transfer on the miku capture (``--work``: where ``python -m eval run fit --scene
<data>/scenes/miku --format colmap`` left its fit): the doll (hair, face, hood, dress: labels 1-4) takes
``--doll-style``, the bed ``--bed-style``, the room ``--room-style``. The views are the six whose reference label maps
(``eval/data/miku/reference/``) mark the face; the Gaussians' labels are those maps lifted (Eq. 2), the stylization's
label maps the maps themselves. One colour match (``--refit-iterations``), then one stylization per ``--setting``
from it, with params.yaml's ``stylize`` section but for the schedule (``--iterations`` + ``--color-pass-iterations``)
and the setting's λ.

A setting is ``NAME=KEY=VALUE[,KEY=VALUE…]``: ``content``, ``structure`` (or any other ``stylize.weights`` key) sets
that λ everywhere; ``L.content`` and ``L.structure`` the λ of content label ``L`` alone (an experiment's
``content_weights`` / ``structure_weights``). ``NAME=`` alone: params.yaml's weights.

Printed and recorded per setting, each a mean over the six views (and per view in the record):

- ``ssim``: content SSIM of the whole view (the stylized render against the fitted scene's, as the evaluate stage);
- ``face_ssim``: the same SSIM map averaged over the face's pixels (label 2 of the reference map);
- ``face_gradient_ssim``: SSIM of the luminance gradient magnitudes (Sobel, :func:`abcgs.losses.terms.luminance_gradients`)
  over the face's pixels: the eyes', nose's and mouth's edges;
- ``gram``: per painting, the relative Gram distance of the render's part it styles
  (:meth:`abcgs.evaluation.style_distance.GramDistance.per_region`).

``--figure``: the face crops side by side, a row per view with the largest faces, a column per setting beside the
fitted scene and the colour-matched start.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs.evaluation.content import SSIM_WINDOW, ssim_map_wang
from abcgs.evaluation.style_distance import GRAM_LAYERS, GramDistance
from abcgs.features.matching import build_groups, load_style
from abcgs.features.params import TransferSpec
from abcgs.features.vgg import VGG16Features
from abcgs.features.weights import resolve_vgg16
from abcgs.gaussians import fitted_rows, render
from abcgs.gaussians.ply import read_ply
from abcgs.io.images import save_image
from abcgs.losses.terms import luminance_gradients
from abcgs.masks.lifting import NO_VOTE, lift_labels
from abcgs.masks.params import LiftParams
from abcgs.params import load_params
from abcgs.sfm.model import read_scene
from abcgs.stylize.colormatch import color_match_and_refit
from abcgs.stylize.loop import stylize
from abcgs.stylize.params import ColorMatchParams, StyleWeights
from abcgs.stylize.targets import LabelWeights
from abcgs.viz import image_grid
from eval.bench.strokes import DATA, reference_map
from eval.record import bench_parser, write_record

FACE = 2
DOLL = (1, 2, 3, 4)
BED, ROOM = 5, 6


def parse_setting(text: str) -> tuple[str, dict[str, float], LabelWeights]:
    """``NAME=KEY=VALUE,…`` → the name, the ``stylize.weights`` overrides and the per-label λ (module docstring)."""
    name, _, body = text.partition("=")
    if not name:
        raise SystemExit(f"--setting {text!r}: give NAME=KEY=VALUE[,KEY=VALUE...]")
    weights: dict[str, float] = {}
    per_label: dict[str, dict[int, float]] = {"content": {}, "structure": {}}
    for item in filter(None, body.split(",")):
        key, eq, value = item.partition("=")
        if not eq:
            raise SystemExit(f"--setting {text!r}: {item!r} is not KEY=VALUE")
        label, dot, term = key.partition(".")
        if dot:
            if term not in per_label or not label.isdigit():
                raise SystemExit(f"--setting {text!r}: {key!r} is not LABEL.content or LABEL.structure")
            per_label[term][int(label)] = float(value)
        elif key in StyleWeights.model_fields:
            weights[key] = float(value)
        else:
            raise SystemExit(f"--setting {text!r}: {key!r} is no stylize.weights key ({', '.join(StyleWeights.model_fields)})")
    return name, weights, LabelWeights(per_label["content"], per_label["structure"])


def region_ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None) -> float:
    """The mean of the SSIM map of ``(H, W, 3)`` images over ``mask`` ``(H, W)`` (all pixels when None), the map's
    valid positions aligned with the pixels at their windows' centres."""
    m = ssim_map_wang(a, b)[0].mean(0).numpy()
    if mask is None:
        return float(m.mean())
    r = SSIM_WINDOW // 2
    inside = mask[r:r + m.shape[0], r:r + m.shape[1]]
    return float(m[inside].mean()) if inside.any() else float("nan")


def gradient_image(img: np.ndarray) -> np.ndarray:
    """``(H, W, 3)`` → ``(H, W, 3)`` the luminance gradient magnitude in [0, 1], repeated over the channels."""
    g = luminance_gradients(torch.from_numpy(np.ascontiguousarray(img)).float())
    mag = g.norm(dim=0).clamp(0, 1).numpy()
    return np.repeat(mag[..., None], 3, axis=2)


def scores(original: list[np.ndarray], stylized: list[np.ndarray], refs: list[np.ndarray],
           grams: dict[str, tuple[GramDistance, tuple[int, ...]]]) -> dict:
    """The module docstring's numbers for one setting's renders (means and per view)."""
    per_view = []
    for a, b, ref in zip(original, stylized, refs):
        face = ref == FACE
        per_view.append({
            "ssim": region_ssim(a, b, None), "face_ssim": region_ssim(a, b, face),
            "face_gradient_ssim": region_ssim(gradient_image(a), gradient_image(b), face),
            "gram": {p: g.per_region(b, np.isin(ref, labels)) for p, (g, labels) in grams.items()},
        })

    def mean(values) -> float:
        return float(np.nanmean(list(values)))

    return {"ssim": mean(v["ssim"] for v in per_view), "face_ssim": mean(v["face_ssim"] for v in per_view),
            "face_gradient_ssim": mean(v["face_gradient_ssim"] for v in per_view),
            "gram": {p: mean(v["gram"][p] for v in per_view) for p in grams}, "per_view": per_view}


def face_crops(images: list[np.ndarray], ref: np.ndarray, margin: float = 0.35) -> list[np.ndarray]:
    """Each image cropped to the face's bounding box in ``ref``, grown by ``margin`` of its size on each side."""
    ys, xs = np.nonzero(ref == FACE)
    h, w = ys.max() - ys.min() + 1, xs.max() - xs.min() + 1
    y0, y1 = max(0, int(ys.min() - margin * h)), min(ref.shape[0], int(ys.max() + margin * h) + 1)
    x0, x1 = max(0, int(xs.min() - margin * w)), min(ref.shape[1], int(xs.max() + margin * w) + 1)
    return [im[y0:y1, x0:x1] for im in images]


def _renders(model, cams) -> list[np.ndarray]:
    with torch.no_grad():
        return [render(model, c)[0].clamp(0, 1).numpy(force=True) for c in cams]


def _parser():
    """The benchmark's options (module docstring)."""
    ap = bench_parser(__doc__)
    ap.add_argument("--work", type=Path, required=True, help="where eval.bench.fit left the fitted miku scene")
    ap.add_argument("--styles", type=Path, default=Path("../shared/data/styles"), help="the paintings' folder")
    ap.add_argument("--doll-style", default="starry_night", help="the doll's painting (a file stem in --styles)")
    ap.add_argument("--bed-style", default="composition_vii")
    ap.add_argument("--room-style", default="shipwreck")
    ap.add_argument("--setting", action="append", default=[], help="NAME=KEY=VALUE[,...] (module docstring)")
    ap.add_argument("--iterations", type=int, default=150, help="main-pass steps")
    ap.add_argument("--color-pass-iterations", type=int, default=50)
    ap.add_argument("--refit-iterations", type=int, default=200, help="the colour match's re-fit steps")
    ap.add_argument("--params", type=Path, default=Path("params.yaml"))
    ap.add_argument("--figure", type=Path, help="write the face crops here (JPEG or PNG)")
    ap.add_argument("--figure-views", type=int, default=3, help="rows of the figure: the views with the largest faces")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    return ap


def _line(name: str, r: dict) -> str:
    """One setting's scores as the benchmark prints them."""
    return (f"{name}: SSIM {r['ssim']:.3f}, face {r['face_ssim']:.3f}, face gradients {r['face_gradient_ssim']:.3f}; "
            "Gram " + ", ".join(f"{p} {v:.3f}" for p, v in r["gram"].items()))


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    settings = [parse_setting(s) for s in (args.setting or ["defaults="])]
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    if args.threads:
        torch.set_num_threads(args.threads)
    spec = json.loads((DATA / "miku" / "strokes.json").read_text())
    scene = read_scene(args.work / spec["work_colmap"])
    original = read_ply(args.work / spec["work_ply"])
    by_stem = {Path(c.name).stem: i for i, c in enumerate(scene.cameras)}
    stems = [s for s in spec["reference"] if s in by_stem]
    sub = scene.subset([by_stem[s] for s in stems])
    cams = list(sub.cameras)
    refs = [reference_map(DATA / "miku" / "reference" / f"{s}.png", c) for s, c in zip(stems, cams)]
    n_labels = len(spec["labels"])
    gaussian_labels = lift_labels(original, cams, refs, n_labels, LiftParams()).labels
    view_labels = [np.where(r == NO_VOTE, 0, r).astype(np.int64) for r in refs]

    params = load_params(args.params)
    base = params.stylize.with_schedule(args.iterations, args.color_pass_iterations)
    sd, info = resolve_vgg16(params.vgg)
    vgg = VGG16Features(sd, base.layers, feature_scale=info.feature_scale)
    paintings = {"doll": args.doll_style, "bed": args.bed_style, "room": args.room_style}
    styles = {name: str(args.styles / f"{stem}.jpg") for name, stem in paintings.items()}
    bound = {"doll": DOLL, "bed": (BED,), "room": (ROOM,)}
    transfer = TransferSpec(scene="miku", transfer="compositional",
                            styles={label: name for name, labels in bound.items() for label in labels})
    present = {int(v) for v in gaussian_labels.unique()} - {0}
    groups = build_groups(transfer, styles, {}, present, vgg, style_height=base.style_height, layers=base.layers)
    grams = {name: (GramDistance(sd, [load_style(styles[name], base.style_height)], GRAM_LAYERS), labels)
             for name, labels in bound.items()}

    t0 = time.perf_counter()
    cm = color_match_and_refit(original, sub, gaussian_labels, view_labels, groups,
                               ColorMatchParams(refit_iterations=args.refit_iterations))
    print(f"colour match + {args.refit_iterations} re-fit steps: {time.perf_counter() - t0:.0f} s", flush=True)
    originals = _renders(original, cams)
    start = _renders(cm.model, cams)
    results = {"colour-matched start": scores(originals, start, view_labels, grams)}
    renders = {"colour-matched start": start}
    used = {}
    for name, weights, label_weights in settings:
        sp = base.model_copy(update={"weights": base.weights.model_copy(update=weights)})
        t0 = time.perf_counter()
        res = stylize(cm.model, cams, view_labels, gaussian_labels[fitted_rows(cm.model)], groups, vgg, sp,
                      depth_model=original, label_weights=label_weights, progress=False)
        renders[name] = _renders(res.model, cams)
        main_steps = [h for h in res.history if h.pass_name == "main"]
        results[name] = scores(originals, renders[name], view_labels, grams) | {
            "seconds": time.perf_counter() - t0, "first_terms": main_steps[0].terms, "last_terms": main_steps[-1].terms}
        used[name] = {"weights": sp.weights.model_dump(), "content_weights": dict(label_weights.content),
                      "structure_weights": dict(label_weights.structure)}
        print(_line(name, results[name]) + f" ({results[name]['seconds']:.0f} s)", flush=True)
    print(_line("colour-matched start", results["colour-matched start"]))
    record = {"scene": spec["title"], "views": stems, "n_gaussians": original.num_gaussians,
              "paintings": paintings, "labels": spec["labels"],
              "schedule": {"refit": args.refit_iterations, "main": args.iterations,
                           "color_pass": args.color_pass_iterations},
              "settings": used, "results": results, "vgg_weights": info.model_dump()}
    if args.json:
        write_record(args.json, record, argv)
    if args.figure:
        largest = sorted(range(len(stems)), key=lambda i: -int((view_labels[i] == FACE).sum()))[:args.figure_views]
        columns = ["fitted", *renders]
        rows = [face_crops([originals[i], *(renders[k][i] for k in renders)], view_labels[i]) for i in largest]
        save_image(args.figure, image_grid(rows, columns, height=220))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
