"""Recall and speed of the approximate (projected) neighbour search against the exact one, on real features.

    python -m eval run knn_recall --colmap out/bench/fern/colmap \
        --ply start=out/bench/fern/colormatch.ply --ply end=out/bench/sty_exact_starry.ply \
        --style ../shared/data/styles/starry_night.jpg --json out/bench/knn_recall_starry.json

For every given scene (a colour-matched start and a stylized end bracket a stylization run) and every view, the
rendered relu3_1..3 features (the stylization's: render ×0.5, 768 channels) are searched against the painting's
(height 256) exactly and with the projected search (:class:`abcgs.features.knn.Projection`) for every
``--ranks`` × ``--candidates``. Printed per setting, over all views and scenes:

- ``recall rs`` / ``recall sr``: the fraction of the exact k nearest style features of each rendered feature (and of
  the exact k nearest rendered features of each style feature) that the projected search returns (k = ``--k``,
  FAST's 5); ``recall nn``: NNFM's nearest style feature (k = 1) found;
- ``pairs``: |A_proj ∩ A_exact| / |A_exact ∪ A_proj| for FAST's affinity A;
- ``target``: the relative difference ‖F_rs(proj) − F_rs(exact)‖ / ‖F_rs(exact)‖ of FAST's aligned features, and
  ``loss``: the largest |FAST loss difference| over the views;
- ``ms``: the median time of FAST's pair search (both directions) per view, against the exact search's
  (``--knn-search``, default ``auto``), on ``--threads`` torch threads and the C++ kernels on all cores.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import torch

from abcgs.features import knn
from abcgs.losses import fast
from abcgs.losses.params import FastParams
from eval.bench.real_features import add_feature_arguments, load_bench_features
from eval.bench.timing import median_ms
from eval.record import bench_parser, write_record


def _found(approx: torch.Tensor, exact: torch.Tensor) -> float:
    """Fraction of the entries of each row of ``exact`` ``(N, k)`` that appear in the same row of ``approx``."""
    return float((exact[:, :, None] == approx[:, None, :]).any(-1).float().mean())


def _parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = bench_parser(__doc__)
    add_feature_arguments(ap)
    ap.add_argument("--ranks", default="64,96,128")
    ap.add_argument("--candidates", default="8,16,32")
    ap.add_argument("--products", default="float32",
                    help="comma-separated projected products to compare: float32, bfloat16 (the AVX512-BF16 kernel where "
                    "this CPU has it, else the same rounding in torch), auto")
    ap.add_argument("--k", type=int, default=5)
    ap.add_argument("--time-views", type=int, default=3, help="views timed per setting")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--knn-search", default="auto", choices=["auto", "exact", "bf16"])
    ap.add_argument("--threads", type=int, default=2)
    return ap


def _exact_search(features: list[torch.Tensor], style: knn.StyleFeatures, k: int, search: str) -> list[tuple]:
    """Per rendered feature set ``(C, N_r)``, what the exact search (``search``) gives against ``style`` ``(C, N_s)``:
    the k nearest style features of each rendered one ``(N_r, k)``, the k nearest rendered features of each style
    one ``(N_s, k)``, the nearest style feature ``(N_r, 1)``, FAST's mutual pairs as a set of ``r * N_s + s``, FAST's
    aligned features ``(C, N_r)`` and FAST's loss."""
    exact_params = FastParams(k=k, knn_search=search, projection_rank=0)
    n_s = style.shape[1]
    exact = []
    for f in features:
        nn_rs, nn_sr = knn.cosine_topk(f, style, k, k, search=search)
        nn1, _ = knn.cosine_topk(f, style, 1, 0, search=search)
        rows, cols = knn.mutual_knn_pairs(f, style, k, search=search)
        target = fast.fast_target(f, style, exact_params)
        exact.append((nn_rs, nn_sr.t(), nn1, set((rows * n_s + cols).tolist()), target,
                      float(fast.cosine_distance_loss(f, target))))
    return exact


def _agreement(features: list[torch.Tensor], exact: list[tuple], style: knn.StyleFeatures, k: int,
               proj: knn.Projection, fp: FastParams) -> dict:
    """How close the projected search ``proj`` (FAST with ``fp``) comes to :func:`_exact_search`'s ``exact``: the
    recalls (mean and worst view), the pairs' Jaccard index, and the largest target and loss differences."""
    n_s = style.shape[1]
    rec_rs, rec_sr, rec_nn, jac, tdiff, ldiff = [], [], [], [], [], []
    for f, (ex_rs, ex_sr, ex_nn, ex_pairs, ex_target, ex_loss) in zip(features, exact):
        nn_rs, nn_sr = knn.cosine_topk(f, style, k, k, projection=proj)
        nn1, _ = knn.cosine_topk(f, style, 1, 0, projection=proj)
        rows, cols = knn.mutual_knn_pairs(f, style, k, projection=proj)
        pairs = set((rows * n_s + cols).tolist())
        target = fast.fast_target(f, style, fp)
        rec_rs.append(_found(nn_rs, ex_rs))
        rec_sr.append(_found(nn_sr.t(), ex_sr))
        rec_nn.append(_found(nn1, ex_nn))
        jac.append(len(pairs & ex_pairs) / len(pairs | ex_pairs))
        tdiff.append(float((target - ex_target).norm() / ex_target.norm()))
        ldiff.append(abs(float(fast.cosine_distance_loss(f, target)) - ex_loss))
    return {"recall_rs": statistics.mean(rec_rs), "recall_sr": statistics.mean(rec_sr),
            "recall_nn": statistics.mean(rec_nn), "recall_rs_worst_view": min(rec_rs),
            "recall_sr_worst_view": min(rec_sr), "pairs_jaccard": statistics.mean(jac),
            "target_rel_diff_max": max(tdiff), "loss_abs_diff_max": max(ldiff)}


def main(argv=None) -> dict:
    args = _parser().parse_args(argv)
    torch.set_num_threads(args.threads)

    loaded = load_bench_features(args)
    style, cameras, features = loaded.style, loaded.cameras, loaded.rendered
    n_r, n_s = features[0][1].shape[1], style.shape[1]
    print(f"{len(features)} feature sets ({len(args.ply)} scenes x {len(cameras)} views), N_r={n_r} N_s={n_s} "
          f"C={style.shape[0]}, k={args.k}; {platform.machine()}, {os.cpu_count()} CPUs, torch threads {args.threads}")

    exact = _exact_search([f for _, f in features], style, args.k, args.knn_search)
    timed = features[: args.time_views]
    ms_exact = statistics.median(
        median_ms(lambda f=f: knn.mutual_knn_pairs(f, style, args.k, search=args.knn_search), args.repeats)
        for _, f in timed
    )
    print(f"exact search ({args.knn_search}): {ms_exact:.1f} ms per view for FAST's pairs")
    header = f"{'rank':>5} {'cand':>5} {'products':>9} {'recall rs':>10} {'recall sr':>10} {'recall nn':>10} {'pairs':>8} " \
             f"{'target':>9} {'loss':>9} {'ms':>7}"
    print(header)
    rows_out = []
    settings = [(int(r), int(c), prod) for r in args.ranks.split(",") for c in args.candidates.split(",")
                for prod in args.products.split(",")]
    for rank, cand, products in settings:
        proj = knn.Projection(rank, cand, products=products)
        fp = FastParams(k=args.k, projection_rank=rank, projection_candidates=cand, projection_min_similarities=0,
                        projection_products=products)
        agreement = _agreement([f for _, f in features], exact, style, args.k, proj, fp)
        ms = statistics.median(
            median_ms(lambda f=f, p=proj: knn.mutual_knn_pairs(f, style, args.k, projection=p), args.repeats)
            for _, f in timed
        )
        row = {"rank": rank, "candidates": cand, "products": products, "bf16_products": proj.bf16_products(),
               **agreement, "ms": ms}
        rows_out.append(row)
        print(f"{rank:>5} {cand:>5} {products:>9} {row['recall_rs']:>10.5f} {row['recall_sr']:>10.5f} {row['recall_nn']:>10.5f} "
              f"{row['pairs_jaccard']:>8.5f} {row['target_rel_diff_max']:>9.2e} {row['loss_abs_diff_max']:>9.2e} "
              f"{ms:>7.1f}")
    out = {"scenes": args.ply, "style": str(args.style), "views": len(cameras), "n_r": n_r, "n_s": n_s, "k": args.k,
           "exact_search": args.knn_search, "exact_ms": ms_exact, "threads": args.threads,
           "bf16_dot_available": knn.bf16_dot_available(),
           "results": rows_out}
    if args.json:
        write_record(args.json, out, argv)
    return out

if __name__ == "__main__":
    main()
