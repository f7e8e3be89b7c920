"""Quality study: one real scene × several paintings × style losses, same schedule and seed; figures + table.

    python eval/quality_study.py --scene ../shared/data/scenes/fern \
        --styles starry_night,woman_with_hat_matisse,shipwreck --ablation-style starry_night --jobs 2

What runs (single-image transfer, the library's default stylization schedule unless ``--set`` changes it):

- every painting: FAST with this project's defaults (``fast``) and NNFM (``nnfm``);
- the ablation painting also: the authors' FAST variant (``fast_authors``: per-channel cosine and the authors'
  learning rates, :data:`VARIANTS`), KNNFM and Gram.

Every run uses the same fitted scene, the same colour-matched start per painting, the same seed and schedule.
Work is cached under ``--work`` (default ``out/quality/<scene>``) keyed by a hash of everything that
determines it (params, painting file, method), so an interrupted or extended study only runs what is
missing; ``--force`` redoes the runs. The fitted scene is shared with ``eval/bench_fit.py``
(``out/bench/<scene>/{colmap,gs}``) and made with its settings when absent.

Outputs in ``--work``: ``figure_<painting>.png`` (two views, every method side by side, the painting, and
a 2× crop row), ``table.md`` / ``table.csv`` / ``study.json`` (per run: SSIM, short/long warp RMSE and VGG
proxy consistency, Gram style distance, patch FID/KID proxy, stylization wall time), and it prints the
table and the issue-11 acceptance checks. Metric definitions: ``eval/metrics`` and README
"Evaluation metrics"; ``gram_distance``: ``eval/metrics/style_distance.py``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import abcgs  # noqa: E402,F401  (before torch: abcgs sets OpenMP's wait policy, see abcgs/__init__.py)

# isort: split
import numpy as np  # noqa: E402
import torch  # noqa: E402
import yaml  # noqa: E402

from abcgs.cameras import Camera  # noqa: E402
from abcgs.errors import InputError  # noqa: E402
from abcgs.eval_params import EvalParams  # noqa: E402
from abcgs.gaussians import GaussianModel  # noqa: E402
from abcgs.io.atomic import write_json, write_text  # noqa: E402
from abcgs.io.images import save_image  # noqa: E402
from abcgs.io.ply import read_ply, write_ply  # noqa: E402
from abcgs.params import deep_merge, set_dotted  # noqa: E402
from abcgs.sfm.colmap import ReconstructParams, read_colmap_scene, reconstruct  # noqa: E402
from abcgs.style.colormatch import ColorMatchParams, color_match_and_refit  # noqa: E402
from abcgs.style.matching import TransferSpec, build_groups, load_style  # noqa: E402
from abcgs.style.stylize import StylizeParams, StylizeResult, stylize  # noqa: E402
from abcgs.style.vgg import VGG16Features  # noqa: E402
from abcgs.style.weights import VggWeightsParams, resolve_vgg16  # noqa: E402

STUDY_VERSION = 2
"""Bump when the study's own procedure changes (invalidates the cache). 2: runs are keyed by the validated
sections (library defaults included), so a changed default invalidates what it changes."""

VARIANTS: dict[str, dict] = {
    "default": {},
    # the authors' code (vpx-ecnu/ABC-GS): cosine per channel across pixels, INRIA learning rates with xyz frozen
    "authors": {"fast": {"cosine": "channel"}, "lr_preset": "authors_code"},
}
METHOD_LABELS = {("fast", "default"): "FAST (default)", ("nnfm", "default"): "NNFM (ARF)",
                 ("fast", "authors"): "FAST (authors' code: channel cosine)", ("knnfm", "default"): "KNNFM", ("gram", "default"): "Gram",
                 ("colormatch", "default"): "colour match only (the start)",
                 ("original", "default"): "original scene (no stylization)"}
REFERENCE_METHODS = ("colormatch", "original")
"""Rows that stylize nothing: the colour-matched start (what a recolouring alone gives) and the fitted scene
itself (its consistency numbers are the floor of the flow-based measurement: flow error, view-dependent colour)."""
FIT_SETTINGS = {"iterations": 3000, "max_gaussians": 150_000, "refine_start": 300, "refine_every": 100,
                "refine_stop": 1800, "reset_every": 1500}
"""The fit of eval/bench_fit.py and `make bench-fern` (README "Fern benchmark")."""


@dataclass(frozen=True)
class RunSpec:
    style: str
    method: str
    variant: str = "default"

    @property
    def name(self) -> str:
        return f"{self.style}__{self.method}" + ("" if self.variant == "default" else f"_{self.variant}")

    @property
    def label(self) -> str:
        return METHOD_LABELS.get((self.method, self.variant), f"{self.method} ({self.variant})")


RUNTIME_KEYS = ("threads", "backend", "log_every", "num_threads", "max_block_elems", "knn_search")
"""How a run executes, not what it computes: left out of the cache keys, at any depth (``stylize.fast.max_block_elems``
is the similarity tile size: the same neighbours, up to float summation order)."""


def _semantic(section: dict) -> dict:
    return {k: _semantic(v) if isinstance(v, dict) else v for k, v in section.items() if k not in RUNTIME_KEYS}


def _digest(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:12]


def _file_sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


# ------------------------------------------------------------------------------------------- the scene
def ensure_scene(scene_dir: Path, bench_root: Path, threads: int, fit_iterations: int = 3000) -> tuple[Path, Path, dict]:
    """COLMAP model + fitted 3DGS of ``scene_dir`` in ``bench_root/<scene>/{colmap,gs}`` (made if missing).

    The fit uses :data:`FIT_SETTINGS`, its step counts scaled by ``fit_iterations / 3000``.
    """
    base = bench_root / scene_dir.name
    colmap, ply = base / "colmap", base / "gs" / "point_cloud.ply"
    if not (colmap / "sparse").is_dir():
        print(f"[study] reconstructing {scene_dir} → {colmap}", flush=True)
        reconstruct(scene_dir / "images", colmap, ReconstructParams())
    if not ply.is_file():
        from abcgs.fit.strategy import StrategyParams
        from abcgs.fit.trainer import FitParams, fit

        s = FIT_SETTINGS
        f = fit_iterations / s["iterations"]
        fp = FitParams(iterations=fit_iterations, max_gaussians=s["max_gaussians"], threads=threads,
                       strategy=StrategyParams(refine_start=s["refine_start"], refine_every=s["refine_every"],
                                               refine_stop=s["refine_stop"], reset_every=s["reset_every"]).scaled(f))
        print(f"[study] fitting {scene_dir.name}: {fp.iterations} steps, {fp.strategy.model_dump()}", flush=True)
        scene = read_colmap_scene(colmap / "sparse", colmap / "images")
        res = fit(scene, fp, progress=True)
        write_ply(ply, res.model)
    return colmap, ply, {"colmap": str(colmap), "ply": str(ply), "ply_sha": _file_sha(ply)}


# ------------------------------------------------------------------------------------------- workers
def _setup(threads: int) -> None:
    torch.set_num_threads(threads)
    os.environ.setdefault("HF_HUB_OFFLINE", "1")


def _vgg(params: dict, layers) -> tuple[VGG16Features, dict]:
    sd, info = resolve_vgg16(VggWeightsParams(**params.get("vgg", {})))
    return VGG16Features(sd, layers, feature_scale=info.feature_scale), info.model_dump()


def _groups(style_path: str, sp: StylizeParams, vgg: VGG16Features):
    exp = TransferSpec(scene="scene", transfer="single", style="style")
    return build_groups(exp, {"style": style_path}, {}, set(), vgg, style_height=sp.style_height, layers=sp.layers)


def colormatch_job(job: dict) -> dict:
    """Colour match + re-fit of the fitted scene to one painting; writes ``job['out']`` (PLY)."""
    _setup(job["threads"])
    out = Path(job["out"])
    if out.is_file():
        return {"path": str(out), "cached": True}
    scene = read_colmap_scene(Path(job["colmap"]) / "sparse", Path(job["colmap"]) / "images")
    original = read_ply(job["ply"])
    sp = StylizeParams(**job["stylize"])
    vgg, _ = _vgg(job, sp.layers)
    groups = _groups(job["style_path"], sp, vgg)
    labels = torch.zeros(original.num_gaussians, dtype=torch.long)
    view_labels = [np.zeros((c.height, c.width), np.int64) for c in scene.cameras]
    t0 = time.perf_counter()
    res = color_match_and_refit(original, scene, labels, view_labels, groups, ColorMatchParams(**job["colormatch"]),
                                progress=False)
    write_ply(out, res.model)
    return {"path": str(out), "cached": False, "seconds": time.perf_counter() - t0}


def run_job(job: dict) -> dict:
    """Stylize the colour-matched scene with one method, evaluate it, write ``<run dir>/{point_cloud.ply,run.json}``."""
    _setup(job["threads"])
    run_dir = Path(job["run_dir"])
    record = run_dir / "run.json"
    if record.is_file():
        return json.loads(record.read_text())
    from eval.metrics.evaluate import evaluate_images, render_views

    scene = read_colmap_scene(Path(job["colmap"]) / "sparse", Path(job["colmap"]) / "images")
    original = read_ply(job["ply"])
    matched = read_ply(job["colormatch_ply"])
    sp = StylizeParams(**job["stylize"])
    vgg, vgg_info = _vgg(job, sp.layers)
    if job["method"] in REFERENCE_METHODS:  # nothing to stylize: evaluate the start or the scene itself
        model = matched if job["method"] == "colormatch" else original
        res = StylizeResult(model=model, history=[], timings={}, fast_stats={}, seconds=0.0)
    else:
        groups = _groups(job["style_path"], sp, vgg)
        labels = torch.zeros(matched.num_gaussians, dtype=torch.long)
        view_labels = [np.zeros((c.height, c.width), np.int64) for c in scene.cameras]
        res = stylize(matched, scene.cameras, view_labels, labels, groups, vgg, sp, method=job["method"],
                      depth_model=original, progress=False)
    ep = EvalParams(**job["evaluate"])
    originals, _ = render_views(original, scene.cameras, ep.backend)
    styled, _ = render_views(res.model, scene.cameras, ep.backend)
    style_img = load_style(job["style_path"], 0)
    t0 = time.perf_counter()
    ev = evaluate_images(originals, styled, [style_img], ep, vgg_params=VggWeightsParams(**job.get("vgg", {})))
    m = ev.metrics
    n_it = max(1, res.timings.get("iterations", 1))
    out = {
        "name": job["name"], "style": job["style"], "method": job["method"], "variant": job["variant"],
        "key": job["key"], "stylize_params": sp.model_dump(), "n_gaussians": res.model.num_gaussians,
        "stylize_seconds": res.seconds, "color_pass_seconds": res.color_pass_seconds,
        "seconds_per_iteration": {k: v / n_it for k, v in res.timings.items() if k != "iterations"},
        "eval_seconds": time.perf_counter() - t0, "threads": job["threads"], "fast_stats": res.fast_stats,
        "metrics": {k: v for k, v in m.items() if not isinstance(v, dict)},
        "provenance": m.get("provenance", {}), "vgg_weights": vgg_info,
        "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                    "torch": torch.__version__},
    }
    run_dir.mkdir(parents=True, exist_ok=True)
    if job["method"] not in REFERENCE_METHODS:  # the reference scenes already lie in the cache
        write_ply(run_dir / "point_cloud.ply", res.model)
    write_json(record, out)  # last: its presence marks the run as done
    return out


# ------------------------------------------------------------------------------------------- outputs
COLUMNS = [("ssim", "SSIM ↑", 3), ("short_rmse", "short RMSE ↓", 4), ("long_rmse", "long RMSE ↓", 4),
           ("short_lpips_proxy_vgg", "short LPIPS-proxy ↓", 3), ("long_lpips_proxy_vgg", "long LPIPS-proxy ↓", 3),
           ("gram_distance", "Gram dist. ↓", 3), ("kid_tf_inception", "KID proxy ↓", 4),
           ("fid_tf_inception", "FID proxy ↓", 1)]


def table(results: list[dict], specs: list[RunSpec]) -> tuple[str, str]:
    head = ["painting", "method"] + [c[1] for c in COLUMNS] + ["stylize min"]
    md = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    csv = [",".join(["painting", "method"] + [c[0] for c in COLUMNS] + ["stylize_minutes"])]
    by = {r["name"]: r for r in results}
    for s in specs:
        r = by[s.name]
        m = r["metrics"]
        vals = [("nan" if m.get(k) is None else f"{m[k]:.{d}f}") for k, _, d in COLUMNS]
        md.append("| " + " | ".join([s.style, s.label, *vals, f"{r['stylize_seconds'] / 60:.1f}"]) + " |")
        csv.append(",".join([s.style, s.name, *[str(m.get(k)) for k, _, _ in COLUMNS], f"{r['stylize_seconds'] / 60:.3f}"]))
    return "\n".join(md) + "\n", "\n".join(csv) + "\n"


def acceptance(results: list[dict], styles: list[str]) -> list[str]:
    """Issue 11's acceptance checks on this study's numbers (printed, also stored in study.json)."""
    by = {(r["style"], r["method"], r["variant"]): r["metrics"] for r in results}
    fast = [by[(s, "fast", "default")] for s in styles]
    nnfm = [by[(s, "nnfm", "default")] for s in styles]
    mean = lambda k, rows: float(np.mean([r[k] for r in rows]))  # noqa: E731
    lines = [
        f"mean SSIM, FAST default over {len(styles)} paintings: {mean('ssim', fast):.3f} (target ≤ 0.60)",
        f"mean short RMSE {mean('short_rmse', fast):.4f} (≤ 0.048), long RMSE {mean('long_rmse', fast):.4f} (≤ 0.077)",
    ]
    wins_gram = sum(f["gram_distance"] < n["gram_distance"] for f, n in zip(fast, nnfm))
    wins_kid = sum(f["kid_tf_inception"] < n["kid_tf_inception"] for f, n in zip(fast, nnfm))
    both = sum(f["gram_distance"] < n["gram_distance"] and f["kid_tf_inception"] < n["kid_tf_inception"]
               for f, n in zip(fast, nnfm))
    ssim_gap = max(n["ssim"] - f["ssim"] for f, n in zip(fast, nnfm))
    lines.append(f"FAST beats NNFM on Gram distance for {wins_gram}/{len(styles)}, on KID for {wins_kid}/{len(styles)}, "
                 f"on both for {both}/{len(styles)} paintings (target ≥ 2 on both)")
    lines.append(f"largest SSIM deficit of FAST vs NNFM: {ssim_gap:+.3f} (target ≤ 0.03)")
    floor = [r for (s, meth, _), r in by.items() if meth == "original"]
    if floor:
        f = floor[0]
        lines.append(f"measurement floor — the unstylized scene under the same flow: short/long RMSE "
                     f"{f['short_rmse']:.4f}/{f['long_rmse']:.4f}; FAST's mean excess over it "
                     f"{mean('short_rmse', fast) - f['short_rmse']:+.4f}/{mean('long_rmse', fast) - f['long_rmse']:+.4f}")
    starts = {s: by.get((s, "colormatch", "default")) for s in styles}
    if all(starts.values()):
        moved = ", ".join(f"{s} {starts[s]['gram_distance']:.3f} → {f['gram_distance']:.3f}" for s, f in zip(styles, fast))
        lines.append(f"Gram distance, colour match only → FAST: {moved} (beyond recolouring when it drops)")
    return lines


def _render(model: GaussianModel, camera: Camera) -> np.ndarray:
    """``(H, W, 3)`` float render in [0, 1] for the figures."""
    from abcgs.gaussians import render

    with torch.no_grad():
        return render(model, camera)[0].clamp(0, 1).numpy()


def figure(specs: list[RunSpec], style: str, style_path: str, cameras: list[Camera], ply: Path, model_paths: dict[str, Path],
           views: tuple[int, ...], crop: tuple[int, int, int, int]) -> np.ndarray:
    """Rows: the chosen views (original, each method, painting), then a 2× crop of the first view."""
    import cv2

    from abcgs.viz import image_grid

    mine = [s for s in specs if s.style == style and s.method != "original"]
    models = [read_ply(ply)] + [read_ply(model_paths[s.name]) for s in mine]
    captions = ["original"] + [s.label for s in mine] + ["painting"]
    painting = load_style(style_path, 0)
    rows = [[_render(m, cameras[v]) for m in models] + [painting] for v in views]
    x0, y0, x1, y1 = crop
    crop_row = []
    for img in rows[0][:-1]:
        c = img[y0:y1, x0:x1]
        crop_row.append(cv2.resize(c, (2 * c.shape[1], 2 * c.shape[0]), interpolation=cv2.INTER_CUBIC))
    rows.append(crop_row)
    return image_grid(rows, captions, height=rows[0][0].shape[0])


def overview_figure(styles: list[str], style_paths: dict[str, Path], cameras: list[Camera], ply: Path,
                    model_paths: dict[str, Path], view: int) -> np.ndarray:
    """One row per painting at one view: original, colour match only, FAST, NNFM, the painting."""
    from abcgs.viz import image_grid

    cam = cameras[view]
    original = _render(read_ply(ply), cam)
    rows = []
    for style in styles:
        names = [RunSpec(style, m).name for m in ("colormatch", "fast", "nnfm")]
        rows.append([original] + [_render(read_ply(model_paths[n]), cam) for n in names if n in model_paths]
                    + [load_style(str(style_paths[style]), 0)])
    captions = ["original", "colour match only", "FAST (default)", "NNFM (ARF)", "painting"]
    return image_grid(rows, captions, height=original.shape[0])


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, required=True, help="scene folder with images/")
    ap.add_argument("--style-dir", type=Path, default=Path("../shared/data/styles"))
    ap.add_argument("--styles", default="starry_night,woman_with_hat_matisse,shipwreck",
                    help="comma-separated painting names (files <name>.jpg in --style-dir)")
    ap.add_argument("--ablation-style", default="starry_night", help="painting that also gets the ablation runs")
    ap.add_argument("--params", type=Path, default=None,
                    help="YAML with stylize/colormatch/evaluate/vgg sections (default: the library defaults)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override, e.g. stylize.iterations=300 (YAML value)")
    ap.add_argument("--work", type=Path, default=None, help="cache and outputs (default out/quality/<scene>)")
    ap.add_argument("--bench-root", type=Path, default=Path("out/bench"), help="shared COLMAP + fit cache")
    ap.add_argument("--jobs", type=int, default=1, help="runs in parallel (processes)")
    ap.add_argument("--threads", type=int, default=0, help="torch threads per job (0: cores / jobs)")
    ap.add_argument("--views", default="2,13", help="views shown in the figures")
    ap.add_argument("--crop", default="240,180,480,360", help="x0,y0,x1,y1 of the 2x crop row (first view)")
    ap.add_argument("--force", action="store_true", help="redo the stylization runs")
    ap.add_argument("--core-only", action="store_true",
                    help="only FAST and NNFM per painting (no ablation runs, no reference rows): for probing a setting")
    ap.add_argument("--plan", action="store_true", help="list the runs (cached or to run) and their folders; run nothing")
    ap.add_argument("--fit-iterations", type=int, default=FIT_SETTINGS["iterations"],
                    help="fit steps when the scene has no fit in --bench-root yet")
    args = ap.parse_args(argv)

    threads = args.threads or max(1, (os.cpu_count() or 1) // max(1, args.jobs))
    styles = [s.strip() for s in args.styles.split(",") if s.strip()]
    if args.ablation_style not in styles:
        raise InputError(f"--ablation-style {args.ablation_style!r} must be one of --styles ({', '.join(styles)})")
    style_paths = {s: (args.style_dir / f"{s}.jpg").resolve() for s in styles}
    for s, p in style_paths.items():
        if not p.is_file():
            raise InputError(f"painting {s!r}: {p} does not exist (give --style-dir and names of its .jpg files)")
    cfg = yaml.safe_load(args.params.read_text()) if args.params else {}
    cfg = {k: cfg.get(k, {}) for k in ("stylize", "colormatch", "evaluate", "vgg")}
    for item in args.set:
        key, _, val = item.partition("=")
        set_dotted(cfg, key, yaml.safe_load(val))
    # validate once, up front (typos fail before any work); cache keys use the validated sections, defaults included
    valid = {"stylize": _semantic(StylizeParams(**cfg["stylize"]).model_dump()),
             "colormatch": _semantic(ColorMatchParams(**cfg["colormatch"]).model_dump()),
             "evaluate": _semantic(EvalParams(**cfg["evaluate"]).model_dump()), "vgg": VggWeightsParams(**cfg["vgg"]).model_dump()}

    work = args.work or Path("out/quality") / args.scene.name
    work.mkdir(parents=True, exist_ok=True)
    colmap, ply, scene_info = ensure_scene(args.scene, args.bench_root, threads * max(1, args.jobs), args.fit_iterations)

    specs = [RunSpec(s, m) for s in styles for m in ("fast", "nnfm")]
    if not args.core_only:
        specs += [RunSpec(args.ablation_style, "fast", "authors"), RunSpec(args.ablation_style, "knnfm"),
                  RunSpec(args.ablation_style, "gram")]
        specs += [RunSpec(s, "colormatch") for s in styles] + [RunSpec(args.ablation_style, "original")]
    specs.sort(key=lambda s: (styles.index(s.style), s.method in REFERENCE_METHODS, s.method != "fast",
                              s.variant != "default", s.method))

    base = {"threads": threads, "colmap": str(colmap), "ply": str(ply), "vgg": cfg["vgg"]}
    cm_jobs, cm_path = [], {}
    for s in styles:
        key = _digest([STUDY_VERSION, scene_info["ply_sha"], _file_sha(style_paths[s]), valid["colormatch"],
                       valid["stylize"]["style_height"], valid["vgg"]])
        cm_path[s] = work / "colormatch" / f"{s}-{key}.ply"
        cm_jobs.append({**base, "style_path": str(style_paths[s]), "out": str(cm_path[s]),
                        "colormatch": cfg["colormatch"], "stylize": cfg["stylize"]})
    run_jobs, run_dirs = [], {}
    for spec in specs:
        sp = deep_merge(cfg["stylize"], VARIANTS[spec.variant])
        key = _digest([STUDY_VERSION, scene_info["ply_sha"], _file_sha(style_paths[spec.style]), valid["colormatch"],
                       _semantic(StylizeParams(**sp).model_dump()), valid["evaluate"], valid["vgg"], spec.method])
        run_dirs[spec.name] = work / "runs" / f"{spec.name}-{key}"
        if args.force and (run_dirs[spec.name] / "run.json").is_file():
            (run_dirs[spec.name] / "run.json").unlink()
        run_jobs.append({**base, "name": spec.name, "style": spec.style, "method": spec.method, "variant": spec.variant,
                         "key": key, "style_path": str(style_paths[spec.style]), "colormatch_ply": str(cm_path[spec.style]),
                         "run_dir": str(run_dirs[spec.name]), "stylize": sp, "evaluate": cfg["evaluate"]})

    model_paths = {spec.name: (cm_path[spec.style] if spec.method == "colormatch" else ply if spec.method == "original"
                               else run_dirs[spec.name] / "point_cloud.ply") for spec in specs}
    model_paths.update({RunSpec(s, "colormatch").name: cm_path[s] for s in styles})  # the overview's start column
    todo = [j for j in run_jobs if not (Path(j["run_dir"]) / "run.json").is_file()]
    print(f"[study] {len(specs)} runs ({len(specs) - len(todo)} cached), {len(styles)} paintings, "
          f"{args.jobs} job(s) × {threads} thread(s); work dir {work}", flush=True)
    if args.plan:
        for j in cm_jobs:
            print(f"  colour match {'cached' if Path(j['out']).is_file() else 'to run'}: {j['out']}")
        for j in run_jobs:
            print(f"  {j['name']:40s} {'cached' if j not in todo else 'to run'}: {j['run_dir']}")
        return {"colormatch": [j["out"] for j in cm_jobs], "runs": {j["name"]: j["run_dir"] for j in run_jobs},
                "todo": [j["name"] for j in todo]}
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        for r in pool.map(colormatch_job, cm_jobs):
            how = "cached" if r["cached"] else "{:.0f} s".format(r["seconds"])
            print(f"[study] colour match ({how}): {r['path']}", flush=True)
        results = []
        for r in pool.map(run_job, run_jobs):
            results.append(r)
            m = r["metrics"]
            print(f"[study] {r['name']}: SSIM {m['ssim']:.3f}, Gram {m['gram_distance']:.3f}, KID {m['kid_tf_inception']:.4f}, "
                  f"short/long RMSE {m['short_rmse']:.4f}/{m['long_rmse']:.4f}, {r['stylize_seconds'] / 60:.1f} min", flush=True)
    md, csv = table(results, specs)
    checks = acceptance(results, styles)
    views = tuple(int(v) for v in args.views.split(","))
    crop = tuple(int(v) for v in args.crop.split(","))
    cameras = read_colmap_scene(colmap / "sparse", colmap / "images").cameras
    for s in styles:
        save_image(work / f"figure_{s}.png", figure(specs, s, str(style_paths[s]), cameras, ply, model_paths, views, crop))
    save_image(work / "figure_overview.png", overview_figure(styles, style_paths, cameras, ply, model_paths, views[0]))
    first = results[0]
    header = (f"# Quality study: {args.scene.name} × {', '.join(styles)}\n\n"
              f"Schedule: {first['stylize_params']['iterations']} stylization steps + "
              f"{first['stylize_params']['color_pass_iterations']} colour-pass steps, seed {first['stylize_params']['seed']}; "
              f"{first['n_gaussians']} Gaussians; {first['machine']['cpus']} CPUs, {threads} torch thread(s) per run, "
              f"{args.jobs} run(s) at a time; VGG weights: {first['vgg_weights']['source']}.\n\n")
    write_text(work / "table.md", header + md + "\n" + "\n".join(f"- {c}" for c in checks) + "\n")
    write_text(work / "table.csv", csv)
    summary = {"scene": str(args.scene), "scene_fit": scene_info, "styles": {s: str(p) for s, p in style_paths.items()},
               "config": cfg, "runs": results, "acceptance": checks, "wall_seconds_this_call": time.perf_counter() - t0}
    write_json(work / "study.json", summary)
    print("\n" + header + md)
    print("\n".join(checks))
    return summary


if __name__ == "__main__":
    main()
