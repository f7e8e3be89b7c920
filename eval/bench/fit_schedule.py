"""The fit's default schedule at any length: held-out PSNR, Gaussians and reset opacities of the pipeline's own ``fit``
section at several ``fit.iterations``, nothing else changed.

    python -m eval run fit_schedule --json docs/measurements/fit_schedule.json
    python -m eval run fit_schedule --iterations 1000 1500 --scenes tiny      # a quick look
    python -m eval run fit_schedule --iterations 1000 --scenes tiny \
        --variant '{"strategy": {"refine_every": 50}}' --variant '{"seed": 1}'     # other fit settings, one run each

Scenes, both generated here (no data needed): ``tiny``, the embedded default (a wall and objects seen from a
forward-facing grid), and ``object``, its objects on nothing seen from three rings (a NeRF-synthetic dataset, white
background). Each goes through the reconstruct stage's code (structure from motion for the tiny scene's photos; for
the object, the dataset's cameras with points triangulated from them, and where too few triangulate, as on this
object's small smooth renders, random points in the cameras' frustums, as that stage does) and is fitted with
``params.yaml``'s ``fit`` section at each length, as the fit stage does, and judged by the fit stage's plausibility
check (:mod:`abcgs.fit.plausibility`). The table shows, per scene and length: the held-out and training PSNR (dB),
the schedule the length resolves to, the share of Gaussians whose opacity is still at the reset value, and the
training minutes.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
from abcgs.fit.params import FitParams
from abcgs.fit.plausibility import check_fit
from abcgs.fit.training import fit
from abcgs.layout import ColmapDir
from abcgs.params import load_params
from abcgs.scene.synthetic import make_tiny_scene, write_object_dataset
from abcgs.sfm.colmap import set_colmap_log_level
from abcgs.sfm.model import read_scene
from abcgs.sources.reconstruct import reconstruct_scene
from abcgs.types import CalibratedScene
from eval.record import bench_parser, write_record

ROOT = Path(__file__).resolve().parents[2]
SCENES = {"tiny": make_tiny_scene, "object": write_object_dataset}


def prepare(name: str, work: Path) -> CalibratedScene:
    """Generate scene ``name`` in ``work``, write its COLMAP layout as the reconstruct stage does and read it back."""
    folder, colmap = work / name, ColmapDir(work / f"{name}_colmap")
    if not colmap.scene.is_file():
        SCENES[name](folder)
        set_colmap_log_level("warning")
        reconstruct_scene(folder, colmap.root, load_params(ROOT / "params.yaml").reconstruct)
    return read_scene(colmap.root)


def run(name: str, iterations: int, work: Path, variant: dict | None = None) -> dict:
    """Fit scene ``name`` for ``iterations`` steps with params.yaml's ``fit`` section, its keys replaced by
    ``variant``'s (e.g. ``{"strategy": {...}}``, ``{"seed": 1}``), and judge it as the fit stage does."""
    scene = prepare(name, work)
    background = scene.background
    base = load_params(ROOT / "params.yaml").fit
    update = {"iterations": iterations, **(variant or {})}
    if background.object:
        update["background"] = background.color
    params = FitParams.model_validate({**base.model_dump(), **update})
    result = fit(scene, params, progress=False)
    check = check_fit(result)
    s = params.strategy_params()
    return {"scene": name, "iterations": iterations, "variant": variant, "heldout_psnr": check.heldout_psnr,
            "train_psnr": check.train_psnr, "reset_share": check.reset_share, "plausible": not check.problems,
            "n_gaussians": result.model.num_gaussians, "minutes": result.seconds / 60,
            "schedule": {k: getattr(s, k) for k in ("refine_start", "refine_every", "refine_stop", "reset_every")},
            "last_reset": s.last_reset(iterations)}


def main(argv=None) -> list[dict]:
    ap = bench_parser(__doc__)
    ap.add_argument("--scenes", nargs="+", choices=tuple(SCENES), default=list(SCENES))
    ap.add_argument("--iterations", nargs="+", type=int, default=[1000, 1500, 3000, 6000])
    ap.add_argument("--work", type=Path, default=None, help="where the scenes are generated (default: a temporary folder)")
    ap.add_argument("--variant", type=json.loads, action="append", default=None,
                    help="fit keys as JSON replacing params.yaml's, one run each (repeatable), e.g. the fixed 3DGS "
                         "steps: '{\"strategy\": {\"refine_start\": 500, \"refine_every\": 100, "
                         "\"refine_stop\": 15000, \"reset_every\": 3000}}'")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="abcgs-fit-schedule-") as tmp:
        work = args.work or Path(tmp)
        print(f"{'scene':>7} {'steps':>6} {'held-out dB':>11} {'train dB':>8} {'start/every/stop/reset':>22} "
              f"{'last reset':>10} {'at reset':>8} {'Gaussians':>9} {'min':>5}", flush=True)
        for name in args.scenes:
            for n in args.iterations:
                for variant in args.variant or [None]:
                    r = run(name, n, work, variant)
                    s = r["schedule"]
                    sched = f"{s['refine_start']}/{s['refine_every']}/{s['refine_stop']}/{s['reset_every']}"
                    print(f"{name:>7} {n:>6} {r['heldout_psnr']:>11.2f} {r['train_psnr']:>8.2f} {sched:>22} "
                          f"{r['last_reset'] or '-':>10} {r['reset_share']:>8.1%} {r['n_gaussians']:>9} "
                          f"{r['minutes']:>5.1f}" + (f"  {json.dumps(variant)}" if variant else ""), flush=True)
                    rows.append(r)
    if args.json:
        write_record(args.json, {"variants": args.variant, "rows": rows}, argv)
    return rows


if __name__ == "__main__":
    main()
