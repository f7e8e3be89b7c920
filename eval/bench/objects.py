"""Object benchmark: a splat of a thing on nothing comes back as the same thing painted, with empty space left empty.

    python -m eval run objects --work /work/bench/objects --miku-fit MIKU_PLY \\
        --json docs/measurements/objects.json --figure docs/img/objects/objects.jpg
    python -m eval run objects --work /tmp/objects --objects rgba --paintings starry_night --quick   # a smoke run

Objects (each made here, from the project's generator or the shared data):

- ``rgba``: the tiny scene's box and sphere on nothing as a NeRF-synthetic dataset (straight-alpha RGBA views on
  three rings, :func:`abcgs.scene.synthetic.write_object_dataset`), read on black as the ``blender`` reader does,
  reconstructed with its own cameras and fitted (:func:`abcgs.fit.training.fit`, ``--fit-iterations``).
- ``miku_splat``: the doll of ``../shared/data/scenes/miku`` cut from a fit of the scene (``--miku-fit``, e.g.
  ``python -m eval run fit --scene ../shared/data/scenes/miku --format colmap --test-every 0``) by a box and
  opacity (:func:`cut_doll`), written as a bare ``.splat`` and read back as a scene the way ``add-scene`` takes one:
  16 views generated around it (:func:`abcgs.splats.cameras.cameras_around`) at 320 × 240, its renders as the photos.
- ``miku_scene``: the same doll with 16 of the capture's photos (every 6th, at half size): each photo cut out by the
  doll's alpha in that view (an RGBA photo set, like a capture with masks), on black.

Each object is stylized with each painting at the photo-size schedule (colour match with a 400-step re-fit, 300
stylization steps + a 200-step colour pass) twice: as an **object** scene (its background recorded: colour match and
style on the object's pixels, silhouette and background held, :mod:`abcgs.silhouette`) and treated as a
**frame-filling** scene (every pixel content: what the pipeline did with every scene before it knew objects). The
metrics (:mod:`abcgs.evaluation.objects`) on every view: the share of empty pixels that moved by more than 0.05, the
silhouette IoU, content SSIM on the object, the Gram distance to the painting (against the colour match's), and for
generated views the largest original alpha on any view's border (an object pixel there would be ≥ 0.5).
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import cv2
import numpy as np
import torch

from abcgs.cameras import Camera, Cameras
from abcgs.evaluation.objects import object_scores
from abcgs.evaluation.style_distance import gram_scores
from abcgs.features.matching import build_groups
from abcgs.features.params import IsolationParams, TransferSpec, VggWeightsParams
from abcgs.features.vgg import VGG16Features
from abcgs.features.weights import resolve_vgg16
from abcgs.fit.params import FitParams
from abcgs.fit.training import fit
from abcgs.gaussians import GaussianModel, render
from abcgs.gaussians.ply import read_ply, write_ply
from abcgs.io.atomic import write_json
from abcgs.io.images import load_image, save_image
from abcgs.layout import ColmapDir
from abcgs.scene.params import TinySceneParams
from abcgs.scene.synthetic import write_object_dataset
from abcgs.sfm.model import read_scene
from abcgs.sfm.params import ReconstructParams
from abcgs.silhouette import EMPTY_ALPHA, background_tensor
from abcgs.sources.blender import read_blender_source
from abcgs.sources.model import write_source_model
from abcgs.sources.validate import axes_meeting_point
from abcgs.splats.formats.splat import write_splat_file
from abcgs.splats.params import SplatViewsParams
from abcgs.stylize.colormatch import color_match_and_refit
from abcgs.stylize.loop import stylize
from abcgs.stylize.params import ColorMatchParams, StylizeParams
from abcgs.types import FRAME_FILLING, Background, CalibratedScene, SceneViews
from abcgs.viz import image_grid
from eval.record import bench_parser, write_record

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared" / "data"
OBJECT = Background(object=True)
MODES = {"object": OBJECT, "frame": FRAME_FILLING}
"""How each run treats the object: as an object scene, or as a frame-filling one (every pixel content)."""


@dataclass
class ObjectCase:
    """One object: its views, the original Gaussians, and whether the views were generated around it."""

    name: str
    scene: SceneViews
    original: GaussianModel
    generated_views: bool


# ------------------------------------------------------------------------------------------------ the objects
def rgba_object(work: Path, width: int, fit_iterations: int) -> ObjectCase:
    """The generated RGBA object, reconstructed with its own cameras (points triangulated) and fitted on black."""
    folder, colmap, ply = work / "rgba" / "dataset", work / "rgba" / "colmap", work / "rgba" / "point_cloud.ply"
    if not folder.is_dir():
        write_object_dataset(folder, TinySceneParams(n_views=24, width=width, height=width * 3 // 4))
    if not colmap.is_dir():
        source = read_blender_source(folder, background=(0.0, 0.0, 0.0))
        write_source_model(source, colmap, ReconstructParams(), background=OBJECT)
    scene = read_scene(colmap)
    if not ply.is_file():
        res = fit(scene, FitParams(iterations=fit_iterations, test_every=0, background=(0.0, 0.0, 0.0)), progress=True)
        write_ply(ply, res.model)
    return ObjectCase("rgba", scene, read_ply(ply), False)


def cut_doll(model: GaussianModel, cameras: list[Camera], radius: float, below: float, above: float,
             min_opacity: float) -> GaussianModel:
    """The doll of the miku capture: the Gaussians at least ``min_opacity`` opaque inside a cylinder of ``radius``
    around the point the cameras look at, from ``below`` under it to ``above`` over it along the cameras' mean up
    (world units of the capture)."""
    centre = axes_meeting_point(cameras)
    up = -np.mean([c.viewmat[1, :3] for c in cameras], axis=0)  # image up (-y of each camera) in world
    up /= np.linalg.norm(up)
    with torch.no_grad():
        d = model.means.double().numpy() - centre
        h = d @ up
        r = np.linalg.norm(d - h[:, None] * up, axis=1)
        keep = (r <= radius) & (h >= -below) & (h <= above) & (model.opacities.double().numpy() >= min_opacity)
    return model.index(torch.from_numpy(keep))


def miku_objects(work: Path, fit_ply: Path, args) -> list[ObjectCase]:
    """The doll as a bare splat (generated views) and with the capture's photos cut out by its alpha."""
    colmap = _miku_colmap(fit_ply)
    capture = read_scene(colmap)
    doll = cut_doll(read_ply(fit_ply), capture.cameras, args.doll_radius, args.doll_below, args.doll_above, 0.05)
    out = work / "miku"
    out.mkdir(parents=True, exist_ok=True)
    splat = out / "doll.splat"
    write_splat_file(splat, doll)
    cases = []
    if "miku_splat" in args.objects:
        from abcgs.sources.bare_splat import read_splat_source
        from abcgs.splats.registry import read_splat

        views = SplatViewsParams(count=args.miku_views, width=args.splat_width, height=args.splat_width * 3 // 4, up=args.miku_up)
        source = read_splat_source(splat, out / "splat_views", views, background=(0.0, 0.0, 0.0))
        scene = source
        cases.append(ObjectCase("miku_splat", scene, read_splat(splat).model, True))
    if "miku_scene" in args.objects:
        step = max(1, len(capture.cameras) // args.miku_views)
        picked = list(range(0, len(capture.cameras), step))[: args.miku_views]
        cams = [capture.cameras[i].scaled(args.miku_scale) for i in picked]
        photos = out / "photos"
        paths = []
        for cam, i in zip(cams, picked):
            with torch.no_grad():
                alpha = render(doll, cam)[1].numpy()
            dst = photos / f"{Path(cam.name).stem}.png"
            if not dst.is_file():  # the photo at the camera's size, cut out by the doll, on black
                photo = cv2.resize(load_image(capture.image_paths[i]), (cam.width, cam.height), interpolation=cv2.INTER_AREA)
                save_image(dst, photo * alpha)
            paths.append(dst)
        cases.append(ObjectCase("miku_scene", CalibratedScene(Cameras.from_list(cams), paths, capture.points, capture.colors),
                                doll, False))
    return cases


def _miku_colmap(fit_ply: Path) -> Path:
    """The reconstructed scene beside an ``eval.bench.fit`` run's ``gs/point_cloud.ply``."""
    colmap = fit_ply.parent.parent / "colmap"
    if not ColmapDir(colmap).scene.is_file():
        raise SystemExit(f"{colmap} is missing: --miku-fit must be the gs/point_cloud.ply of an eval.bench.fit run")
    return colmap


# ------------------------------------------------------------------------------------------------ one run
@torch.no_grad()
def _renders(model: GaussianModel, cams: list[Camera], bg: torch.Tensor) -> tuple[list[np.ndarray], list[np.ndarray]]:
    imgs, alphas = [], []
    for c in cams:
        img, a, _ = render(model, c, background=bg)
        imgs.append(img.clamp(0, 1).numpy())
        alphas.append(a[..., 0].numpy())
    return imgs, alphas


def measure(case: ObjectCase, original: tuple, result: GaussianModel, matched: GaussianModel, painting: np.ndarray,
            vgg_state: dict) -> dict:
    """The object metrics of one stylization (module docstring); views rendered on black."""
    bg = torch.zeros(3)
    (o_imgs, o_alpha), (s_imgs, s_alpha) = original, _renders(result, case.scene.cameras, bg)
    m_imgs, _ = _renders(matched, case.scene.cameras, bg)
    scores = object_scores(o_imgs, s_imgs, o_alpha, s_alpha)  # the evaluate stage's own definitions
    return {
        "background_change": scores.background_change, "silhouette_iou": scores.silhouette_iou,
        "ssim_object": scores.ssim_object,
        "gram_distance": gram_scores(vgg_state, s_imgs, [painting]).mean,
        "gram_distance_colormatch": gram_scores(vgg_state, m_imgs, [painting]).mean,
        "empty_fraction": float(np.mean([(a < EMPTY_ALPHA).mean() for a in o_alpha])),
    }


def border_alpha(case: ObjectCase, alphas: list[np.ndarray]) -> float:
    """The largest original alpha on any view's border (1-pixel frame)."""
    return float(max(max(a[0].max(), a[-1].max(), a[:, 0].max(), a[:, -1].max()) for a in alphas))


def run_case(case: ObjectCase, painting_name: str, painting_path: Path, mode: str, vgg: VGG16Features,
             vgg_state: dict, sp: StylizeParams, cm: ColorMatchParams, out: Path) -> dict:
    background = MODES[mode]
    labels = torch.zeros(case.original.num_gaussians, dtype=torch.long)
    view_labels = [np.zeros((c.height, c.width), np.int64) for c in case.scene.cameras]
    groups = build_groups(TransferSpec(scene=case.name, transfer="single", style=painting_name),
                          {painting_name: str(painting_path)}, {}, set(), vgg, style_height=sp.style_height,
                          isolation=IsolationParams(), layers=sp.layers)
    t0 = time.perf_counter()
    matched = color_match_and_refit(case.original, case.scene, labels, view_labels, groups, cm, progress=False,
                                    background=background)
    t1 = time.perf_counter()
    res = stylize(matched.model, case.scene.cameras, view_labels, labels, groups, vgg, sp, depth_model=case.original,
                  background=background, progress=False)
    t2 = time.perf_counter()
    original = _renders(case.original, case.scene.cameras, torch.zeros(3))
    record = measure(case, original, res.model, matched.model, load_image(painting_path), vgg_state)
    record.update(colormatch_seconds=t1 - t0, stylize_seconds=t2 - t1, n_gaussians=case.original.num_gaussians)
    write_ply(out / f"{case.name}_{painting_name}_{mode}.ply", res.model)
    return record


# ------------------------------------------------------------------------------------------------ the figure
def figure(cases: list[ObjectCase], runs: list[tuple[str, str]], work: Path, path: Path,
           views: tuple[float, ...]) -> None:
    """Per object and view (``views``: fractions of the way through its views): the original, then each run
    ``(painting, mode)``."""
    rows, captions = [], ["original"] + [f"{p}: as {'an object' if m == 'object' else 'frame-filling'}" for p, m in runs]
    for case in cases:
        for v in views:
            cam = case.scene.cameras[min(int(v * len(case.scene.cameras)), len(case.scene.cameras) - 1)]
            with torch.no_grad():
                row = [render(case.original, cam)[0].clamp(0, 1).numpy()]
                for p, mode in runs:
                    m = read_ply(work / f"{case.name}_{p}_{mode}.ply")
                    row.append(render(m, cam, background=background_tensor(MODES[mode]))[0].clamp(0, 1).numpy())
            rows.append(row)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_image(path, image_grid(rows, captions, height=200))


def main(argv: list[str] | None = None) -> dict:
    ap = bench_parser(__doc__)
    ap.add_argument("--work", type=Path, required=True, help="cache of the objects and the stylized PLYs")
    ap.add_argument("--objects", default="rgba,miku_splat,miku_scene")
    ap.add_argument("--paintings", default="starry_night,udnie", help="stems in ../shared/data/styles")
    ap.add_argument("--styles", type=Path, default=SHARED / "styles")
    ap.add_argument("--miku-fit", type=Path, default=None, help="gs/point_cloud.ply of an eval.bench.fit run of miku")
    ap.add_argument("--miku-up", default="-y", help="views.up of the doll's generated views")
    ap.add_argument("--doll-radius", type=float, default=1.7, help="cut_doll's cylinder (capture units)")
    ap.add_argument("--doll-below", type=float, default=1.3)
    ap.add_argument("--doll-above", type=float, default=2.0)
    ap.add_argument("--miku-views", type=int, default=16, help="photos of the miku_scene object (every k-th)")
    ap.add_argument("--miku-scale", type=float, default=0.5, help="the miku_scene photos' scale (of 493 x 370)")
    ap.add_argument("--splat-width", type=int, default=320)
    ap.add_argument("--rgba-width", type=int, default=320)
    ap.add_argument("--fit-iterations", type=int, default=2000)
    ap.add_argument("--frame-paintings", default="starry_night",
                    help="the paintings also run with the object treated as frame-filling (for comparison)")
    ap.add_argument("--quick", action="store_true", help="a short schedule (30 + 20 steps, 40-step re-fit)")
    ap.add_argument("--figure", type=Path, default=None)
    args = ap.parse_args(argv)
    args.objects = args.objects.split(",")
    torch.manual_seed(0)
    work = args.work
    work.mkdir(parents=True, exist_ok=True)
    cases = [rgba_object(work, args.rgba_width, args.fit_iterations)] if "rgba" in args.objects else []
    if any(o.startswith("miku") for o in args.objects):
        if args.miku_fit is None:
            raise SystemExit("--miku-fit is needed for the miku objects")
        cases += miku_objects(work, args.miku_fit, args)
    sp = StylizeParams()
    cm = ColorMatchParams()
    if args.quick:
        sp = sp.with_schedule(30, 20)
        cm = ColorMatchParams(refit_iterations=40)
    state, info = resolve_vgg16(VggWeightsParams())
    vgg = VGG16Features(state, sp.layers, feature_scale=info.feature_scale)
    paintings = args.paintings.split(",")
    framed = set(args.frame_paintings.split(",")) if args.frame_paintings else set()
    runs = [(p, m) for p in paintings for m in ("frame", "object") if m == "object" or p in framed]
    record = {"load_average_at_start": list(os.getloadavg()),
              "schedule": {"refit": cm.refit_iterations, "stylize": sp.optim.iterations,
                           "color_pass": sp.optim.color_pass_iterations}, "objects": {}}
    for case in cases:
        with torch.no_grad():
            alphas = [render(case.original, c)[1][..., 0].numpy() for c in case.scene.cameras]
        entry = {"views": len(case.scene.cameras), "size": [case.scene.cameras[0].width, case.scene.cameras[0].height],
                 "n_gaussians": case.original.num_gaussians, "border_alpha": border_alpha(case, alphas),
                 "generated_views": case.generated_views, "runs": {}}
        for p, mode in runs:
            done = work / f"{case.name}_{p}_{mode}.json"  # a finished run is kept: the benchmark resumes
            r = (json.loads(done.read_text()) if done.is_file() and not args.quick
                 else run_case(case, p, args.styles / f"{p}.jpg", mode, vgg, state, sp, cm, work))
            write_json(done, r)
            entry["runs"][f"{p}/{mode}"] = r
            print(f"{case.name:11s} {p:14s} {mode:7s} background_change {r['background_change']:.4f}  "
                  f"silhouette_iou {r['silhouette_iou']:.3f}  ssim_object {r['ssim_object']:.3f}  gram "
                  f"{r['gram_distance']:.3f} (colour match {r['gram_distance_colormatch']:.3f})  "
                  f"{r['stylize_seconds']:.0f} s", flush=True)
        record["objects"][case.name] = entry
        if args.json:
            write_record(args.json, record, argv)
    if args.figure:
        figure(cases, runs, work, args.figure, (0.0, 0.4))
    print(json.dumps({k: {"border_alpha": v["border_alpha"]} for k, v in record["objects"].items()}))
    return record


if __name__ == "__main__":
    main()
