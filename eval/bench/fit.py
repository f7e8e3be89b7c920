"""Benchmark the baseline 3DGS fit on a real scene: held-out PSNR against training wall time.

    python -m eval run fit --scene ../shared/data/scenes/fern --json out/bench/fit_fern.json
    python -m eval run fit --scene ../shared/data/scenes/fern --format llff   # LLFF's poses, no SfM

Reconstructs the scene with pycolmap (``--format photos``, the default) or writes the dataset's own cameras
(``--format llff``, ``colmap``, …, ``auto``: :mod:`abcgs.sources`; points triangulated from the given poses), cached
in ``--work``, then fits with the given budget, evaluates the
held-out views (every 8th, LLFF convention) every ``--eval-every`` steps, and prints the PSNR-vs-time
table; ``--json`` also writes it, and a PNG curve is written next to it. Wall time counts training
steps only (evaluation excluded), on whatever machine runs it — the table header says which.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import torch

from abcgs.fit.params import FitParams, StrategyParams
from abcgs.fit.training import fit
from abcgs.gaussians.ply import write_ply
from abcgs.layout import ColmapDir
from abcgs.runtime import resolve_device
from abcgs.sfm.model import read_scene
from abcgs.sfm.params import ReconstructParams
from abcgs.sources.read import resolve_format
from abcgs.sources.registry import formats, reader_of
from eval.record import bench_parser, write_record


def main(argv=None) -> dict:
    ap = bench_parser(__doc__)
    ap.add_argument("--scene", type=Path, required=True, help="folder with images/ (or a dataset with cameras)")
    ap.add_argument("--format", default="photos", choices=("auto", *formats()),
                    help="where the cameras come from (photos: structure from motion)")
    ap.add_argument("--work", type=Path, default=Path("out/bench"), help="where the reconstruction is cached")
    ap.add_argument("--iterations", type=int, default=3000)
    ap.add_argument("--eval-every", type=int, default=250)
    ap.add_argument("--max-gaussians", type=int, default=200_000)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0 = all cores)")
    ap.add_argument("--device", default="auto", help="runtime.device: auto, cpu, cuda, cuda:N")
    ap.add_argument("--sh-degree", type=int, default=0, help="fit.sh_degree")
    ap.add_argument("--seed", type=int, default=0, help="fit.seed: the fit's random draws (another seed, another fit)")
    ap.add_argument("--test-every", type=int, default=8, help="fit.test_every (0: train on every view, no held-out PSNR)")
    ap.add_argument("--refine-every", type=int, default=100)
    ap.add_argument("--refine-stop-fraction", type=float, default=0.6, help="densify until this fraction of the steps")
    ap.add_argument("--reset-every", type=int, default=1500)
    ap.add_argument("--reconstruct", default="{}",
                    help="reconstruct params as JSON (abcgs.sfm.params.ReconstructParams), e.g. "
                         "'{\"matcher\": \"sequential\"}'; the reconstruction is cached in --work: use a new one")
    args = ap.parse_args(argv)
    reconstruct_params = ReconstructParams.model_validate_json(args.reconstruct)

    fmt = resolve_format(args.scene, args.format)
    sfm = reader_of(fmt).cameras == "sfm"  # photos: cameras found by structure from motion
    run = args.scene.name if sfm else f"{args.scene.name}-{fmt}"
    colmap = args.work / run / "colmap"
    if not ColmapDir(colmap).scene.is_file():
        from abcgs.sources.params import SceneParams
        from abcgs.sources.reconstruct import reconstruct_scene  # pycolmap: only where a layout is written

        reconstruct_scene(SceneParams.at(args.scene, fmt), colmap, reconstruct_params)
    scene = read_scene(colmap)
    params = FitParams(
        iterations=args.iterations, eval_every=args.eval_every, max_gaussians=args.max_gaussians,
        threads=args.threads, sh_degree=args.sh_degree, test_every=args.test_every, seed=args.seed,
        strategy=StrategyParams(
            refine_start=min(500, args.iterations // 10), refine_every=args.refine_every,
            refine_stop=int(args.refine_stop_fraction * args.iterations), reset_every=args.reset_every,
        ),
    )
    device = resolve_device(args.device)
    result = fit(scene, params, progress=True, device=device)
    write_ply(args.work / run / "gs" / "point_cloud.ply", result.model)
    cam = scene.cameras[0]
    print(f"\n# {args.scene.name} ({fmt}): {len(scene.cameras)} views at {cam.width}x{cam.height}, "
          f"{len(result.views.test)} held out; {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"{torch.get_num_threads() if args.threads == 0 else args.threads} torch threads, backend {result.backend}")
    print(f"{'step':>6} {'train s':>8} {'PSNR dB':>8} {'SSIM':>6}")
    for row in result.eval_history:
        print(f"{row['step']:>6} {row['seconds']:8.1f} {row['psnr']:8.2f} {row['ssim']:6.3f}")
    out = {"scene": str(args.scene), "format": fmt, "points": int(len(scene.points)), "width": cam.width,
           "height": cam.height, "params": params.model_dump(), "reconstruct": reconstruct_params.model_dump(),
           "n_gaussians": result.model.num_gaussians, "curve": result.eval_history, "backend": result.backend,
           "device": str(device),
           "gpu": torch.cuda.get_device_name() if torch.cuda.is_available() else None}
    if args.json:
        write_record(args.json, out, argv)
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5, 3.2), dpi=120)
        ax.plot([r["seconds"] / 60 for r in result.eval_history], [r["psnr"] for r in result.eval_history], "o-")
        ax.set_xlabel("training wall time (min)")
        ax.set_ylabel("held-out PSNR (dB)")
        ax.set_title(f"3DGS fit on {args.scene.name} ({fmt}), {cam.width}x{cam.height}")
        ax.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(args.json.with_suffix(".png"))
    return out


if __name__ == "__main__":
    main()
