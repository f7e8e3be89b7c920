"""Where a 3DGS fit step's time goes: render, loss, loss backward, render backward, Adam.

    python -m eval run fit_step --scene ../shared/data/scenes/fern            # after eval/bench/fit.py
    python -m eval run fit_step --scene ../shared/data/scenes/fern --loss torch   # the torch-op loss

Loads the scene's reconstruction and a fitted model (``--ply``; default: what ``eval/bench/fit.py`` wrote under
``--work``), then runs ``--steps`` fit steps over the training views (after ``--warmup`` steps) with the fit's
thread setting (torch at ``--threads`` threads, the C++ kernels at ``--kernel-threads``) and prints the mean
milliseconds of each phase per step. ``--loss fused|torch`` picks the L1 + SSIM implementation
(``abcgs.fit.losses.l1_ssim``), so both can be compared in one process. ``--json`` writes the table.
The model is optimised as in a fit (Adam with the 3DGS learning rates; the means' rate is not scaled by the scene
extent), so later steps see slightly different parameters; densification is off (this times a step, not a schedule).
"""

from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import torch

from abcgs.fit.data import load_views
from abcgs.fit.losses import reconstruction_loss
from abcgs.fit.params import FitParams
from abcgs.fit.training import make_optimizers
from abcgs.gaussians import render
from abcgs.gaussians.ply import read_ply
from abcgs.layout import ColmapDir
from abcgs.render import select_backend
from abcgs.render.cpu import kernel_threads
from abcgs.sfm.model import read_scene
from eval.record import bench_parser, write_record

PHASES = ("render", "loss", "loss_backward", "render_backward", "adam")


def main(argv=None) -> dict:
    ap = bench_parser(__doc__)
    ap.add_argument("--scene", type=Path, required=True, help="scene folder (its name keys the --work cache)")
    ap.add_argument("--work", type=Path, default=Path("out/bench"), help="where eval/bench/fit.py cached it")
    ap.add_argument("--ply", type=Path, default=None, help="fitted model (default: WORK/SCENE/gs/point_cloud.ply)")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1, help="torch threads (the fit's default: 1)")
    ap.add_argument("--kernel-threads", type=int, default=0, help="C++ kernel threads (0 = every core)")
    ap.add_argument("--loss", choices=("fused", "torch"), default="fused")
    args = ap.parse_args(argv)

    base = args.work / args.scene.name
    colmap = base / "colmap"
    ply = args.ply or base / "gs" / "point_cloud.ply"
    for path, what in ((ColmapDir(colmap).scene, "reconstruction"), (ply, "fitted model")):
        if not path.exists():
            sys.exit(f"bench_fit_step: no {what} at {path}; run eval/bench/fit.py --scene {args.scene} first")
    torch.set_num_threads(args.threads)
    scene = read_scene(colmap)
    params = FitParams()
    views = load_views(scene, params.resolution_scale, params.test_every, "cpu")
    model = read_ply(ply).as_parameters()
    optimizers = make_optimizers(model, params, 1.0)
    backend = select_backend(torch.device("cpu"), "auto")
    fused = args.loss == "fused"
    gen = torch.Generator().manual_seed(0)
    totals = dict.fromkeys(PHASES, 0.0)

    def step(i: int, record: bool) -> None:
        idx = views.train[i % len(views.train)]
        t = [time.perf_counter()]
        image, _, _ = render(model, views.cameras[idx], backend=backend, sh_degree=model.sh_degree,
                             background=torch.rand(3, generator=gen))
        t.append(time.perf_counter())
        terms = reconstruction_loss(image, views.images[idx], params.ssim_lambda, fused=fused)
        t.append(time.perf_counter())
        (v_image,) = torch.autograd.grad(terms.total, image, retain_graph=True)
        t.append(time.perf_counter())
        image.backward(v_image)
        t.append(time.perf_counter())
        for opt in optimizers.values():
            opt.step()
            opt.zero_grad(set_to_none=True)
        t.append(time.perf_counter())
        if record:
            for name, a, b in zip(PHASES, t, t[1:]):
                totals[name] += b - a

    with kernel_threads(args.kernel_threads):
        for i in range(args.warmup):
            step(i, False)
        for i in range(args.steps):
            step(args.warmup + i, True)
    per_step = {name: 1000.0 * v / args.steps for name, v in totals.items()}
    total = sum(per_step.values())
    cam = views.cameras[views.train[0]]
    print(f"# {args.scene.name}: {model.num_gaussians} Gaussians, {cam.width}x{cam.height}; "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; torch {args.threads} thread(s), "
          f"kernels {args.kernel_threads or os.cpu_count()}; loss {args.loss}; mean of {args.steps} steps")
    print(f"{'phase':<16} {'ms/step':>8} {'share':>6}")
    for name, ms in per_step.items():
        print(f"{name:<16} {ms:8.1f} {ms / total:6.1%}")
    print(f"{'step':<16} {total:8.1f}")
    out = {"scene": str(args.scene), "n_gaussians": model.num_gaussians, "width": cam.width, "height": cam.height,
           "loss": args.loss, "threads": args.threads, "kernel_threads": args.kernel_threads, "steps": args.steps,
           "ms_per_step": per_step, "step_ms": total}
    if args.json:
        write_record(args.json, out, argv)
    return out


if __name__ == "__main__":
    main()
