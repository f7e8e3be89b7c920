"""Benchmark the rasterizer backends on random scenes with realistic screen-space sizes.

Runs, in one process, the ``reference`` (pure PyTorch) and the ``cpu`` (compiled) backends on the same
scenes, forward and forward+backward, RGB and 16 channels, and prints a table; ``--json PATH`` writes
the rows. Each timing is the median of ``--repeats`` runs after one warm-up run; the peak resident
memory of each case is sampled every 2 ms from /proc/self/statm while the fast backend runs.

    python -m eval run rasterizer --json out/bench/rasterizer.json

Scenes: N Gaussians uniformly in the camera frustum at depth 2–8 world units, random rotations,
per-axis screen-space standard deviations log-normal around 1.5 px (σ_log = 0.8, so ~95% between
0.3 and 7 px, like a fitted 3DGS scene), opacities sigmoid(N(0, 1.5)).
"""

from __future__ import annotations

import os
import platform
import statistics
import threading
import time
from dataclasses import dataclass

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split

import torch

from abcgs.render import rasterize
from eval.record import bench_parser, write_record

CASES = [(20_000, 128, 128), (100_000, 256, 256), (300_000, 512, 384)]


def random_scene(n: int, width: int, height: int, channels: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    focal = 0.8 * width
    z = 2.0 + 6.0 * torch.rand(n, generator=g)
    u = (torch.rand(n, generator=g) * 1.1 - 0.05) * width
    v = (torch.rand(n, generator=g) * 1.1 - 0.05) * height
    means = torch.stack([(u - width / 2) * z / focal, (v - height / 2) * z / focal, z], -1)
    px_sigma = torch.exp(torch.randn(n, 3, generator=g) * 0.8 + 0.4)  # median ≈ 1.5 px
    scales = px_sigma * z[:, None] / focal
    quats = torch.randn(n, 4, generator=g)
    opacities = torch.sigmoid(torch.randn(n, generator=g) * 1.5)
    colors = torch.rand(n, channels, generator=g)
    viewmat = torch.eye(4)
    K = torch.tensor([[focal, 0, width / 2], [0, focal, height / 2], [0, 0, 1.0]])
    return means, quats, scales, opacities, colors, viewmat, K


class PeakRSS:
    """Samples the process's resident set size in a background thread."""

    def __init__(self, interval: float = 0.002):
        self.interval, self.peak, self._stop = interval, 0, threading.Event()
        self._page = os.sysconf("SC_PAGE_SIZE")

    def _rss(self) -> int:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * self._page

    def __enter__(self):
        self.peak = self._rss()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, self._rss())
            time.sleep(self.interval)

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self._rss())


def time_backend(scene, width, height, backend: str, backward: bool, repeats: int) -> float:
    means, quats, scales, opacities, colors, viewmat, K = scene
    times = []
    for i in range(repeats + 1):
        params = [t.clone().requires_grad_(backward) for t in (means, quats, scales, opacities, colors)]
        t0 = time.perf_counter()
        img, alpha, _ = rasterize(*params, viewmat, K, width, height, backend=backend)
        if backward:
            (img.sum() + alpha.sum()).backward()
        if i > 0:
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


@dataclass
class Row:
    n: int
    width: int
    height: int
    channels: int
    reference_fwd_s: float
    fast_fwd_s: float
    reference_fwd_bwd_s: float
    fast_fwd_bwd_s: float
    speedup_fwd: float
    speedup: float
    peak_rss_mb: float


def main(argv: list[str] | None = None) -> list[Row]:
    ap = bench_parser(__doc__)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--reference-repeats", type=int, default=1)
    ap.add_argument("--channels", type=int, nargs="+", default=[3, 16])
    ap.add_argument("--cases", default="all", help="'all' or comma list of indices into the case list")
    ap.add_argument("--skip-reference", action="store_true", help="time only the fast backend")
    ap.add_argument("--kernel-threads", type=int, default=0,
                    help="threads of the compiled kernels' own loops (0 = every core; csrc/parallel.h)")
    ap.add_argument("--torch-threads", type=int, default=0, help="torch intra-op threads (0 = torch's default)")
    args = ap.parse_args(argv)
    from abcgs.render.cpu import set_kernel_threads

    set_kernel_threads(args.kernel_threads)
    if args.torch_threads:
        torch.set_num_threads(args.torch_threads)
    cases = CASES if args.cases == "all" else [CASES[int(i)] for i in args.cases.split(",")]
    torch.set_grad_enabled(True)
    print(
        f"# torch {torch.__version__}, {torch.get_num_threads()} torch threads, kernel threads "
        f"{args.kernel_threads or 'all'}, {platform.processor() or platform.machine()}, load {os.getloadavg()[0]:.2f}, "
        f"{os.cpu_count()} CPUs; median of {args.repeats} (fast) / {args.reference_repeats} (reference) after a warm-up",
        flush=True,
    )
    header = f"{'N':>8} {'W×H':>9} {'C':>3} | {'ref fwd':>8} {'fast fwd':>8} {'×':>6} | {'ref f+b':>8} {'fast f+b':>8} {'×':>6} | {'peak MB':>8}"
    print(header)
    print("-" * len(header), flush=True)
    rows = []
    for n, w, h in cases:
        for c in args.channels:
            scene = random_scene(n, w, h, c)
            with PeakRSS() as mem:
                fast_f = time_backend(scene, w, h, "cpu", False, args.repeats)
                fast_fb = time_backend(scene, w, h, "cpu", True, args.repeats)
            if args.skip_reference:
                ref_f = ref_fb = float("nan")
            else:
                ref_f = time_backend(scene, w, h, "reference", False, args.reference_repeats)
                ref_fb = time_backend(scene, w, h, "reference", True, args.reference_repeats)
            row = Row(n, w, h, c, ref_f, fast_f, ref_fb, fast_fb, ref_f / fast_f, ref_fb / fast_fb, mem.peak / 2**20)
            rows.append(row)
            print(
                f"{n:>8} {f'{w}×{h}':>9} {c:>3} | {ref_f:8.3f} {fast_f:8.3f} {row.speedup_fwd:6.1f} | "
                f"{ref_fb:8.3f} {fast_fb:8.3f} {row.speedup:6.1f} | {row.peak_rss_mb:8.0f}",
                flush=True,
            )
    if args.json:
        write_record(args.json, {"kernel_threads": args.kernel_threads, "rows": [r.__dict__ for r in rows]}, argv)
    return rows


if __name__ == "__main__":
    main()
