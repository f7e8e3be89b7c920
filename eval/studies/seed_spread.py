"""Measure the seed-to-seed spread of the tiny-scene regression metrics (justifies the CI tolerances).

    python -m eval run seed_spread --seeds 0 1 2 --json tests/baselines/tiny_seed_spread.json

For each seed, runs `dvc repro` in a fresh copy of the working tree with the reduced iteration counts of
tests/test_pipeline_e2e.py and every seed in params.yaml set to that seed, then reports per experiment the
mean and standard deviation of the gated metrics (SSIM, short/long-range RMSE).
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import yaml

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from eval.bench.regression import GATED, REDUCED, reduce
from eval.bench.repo_copy import copy_repo, run_in
from eval.record import bench_parser, write_record

ROOT = Path(__file__).resolve().parents[2]

SEEDED = ("fit", "colormatch", "stylize", "evaluate")


def run_once(seed: int, work: Path) -> dict[str, dict[str, float]]:
    def edit(params: dict) -> None:
        reduce(params)
        for section in SEEDED:
            params.setdefault(section, {})["seed"] = seed

    repo = copy_repo(work / f"seed{seed}", edit)
    proc = run_in(["dvc", "repro"], repo, timeout=None)
    if proc.returncode != 0:
        raise RuntimeError(f"dvc repro failed for seed {seed}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    params = yaml.safe_load((repo / "params.yaml").read_text())
    out = {}
    for exp in params["experiments"]:
        ev = json.loads((repo / "out" / exp / "eval.json").read_text())
        out[exp] = {k: float(ev[k]) for k in GATED}
    return out


def main(argv=None) -> dict:
    ap = bench_parser(__doc__)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        runs = {s: run_once(s, Path(tmp)) for s in args.seeds}
    summary = {}
    for exp in runs[args.seeds[0]]:
        summary[exp] = {}
        for k in GATED:
            vals = np.array([runs[s][exp][k] for s in args.seeds])
            summary[exp][k] = {"mean": float(vals.mean()), "std": float(vals.std(ddof=1)) if len(vals) > 1 else 0.0,
                               "values": vals.tolist()}
            print(f"{exp:22s} {k:12s} mean {vals.mean():.4f} std {summary[exp][k]['std']:.4f} {vals.round(4).tolist()}")
    result = {"seeds": args.seeds, "reduced": dict(REDUCED), "metrics": summary}
    if args.json:
        write_record(args.json, result, argv)
    return result


if __name__ == "__main__":
    main()
