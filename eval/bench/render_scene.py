"""Render forward and forward + backward of a fitted scene on its own training views.

    python -m eval run render_scene --work out/bench/fern          # after eval/bench/fit.py --scene .../fern

How it measures: the model ``<work>/gs/point_cloud.ply`` and the cameras of ``<work>/colmap``; for each of
``--views`` views, ``--repeats`` timed calls after a warm-up (``eval.bench.timing.repeat_seconds``) of a no-grad render
(forward), then of a render with every parameter requiring a gradient and the backward of a fixed weighted sum of
its pixels (forward + backward). The medians over all views and calls are printed, in ms, with the thread count
and load. The EWA projection's kernels (``project_forward`` / ``project_backward`` of the C++ extension, called
directly with fixed random output gradients) are timed the same way and printed on a second line. Whether torch's OpenMP
workers wait passively (``OMP_WAIT_POLICY``, see ``abcgs/__init__.py``) is printed too: run it with
``OMP_WAIT_POLICY=ACTIVE`` or with abcgs imported after torch to compare (docs/SCALING.md "Idle OpenMP workers").
"""

from __future__ import annotations

import argparse
import os
import statistics
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import torch

from abcgs.gaussians import render
from abcgs.gaussians.ply import read_ply
from abcgs.render.cpu import load_extension
from abcgs.sfm.model import read_scene
from eval.bench.timing import repeat_seconds


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, default=Path("out/bench/fern"), help="bench_fit's folder of one scene")
    ap.add_argument("--views", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=3, help="timed calls per view, after one warm-up call")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0 = all cores)")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error("--repeats must be at least 1")
    if args.threads:
        torch.set_num_threads(args.threads)
    scene = read_scene(args.work / "colmap")
    model = read_ply(args.work / "gs" / "point_cloud.ply").map(lambda t: t.detach().requires_grad_(True))
    cams = scene.cameras[: args.views]
    forward, both = [], []
    for cam in cams:
        shape = render(model, cam)[0].shape
        weights = torch.linspace(0, 1, shape.numel()).reshape(shape)

        def forward_only(cam=cam):
            with torch.no_grad():
                render(model, cam)

        def forward_backward(cam=cam, weights=weights):
            (render(model, cam)[0] * weights).sum().backward()

        forward += repeat_seconds(forward_only, args.repeats)
        both += repeat_seconds(forward_backward, args.repeats)
    proj_f, proj_b = projection_kernel_seconds(model, cams, args.repeats)
    out = {
        "projection_forward_ms": 1e3 * statistics.median(proj_f), "projection_backward_ms": 1e3 * statistics.median(proj_b),
        "gaussians": int(model.means.shape[0]), "size": [cams[0].width, cams[0].height], "views": len(cams),
        "forward_ms": 1e3 * statistics.median(forward), "forward_backward_ms": 1e3 * statistics.median(both),
        "torch_threads": torch.get_num_threads(), "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", "<libgomp default>"),
        "load": os.getloadavg()[0],
    }
    print(f"{out['gaussians']} Gaussians, {out['size'][0]}x{out['size'][1]}, {len(cams)} views x {args.repeats} calls "
          f"(each after a warm-up call): forward {out['forward_ms']:.1f} ms, forward + backward "
          f"{out['forward_backward_ms']:.1f} ms (medians; {out['torch_threads']} torch threads, "
          f"OMP_WAIT_POLICY {out['omp_wait_policy']}, load {out['load']:.2f})")
    print(f"projection kernels (medians, kernel threads {load_extension().kernel_threads()}): forward "
          f"{out['projection_forward_ms']:.2f} ms, backward {out['projection_backward_ms']:.2f} ms")
    return out


def projection_kernel_seconds(model, cams, repeats: int) -> tuple[list[float], list[float]]:
    """Seconds of the C++ projection's forward and backward calls on each view (after a warm-up call each)."""
    ext = load_extension()
    means, quats, scales = (t.detach().contiguous() for t in (model.means, model.quats, model.scales))
    opac = model.opacities.detach().contiguous()
    gen = torch.Generator().manual_seed(0)
    n = means.shape[0]
    grads = [torch.randn(n, 2, generator=gen), torch.randn(n, 3, generator=gen), torch.randn(n, generator=gen)]
    fwd, bwd = [], []
    for cam in cams:
        vm = torch.as_tensor(cam.viewmat, dtype=torch.float32)
        K = torch.as_tensor(cam.K, dtype=torch.float32)
        args = (cam.width, cam.height, 0.01, 1e10, 0.3)
        fwd += repeat_seconds(lambda vm=vm, K=K, args=args: ext.project_forward(means, quats, scales, opac, vm, K, *args),
                              repeats)
        bwd += repeat_seconds(lambda vm=vm, K=K, args=args: ext.project_backward(means, quats, scales, vm, K, *args, *grads),
                              repeats)
    return fwd, bwd


if __name__ == "__main__":
    main()
