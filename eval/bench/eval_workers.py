"""Seconds per image pair of the evaluation's perceptual distance on 1 and on N pair workers (``evaluate.workers``).

    python eval/bench/eval_workers.py                 # 6 pairs of 497×373 images, workers 1 and 2, alternated twice
    python eval/bench/eval_workers.py --size 497x373 --pairs 8 --workers 2 --rounds 3

How it measures: the VGG-16 proxy distance (``lpips_proxy_vgg``, random VGG weights: the time does not depend on
them) of random image pairs at LLFF fern's evaluation size, one torch thread per pair (``evaluate.num_threads``'s
default), through :func:`abcgs.evaluation.parallel.ordered_map` with 1 worker and with ``--workers``, alternated
``--rounds`` times after a warm-up; prints the seconds per pair of each run and checks that both give the same
numbers. Run on an idle machine.
"""

from __future__ import annotations

import argparse
import time

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs.evaluation.content import PerceptualDistance
from abcgs.evaluation.parallel import available_cores, ordered_map
from abcgs.features.vgg import random_state_dict


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("--size", default="497x373", help="image WxH")
    ap.add_argument("--pairs", type=int, default=6)
    ap.add_argument("--workers", type=int, default=available_cores())
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    w, h = (int(v) for v in args.size.split("x"))
    rng = np.random.default_rng(0)
    pairs = [(rng.random((h, w, 3), dtype=np.float32), rng.random((h, w, 3), dtype=np.float32)) for _ in range(args.pairs)]
    dist = PerceptualDistance("proxy", vgg_state=random_state_dict(0, "relu5_3"), vgg_info={"source": "random"})
    dist(*pairs[0])  # warm-up
    print(f"# {args.pairs} pairs of {w}x{h}, one torch thread per pair, {available_cores()} cores")
    out: dict[int, list[float]] = {1: [], args.workers: []}
    values = {}
    for _ in range(args.rounds):
        for n in (1, args.workers):
            t0 = time.perf_counter()
            values[n] = ordered_map(lambda ab: dist(*ab), pairs, n)
            out[n].append((time.perf_counter() - t0) / len(pairs))
            print(f"workers {n}: {out[n][-1]:.2f} s per pair", flush=True)
    same = values[1] == values[args.workers]
    print(f"same distances on 1 and {args.workers} workers: {same}")
    if not same:
        raise SystemExit("the distances differ between worker counts")
    return {"seconds_per_pair": out, "same": same}


if __name__ == "__main__":
    main()
