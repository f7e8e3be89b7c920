"""Time the VGG-16 feature extractor in both memory layouts, at the sizes the pipeline uses.

    python -m eval run vgg [--repeats 5] [--threads 0]

Cases: stylization (relu3_1..3 of a 504×378 render halved to 252×189, forward and forward+backward to the
input) and evaluation (the perceptual proxy's relu1_2..relu5_3 on a pair of 497×373 renders, forward).
Random weights (timing does not depend on them); each figure is the minimum of ``--repeats`` runs after a
warm-up. Prints the ratio contiguous / channels-last (> 1: channels-last is faster).
"""

from __future__ import annotations

import argparse
import os

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import torch

from abcgs.features.vgg import VGG16Features, random_state_dict
from eval.bench.timing import repeat_seconds

CASES = [
    ("stylize relu3 fwd+bwd", ("relu3_1", "relu3_2", "relu3_3"), (1, 189, 252), True),
    ("eval proxy relu5_3 fwd", ("relu1_2", "relu2_2", "relu3_3", "relu4_3", "relu5_3"), (2, 373, 497), False),
]


def run_case(vgg: VGG16Features, shape: tuple[int, int, int], backward: bool, repeats: int) -> float:
    b, h, w = shape
    x = torch.rand(b, 3, h, w, generator=torch.Generator().manual_seed(0))

    def once():
        if backward:
            xx = x.clone().requires_grad_(True)
            sum(f.sum() for f in vgg(xx).values()).backward()
        else:
            with torch.no_grad():
                vgg(x)

    return min(repeat_seconds(once, repeats))


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch's default)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    sd = random_state_dict(0, "relu5_3")
    print(f"# torch {torch.__version__}, {torch.get_num_threads()} threads, load {os.getloadavg()[0]:.2f}; "
          f"min of {args.repeats} after a warm-up")
    rows = []
    for name, layers, shape, backward in CASES:
        t = {cl: run_case(VGG16Features(sd, layers, channels_last=cl), shape, backward, args.repeats) for cl in (False, True)}
        rows.append({"case": name, "contiguous_s": t[False], "channels_last_s": t[True], "ratio": t[False] / t[True]})
        print(f"{name:24s} contiguous {t[False]:.3f}s  channels-last {t[True]:.3f}s  ×{t[False] / t[True]:.2f}", flush=True)
    return rows


if __name__ == "__main__":
    main()
