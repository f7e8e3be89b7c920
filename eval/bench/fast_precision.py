"""Precision and time of FAST's C×C algebra on real features: what each cheaper arithmetic costs in accuracy.

    python -m eval run fast_precision --colmap out/bench/fern/colmap \\
        --ply start=<colour-matched PLY> --ply end=<stylized PLY> \\
        --style ../shared/data/styles/starry_night.jpg --group-sizes 0,600 --rest-ms 286 \\
        --json out/bench/fast_precision_starry.json

After the neighbour search, a FAST step forms ``M = F_r D_r F_rᵀ`` and ``R = F_r U F_sᵀ`` (two C × N_r × C products),
solves ``P = (M + εI)⁻¹ R`` (float64 Cholesky) and takes the target ``F_rs = Pᵀ F_r`` (a third product)
(:mod:`abcgs.losses.fast`). For every given scene, view and group size, with the pairs of the default search, this
prints how far each variant's target lies from the same algebra in float64 (same pairs, so only the arithmetic
differs), ``‖F_rs − F_rs,64‖ / ‖F_rs,64‖`` (median and worst over the feature sets), the largest change of the
loss ``1 − cos``, and how many of its systems Cholesky found not positive definite (solved by LU instead):

- ``library``: :func:`abcgs.losses.fast.alignment_from_pairs` — float32 products, float64 solve, float32 target;
  all three in float64 for a group of fewer than 1.25 C features (``fast.is_small_group``);
- ``float32 statistics``: float32 products, float64 solve and float32 target for every group (the library before
  small groups went to float64);
- ``solve float32``: as ``float32 statistics`` with the solve in float32 (``stylize.fast.solve_dtype: float32``);
- ``target bfloat16``: as ``float32 statistics`` with the target product's operands in bfloat16 (float32 sums;
  oneDNN's AVX512-BF16 kernel where the CPU has it);
- ``statistics bfloat16``: as ``float32 statistics`` with ``M`` and ``R`` from bfloat16 operands.

Group size 0 is the whole view (single-image transfer); ``n > 0`` takes the view's first ``n`` features in raster
order (a band at the top of the view, as a region of compositional or semantic transfer gives a group), where
``n < C`` leaves ``M`` singular up to ``ε``.

It then times each part on the whole views (median of ``--repeats`` on ``--time-views`` views of the first scene):
the search, the pair statistics, the solve, the target and the cosine distance (forward and backward), in each
arithmetic, and the whole loss as the library runs it. With ``--rest-ms`` (the rest of a stylization step: render,
VGG, backward and optimiser, from ``eval/bench/stylize.py``) it prints the time FAST may take to be a quarter of
the step, the sum of the default parts and that sum with the cheaper arithmetic.
"""

from __future__ import annotations

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

VARIANTS = ("library", "float32 statistics", "solve float32", "target bfloat16", "statistics bfloat16")


def statistics_bf16(f_r: torch.Tensor, style: knn.StyleFeatures, rows: torch.Tensor, cols: torch.Tensor):
    """:func:`abcgs.losses.fast.pair_statistics` with the two products' operands rounded to bfloat16."""
    counts, g = fast.pair_sums(style, rows, cols, f_r.shape[1])
    n_pair = rows.numel()
    lhs = (f_r * (counts.float() / n_pair)).bfloat16()
    m = (lhs @ f_r.t().bfloat16()).float()
    rhs = (f_r.bfloat16() @ g.bfloat16()).float() / n_pair
    return m, rhs


def target_bf16(p: torch.Tensor, f_r: torch.Tensor) -> torch.Tensor:
    return (p.t().bfloat16() @ f_r.bfloat16()).float()


def reference_target(f_r: torch.Tensor, style: knn.StyleFeatures, rows, cols, eps: float) -> torch.Tensor:
    """The same algebra in float64 from the same pairs (``G`` summed in float64 too)."""
    f64 = f_r.double()
    counts, g = fast.pair_sums(style.raw.double(), rows, cols, f_r.shape[1])
    n_pair = rows.numel()
    m = (f64 * (counts.double() / n_pair)) @ f64.t()
    rhs = (f64 @ g) / n_pair
    p = fast.solve_alignment(m, rhs, eps=eps, solve_dtype=torch.float64)
    return p.t() @ f64


def variant_target(name: str, f_r, style, rows, cols, fp: FastParams, stats: fast.FastStats) -> torch.Tensor:
    """The target of one variant (module docstring) from the given pairs; all but ``library`` use float32 products
    whatever the group's size."""
    if name == "library":
        return fast.apply_alignment(fast.alignment_from_pairs(f_r, style, rows, cols, fp, stats), f_r)
    if name == "statistics bfloat16":
        m, rhs = statistics_bf16(f_r, style, rows, cols)
    else:
        m, rhs = fast.pair_statistics(f_r, style, rows, cols)
    solve_dtype = torch.float32 if name == "solve float32" else torch.float64
    p = fast.solve_alignment(m, rhs, eps=fp.eps, solve_dtype=solve_dtype, stats=stats)
    return target_bf16(p, f_r) if name == "target bfloat16" else p.t() @ f_r


def part_functions(f_r: torch.Tensor, style: knn.StyleFeatures, fp: FastParams) -> dict:
    """The parts of one FAST step on ``f_r`` as zero-argument callables, by name (each arithmetic's variant)."""
    rows, cols = knn.mutual_knn_pairs(f_r, style, fp.k, search=fp.knn_search, projection=knn.projection_of(fp))
    m, rhs = fast.pair_statistics(f_r, style, rows, cols)
    p = fast.solve_alignment(m, rhs, eps=fp.eps)
    target = p.t() @ f_r
    x = f_r.clone().requires_grad_(True)
    return {
        "search": lambda: knn.mutual_knn_pairs(f_r, style, fp.k, search=fp.knn_search, projection=knn.projection_of(fp)),
        "statistics float32": lambda: fast.pair_statistics(f_r, style, rows, cols),
        "statistics bfloat16": lambda: statistics_bf16(f_r, style, rows, cols),
        "solve float64": lambda: fast.solve_alignment(m, rhs, eps=fp.eps),
        "solve float32": lambda: fast.solve_alignment(m, rhs, eps=fp.eps, solve_dtype=torch.float32),
        "target float32": lambda: p.t() @ f_r,
        "target bfloat16": lambda: target_bf16(p, f_r),
        "cosine fwd+bwd": lambda: fast.cosine_distance_loss(x, target, axis=fp.cosine).backward(),
        "FAST fwd+bwd (library)": lambda: fast.fast_loss([(x, style)], fp).backward(),
    }


def main(argv=None) -> dict:
    ap = bench_parser(__doc__)
    add_feature_arguments(ap)
    ap.add_argument("--group-sizes", default="0,600", help="comma-separated; 0 = the whole view")
    ap.add_argument("--time-views", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--rest-ms", type=float, default=None, help="the rest of a stylization step, ms (see above)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)

    loaded = load_bench_features(args)
    fp, style, cameras = loaded.params.stylize.fast, loaded.style, loaded.cameras
    views = [f for _, f in loaded.rendered]
    c = style.shape[0]
    sizes = [int(s) for s in args.group_sizes.split(",")]
    print(f"{len(views)} views ({len(args.ply)} scenes x {len(cameras)}), N_r={views[0].shape[1]} N_s={style.shape[1]} "
          f"C={c}; group sizes {sizes}; {platform.machine()}, {os.cpu_count()} CPUs, torch threads {args.threads}, "
          f"bf16 dot kernel: {knn.bf16_dot_available()}")

    results = []
    print(f"{'group':>6} {'variant':>20} {'target median':>14} {'target worst':>13} {'loss worst':>11} {'LU solves':>9}")
    for size in sizes:
        groups = [f if size == 0 else f[:, :size].contiguous() for f in views]
        errs: dict[str, list[float]] = {v: [] for v in VARIANTS}
        loss_diff: dict[str, list[float]] = {v: [] for v in VARIANTS}
        stats = {v: fast.FastStats() for v in VARIANTS}
        for f_r in groups:
            rows, cols = knn.mutual_knn_pairs(f_r, style, fp.k, max_block_elems=fp.max_block_elems,
                                              search=fp.knn_search, projection=knn.projection_of(fp))
            ref = reference_target(f_r, style, rows, cols, fp.eps)
            ref_loss = float(fast.cosine_distance_loss(f_r.double(), ref, axis=fp.cosine))
            for v in VARIANTS:
                t = variant_target(v, f_r, style, rows, cols, fp, stats[v]).double()
                errs[v].append(float((t - ref).norm() / ref.norm()))
                loss_diff[v].append(abs(float(fast.cosine_distance_loss(f_r.double(), t, axis=fp.cosine)) - ref_loss))
        for v in VARIANTS:
            row = {"group_size": size, "variant": v, "target_rel_err_median": statistics.median(errs[v]),
                   "target_rel_err_worst": max(errs[v]), "loss_abs_diff_worst": max(loss_diff[v]),
                   "fallbacks": stats[v].fallbacks, "lu_solves": stats[v].lu_solves}
            results.append(row)
            print(f"{size or 'view':>6} {v:>20} {row['target_rel_err_median']:>14.2e} {row['target_rel_err_worst']:>13.2e} "
                  f"{row['loss_abs_diff_worst']:>11.2e} {row['lu_solves']:>9}" + (f" ({row['fallbacks']} identity fallbacks)"
                                                                        if row["fallbacks"] else ""))

    timed = views[: args.time_views]
    times: dict[str, list[float]] = {}
    for f_r in timed:
        for name, fn in part_functions(f_r, style, fp).items():
            times.setdefault(name, []).append(median_ms(fn, args.repeats))
    ms = {k: statistics.median(v) for k, v in times.items()}
    print(f"times on {len(timed)} whole views, median of {args.repeats} each:")
    for k, v in ms.items():
        print(f"  {k:>24}: {v:7.1f} ms")
    parts = ms["search"] + ms["statistics float32"] + ms["solve float64"] + ms["target float32"] + ms["cosine fwd+bwd"]
    cheaper = ms["search"] + ms["statistics float32"] + ms["solve float32"] + ms["target bfloat16"] + ms["cosine fwd+bwd"]
    algebra = ms["statistics float32"] + ms["solve float64"] + ms["target float32"] + ms["cosine fwd+bwd"]
    out = {"scenes": args.ply, "style": str(args.style), "views": len(views), "n_r": views[0].shape[1],
           "n_s": style.shape[1], "c": c, "fast_params": fp.model_dump(), "threads": args.threads,
           "bf16_dot_available": knn.bf16_dot_available(),
           "precision": results, "ms": ms, "sum_of_parts_ms": parts, "algebra_ms": algebra,
           "with_float32_solve_and_bf16_target_ms": cheaper}
    print(f"sum of the default parts {parts:.1f} ms (the algebra after the search {algebra:.1f} ms); with the float32 "
          f"solve and the bf16 target {cheaper:.1f} ms")
    if args.rest_ms is not None:
        budget = args.rest_ms / 3.0
        out.update(rest_ms=args.rest_ms, fast_budget_for_25_percent_ms=budget,
                   share_default=parts / (parts + args.rest_ms), share_cheaper=cheaper / (cheaper + args.rest_ms),
                   search_budget_after_default_algebra_ms=budget - algebra)
        print(f"rest of the step {args.rest_ms:.0f} ms: FAST may take {budget:.1f} ms for 25 %; the default parts give "
              f"{100 * out['share_default']:.1f} %, the cheaper arithmetic {100 * out['share_cheaper']:.1f} %; after the "
              f"default algebra the search would have {budget - algebra:.1f} ms")
    if args.json:
        write_record(args.json, out, argv)
    return out


if __name__ == "__main__":
    main()
