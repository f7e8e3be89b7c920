"""Check the CPU kernels against the reference backend on a splat of real size: sampled pixels and Gaussians.

    python -m eval run large_splat_match --n 3000000 --json docs/measurements/large_splat_match_3m.json

The scene is :func:`eval.bench.large_splat.synthesize` (``--n`` Gaussians of SH degree 3), seen by one of its cameras
at ``--width`` × ``--height``. The reference backend (pure torch, the tests' oracle) would take hours on the whole
view, so both backends render a ``--window``-pixel square of it (the same camera with its principal point moved:
all ``--n`` Gaussians go through both, the window's pixels are those of the full view) with the main pass's render
mode (RGB + depth) and take the gradient of one random linear function of image, alpha and depth. The record holds
the largest differences of image, alpha and depth over the window's pixels, and of every parameter's gradient over
``--gaussians`` sampled Gaussians among those the window sees, each beside the largest value of its kind (the scale
of the difference); and the largest difference between the window and the same pixels of the CPU backend's render
of the full view. Prints a table and, with ``--json``, writes the record.
"""

from __future__ import annotations

import os
import time
from dataclasses import replace

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import torch

from abcgs.gaussians import render
from eval.bench.large_splat import cameras, synthesize
from eval.record import bench_parser, write_record

FIELDS = ("means", "quats", "log_scales", "opacity_logits", "sh0", "shN")


def run_backend(model, cam, backend: str, weights: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    m = model.as_parameters()
    t = time.perf_counter()
    img, alpha, meta = render(m, cam, backend=backend, render_mode="RGB+D")
    loss = (img * weights["image"]).sum() + (alpha * weights["alpha"]).sum() + (meta.depth * weights["depth"]).sum()
    grads = torch.autograd.grad(loss, [getattr(m, f) for f in FIELDS])
    out = {"image": img.detach(), "alpha": alpha.detach(), "depth": meta.depth.detach(), "visible": meta.visible,
           "seconds": torch.tensor(time.perf_counter() - t)}
    return out | {f"grad_{f}": g for f, g in zip(FIELDS, grads)}


def main(argv=None) -> dict:
    ap = bench_parser(__doc__)
    ap.add_argument("--n", type=int, default=3_000_000)
    ap.add_argument("--width", type=int, default=504)
    ap.add_argument("--height", type=int, default=378)
    ap.add_argument("--window", type=int, default=64, help="side of the square window both backends render (px)")
    ap.add_argument("--gaussians", type=int, default=20_000)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    model = synthesize(args.n)
    full = cameras(4, args.width, args.height)[1]
    x0, y0 = (args.width - args.window) // 2, (args.height - args.window) // 2
    K = full.K.copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    cam = replace(full, K=K, width=args.window, height=args.window)
    g = torch.Generator().manual_seed(0)
    hw = (args.window, args.window)
    weights = {"image": torch.rand(*hw, 3, generator=g), "alpha": torch.rand(*hw, 1, generator=g),
               "depth": torch.rand(*hw, 1, generator=g) * 0.1}
    res = {b: run_backend(model, cam, b, weights) for b in ("cpu", "reference")}
    with torch.no_grad():
        whole = render(model, full, backend="cpu")[0][y0:y0 + args.window, x0:x0 + args.window]
    seen = torch.nonzero(res["cpu"]["visible"] & res["reference"]["visible"]).squeeze(1)
    gauss = seen[torch.randperm(seen.numel(), generator=g)[: args.gaussians]]
    rec: dict = {"n_gaussians": args.n, "width": args.width, "height": args.height, "window": [x0, y0, args.window],
                 "visible_in_window": int(seen.numel()),
                 "sampled_gaussians": int(gauss.numel()), "load_average": os.getloadavg(),
                 "seconds": {b: float(r["seconds"]) for b, r in res.items()}, "max_abs_diff": {}, "max_abs": {},
                 "window_vs_full_view": float((whole - res["cpu"]["image"]).abs().max())}
    for key in ("image", "alpha", "depth"):
        a, b = res["cpu"][key], res["reference"][key]
        rec["max_abs_diff"][key], rec["max_abs"][key] = float((a - b).abs().max()), float(b.abs().max())
    for f in FIELDS:
        a, b = (res[k][f"grad_{f}"][gauss] for k in ("cpu", "reference"))
        rec["max_abs_diff"][f"grad_{f}"], rec["max_abs"][f"grad_{f}"] = float((a - b).abs().max()), float(b.abs().max())
    for key, diff in rec["max_abs_diff"].items():
        print(f"{key:>22}: max |cpu - reference| {diff:.3g}   (largest |reference| {rec['max_abs'][key]:.3g})")
    print(f"window vs the full view's pixels: {rec['window_vs_full_view']:.3g}")
    print(f"seconds: {rec['seconds']}   load {rec['load_average'][0]:.1f}")
    if args.json:
        write_record(args.json, rec, argv)
    return rec


if __name__ == "__main__":
    main()
