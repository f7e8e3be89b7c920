"""The evaluation's shared work gives the straightforward computation's numbers: the reference stage's stored flows and
pair masks (read instead of recomputed) and the batched perceptual distances (several pairs per VGG forward, spread
over threads) against every view and pair computed one at a time from scratch, on a small generated scene.

Tolerance: 1e-6 absolute on every metric (the task's bar); on the CPU the numbers come out equal, since a VGG forward
gives each sample the same features in any batch and every pair's distance is then computed by the same operations.
A corrupted stored mask must move the numbers (the comparison is not blind, and the stored masks are what runs)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.ndimage
from test_eval_stage import eval_scene

from abcgs.errors import InputError
from abcgs.evaluation.consistency import backward_warp, fb_consistency_mask, make_flow_estimator
from abcgs.evaluation.content import PerceptualDistance, masked_rmse, nan_mean, pair_batches, ssim_wang
from abcgs.evaluation.evaluate import evaluate_scene, write_evaluation
from abcgs.evaluation.params import EvalParams
from abcgs.evaluation.reference import (
    compute_reference,
    load_reference,
    mask_pairs,
    pairs_for,
    render_views,
    save_reference,
)
from abcgs.features.vgg import random_state_dict

TOL = 1e-6
PARAMS = EvalParams(fid=False, fps_passes=1, long_term_gap=3, workers=2, perceptual="proxy")


@pytest.fixture(scope="module")
def scene():
    return eval_scene(n_views=6)


def texture(h: int, w: int, seed: int) -> np.ndarray:
    img = scipy.ndimage.gaussian_filter(np.random.default_rng(seed).random((h, w, 3)), sigma=(1.5, 1.5, 0))
    return ((img - img.min()) / (img.max() - img.min())).astype(np.float32)


@pytest.mark.parametrize("precision", ["float32", "bfloat16"])
def test_batched_perceptual_distances_are_the_pair_by_pair_ones(precision) -> None:
    """Runs of two sizes, masks (one keeping nothing: NaN) and none, every batch size and thread count; in either
    precision of the VGG (bf16 too gives each sample the same features in any batch)."""
    proxy = PerceptualDistance("proxy", vgg_state=random_state_dict(0, "relu5_3"), vgg_info={"source": "random (test)"},
                               precision=precision)
    sizes = [(40, 56)] * 3 + [(32, 48)] * 2 + [(40, 56)] * 2
    a = [texture(h, w, k) for k, (h, w) in enumerate(sizes)]
    b = [np.clip(x + 0.2 * texture(*x.shape[:2], 50 + k) - 0.1, 0, 1) for k, x in enumerate(a)]
    masks = [texture(h, w, 100 + k)[..., 0] > 0.3 for k, (h, w) in enumerate(sizes)]
    masks[1], masks[5] = None, np.zeros(sizes[5], bool)
    want = [proxy(x, y, m) for x, y, m in zip(a, b, masks)]
    assert np.isnan(want[5]) and np.isfinite(np.delete(want, 5)).all() and len(set(np.delete(want, 5))) == 6
    for batch_pixels in (1, 2 * 40 * 56 * 2, 1 << 19):
        for workers in (1, 2):
            got = proxy.distances(a, b, masks, workers=workers, batch_pixels=batch_pixels)
            np.testing.assert_allclose(got, want, rtol=0, atol=TOL, err_msg=f"{batch_pixels} px, {workers} workers")
    assert proxy.distances(a[:2], b[:2]) == pytest.approx([proxy(a[0], b[0]), proxy(a[1], b[1])], abs=TOL)
    moved = proxy.distances(a, [b[2], b[1], b[0], *b[3:]], masks)  # two pairs mixed up: other numbers
    assert abs(moved[0] - want[0]) > 1e-3 and abs(moved[2] - want[2]) > 1e-3 and moved[3:] == pytest.approx(want[3:], nan_ok=True)


def test_pair_batches_keep_sizes_apart_and_give_every_thread_work() -> None:
    sizes = [(10, 10)] * 5 + [(8, 8)] * 3
    assert pair_batches(sizes, batch_pixels=400, workers=1) == [[0, 1], [2, 3], [4], [5, 6, 7]]
    assert pair_batches(sizes, batch_pixels=1 << 20, workers=2) == [[0, 1, 2], [3, 4], [5, 6], [7]]
    assert pair_batches([(10, 10)], batch_pixels=1, workers=4) == [[0]]


def _straightforward(cams, model, styl, proxy, params: EvalParams) -> dict:
    """The metrics computed one view and one pair at a time: fresh renders, flows estimated here, masks made here."""
    originals, _ = render_views(model, cams, params.backend)
    stylized, _ = render_views(styl, cams, params.backend)
    estimate = make_flow_estimator(params.flow, params.raft_weights, params.raft_iterations)
    pairs = pairs_for(cams, params)
    out = {"ssim": nan_mean([ssim_wang(o, s) for o, s in zip(originals, stylized)]),
           "content_lpips_proxy_vgg": nan_mean([proxy(o, s) for o, s in zip(originals, stylized)])}
    for kind in ("short", "long"):
        rows, floor = [], []
        for i, j in pairs.of(kind):
            f_ij, f_ji = estimate(originals[i], originals[j]), estimate(originals[j], originals[i])
            mask = fb_consistency_mask(f_ij, f_ji)
            warped = backward_warp(stylized[j], f_ij)
            rows.append((masked_rmse(stylized[i], warped, mask), proxy(stylized[i], warped, mask), float(mask.mean())))
            floor.append(masked_rmse(originals[i], backward_warp(originals[j], f_ij), mask))
        out[f"{kind}_rmse"] = nan_mean([r[0] for r in rows])
        out[f"{kind}_lpips_proxy_vgg"] = nan_mean([r[1] for r in rows])
        out[f"{kind}_valid_fraction"] = float(np.mean([r[2] for r in rows]))
        out[f"{kind}_rmse_floor"] = nan_mean(floor)
        out[f"{kind}_pairs"] = rows
    return out


def _compare(m: dict, want: dict) -> list[str]:
    """Keys where the evaluation record ``m`` is more than TOL from the straightforward numbers."""
    bad = [k for k, v in want.items() if not k.endswith("_pairs") and abs(m[k] - v) > TOL]
    for kind in ("short", "long"):
        for row, (rmse, perc, valid) in zip(m["consistency_pairs"][kind], want[f"{kind}_pairs"]):
            if max(abs(row["rmse"] - rmse), abs(row["lpips_proxy_vgg"] - perc), abs(row["valid_fraction"] - valid)) > TOL:
                bad.append(f"{kind} pair {row['i']}-{row['j']}")
    return bad


def test_the_stored_reference_and_batched_pairs_give_the_straightforward_metrics(scene, proxy, tmp_path) -> None:
    cams, model, styl, style = scene
    ref = compute_reference(cams, model, PARAMS, model_digest="abc")
    save_reference(tmp_path / "ref", ref)
    loaded = load_reference(tmp_path / "ref", cams, PARAMS, model_digest="abc")
    keys = mask_pairs(loaded.originals, loaded.pairs)
    assert sorted(loaded.masks) == sorted(keys) and len(keys) == len(loaded.pairs.short) + len(loaded.pairs.long)
    for i, j, hw in keys:  # stored bits = the mask of the stored flows
        np.testing.assert_array_equal(loaded.masks[(i, j, hw)],
                                      fb_consistency_mask(loaded.flows[(i, j, hw)], loaded.flows[(j, i, hw)]))
    (tmp_path / "ref" / "masks.npz").rename(tmp_path / "masks.npz")
    with pytest.raises(InputError, match="no pair masks"):
        load_reference(tmp_path / "ref", cams, PARAMS, model_digest="abc")
    want = _straightforward(cams, model, styl, proxy, PARAMS)
    fast = evaluate_scene(cams, model, styl, [style], PARAMS, perceptual=proxy, reference=loaded)
    m = fast.metrics
    assert m["short_pairs_resampled"] == 0 and len(m["consistency_pairs"]["long"]) == 3
    assert _compare(m, want) == []
    plain = evaluate_scene(cams, model, styl, [style], PARAMS.model_copy(update={"workers": 1}), perceptual=proxy)
    assert _compare(plain.metrics, want) == []  # no reference, one thread: the same numbers
    assert abs(plain.metrics["gram_distance"] - m["gram_distance"]) <= TOL

    (i, j, hw), first = keys[0], loaded.masks[keys[0]]
    loaded.masks[(i, j, hw)] = np.zeros_like(first)
    loaded.masks[(i, j, hw)][: hw[0] // 2] = True  # a wrong stored mask: the evaluation uses it, the numbers move
    corrupted = evaluate_scene(cams, model, styl, [style], PARAMS, perceptual=proxy, reference=loaded).metrics
    assert f"short pair {i}-{j}" in _compare(corrupted, want) or f"long pair {i}-{j}" in _compare(corrupted, want)

    # the cost benchmark reads the timings the evaluation writes
    from eval.bench.evaluate_cost import main as cost_main

    out = tmp_path / "out"
    write_evaluation(out / "e" / "eval.json", out / "e" / "metrics.json", {"experiment": "e", **m}, fast)
    total = json.loads((out / "e" / "eval_info.json").read_text())["eval_timings_s"]["total_s"]
    (out / "e" / "stylize_info.json").write_text(json.dumps({"stylize_seconds": 4 * total}))
    assert cost_main(["--experiment", "e", "--out", str(out), "--json", str(tmp_path / "cost.json")]) == 0
    rec = json.loads((tmp_path / "cost.json").read_text())
    assert rec["ratio"] == pytest.approx(0.25) and rec["met"] and rec["evaluation"]["cpu_s"] > 0
    assert {"content", "consistency", "fid_kid", "gram", "render", "speed passes"} <= set(rec["parts"])
    assert cost_main(["--experiment", "nothing", "--out", str(out)]) == 2
