"""Micro-benchmark of the FAST loss at realistic sizes: chunked (library) vs dense reference.

Sizes (defaults): a 504×378 render, ×0.5 before VGG, /4 by VGG pooling → 63×47 ≈ 2961 rendered
features; a style image resized to height 256 (4:3) → 64×85 = 5440 style features; C = 768
(relu3_1..3). Features are random ReLU-like (timing does not depend on content).

    python eval/bench/fast.py [--render 504x378] [--style 341x256] [--budgets 16777216,4194304] [--repeats 3] [--device cpu]

Prints per-stage times of the chunked implementation with the exact search (kNN, pair statistics, solve,
loss+backward) with the style side prepared once (:class:`abcgs.features.knn.StyleFeatures`, as a stylization run
does), its total for several ``max_block_elems`` budgets, the total with the default projected (approximate) search,
and the dense reference's total. The share of FAST in a real
stylization step is printed by ``eval/bench/stylize.py``.
"""

from __future__ import annotations

import argparse

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import torch

from abcgs.features import knn
from abcgs.features.params import DEFAULT_MAX_BLOCK_ELEMS
from abcgs.losses import fast
from abcgs.losses.params import FastParams
from eval.bench.timing import repeat_seconds


def _best(fn, repeats: int) -> float:
    return min(repeat_seconds(fn, repeats))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--render", default="504x378", help="render WxH before the x0.5 downsampling")
    ap.add_argument("--style", default="341x256", help="style WxH fed to VGG")
    ap.add_argument("--channels", type=int, default=768)
    ap.add_argument("--budgets", default="16777216,4194304,1048576")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--device", default="cpu", help="cpu or cuda")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    rw, rh = (int(v) for v in args.render.split("x"))
    sw, sh = (int(v) for v in args.style.split("x"))
    n_r = (rw // 2 // 4) * (rh // 2 // 4)
    n_s = (sw // 4) * (sh // 4)
    c = args.channels
    g = torch.Generator().manual_seed(0)
    f_r = (torch.randn(c, n_r, generator=g) + 0.3).relu().to(args.device).requires_grad_(True)
    f_s = (torch.randn(c, n_s, generator=g) + 0.3).relu().to(args.device)
    print(
        f"N_r={n_r} N_s={n_s} C={c} device={args.device} threads={torch.get_num_threads()} "
        f"(dense N_r*N_s={n_r * n_s:,} sims)"
    )

    params = FastParams()
    t_prep = _best(lambda: knn.StyleFeatures.of(f_s), args.repeats)
    style = knn.StyleFeatures.of(f_s)
    rows, cols = knn.mutual_knn_pairs(f_r, style, params.k)
    m, rhs = fast.pair_statistics(f_r, style, rows, cols)
    print(f"N_pair={rows.numel()}; style side prepared once per run in {t_prep:.3f}s")
    t_knn = _best(lambda: knn.mutual_knn_pairs(f_r, style, params.k), args.repeats)
    t_stats = _best(lambda: fast.pair_statistics(f_r, style, rows, cols), args.repeats)
    t_solve = _best(lambda: fast.solve_alignment(m, rhs), args.repeats)
    target = fast.fast_target(f_r, style)

    def loss_bw():
        f_r.grad = None
        fast.cosine_distance_loss(f_r, target).backward()

    t_loss = _best(loss_bw, args.repeats)
    print(f"chunked stages: knn {t_knn:.3f}s  pair-stats {t_stats:.3f}s  solve(f64, Cholesky) {t_solve:.3f}s  "
          f"loss+bw {t_loss:.3f}s")

    def run_chunked(budget: int, projection_rank: int = 0):
        def f():
            f_r.grad = None
            params = FastParams(max_block_elems=budget, projection_rank=projection_rank)
            fast.fast_loss([(f_r, style)], params).backward()

        return f

    def run_dense():
        f_r.grad = None
        fast.fast_loss_dense(f_r, f_s).backward()

    for b in (int(x) for x in args.budgets.split(",")):
        print(f"chunked total (max_block_elems={b:>9,}): {_best(run_chunked(b), args.repeats):.3f}s")
    rank = FastParams().projection_rank
    print(f"projected search (rank {rank}, the default; approximate): "
          f"{_best(run_chunked(DEFAULT_MAX_BLOCK_ELEMS, rank), args.repeats):.3f}s "
          "(random features: its recall on real ones is eval/bench/knn_recall.py's)")
    print(f"dense reference total:                     {_best(run_dense, args.repeats):.3f}s")
    with torch.no_grad():
        lc = float(fast.fast_loss([(f_r, f_s)], FastParams(max_block_elems=1 << 20, projection_rank=0)))
        ld = float(fast.fast_loss_dense(f_r, f_s))
    print(f"loss chunked {lc:.7f} dense {ld:.7f} |diff| {abs(lc - ld):.2e}")


if __name__ == "__main__":
    main()
