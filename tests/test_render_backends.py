"""Fast C++ backend vs the reference backend, tiling invariance, determinism and backend selection."""

from __future__ import annotations

import importlib
import warnings

import pytest
import torch
from render_scenes import GRAD_FIELDS, random_scene, torch_threads

from abcgs.render import BACKENDS, BackendUnavailable, project_gaussians, rasterize, select_backend
from abcgs.render import cpu as cpu_backend
from abcgs.render.reference import rasterize_brute_force, rasterize_reference

# the package re-exports the function `rasterize`, which shadows the submodule attribute of the same name
rasterize_module = importlib.import_module("abcgs.render.rasterize")

needs_cpu = pytest.mark.skipif(not cpu_backend.is_available(), reason="C++ backend not built")



def _render_and_grads(scene, backend, weights, **kw):
    """Render, backprop a random weighting of image/alpha/depth; return outputs and input gradients."""
    s = scene.leaves()
    bg = kw.pop("background", None)
    if bg is not None:
        bg = bg.clone().requires_grad_(True)
    image, alpha, meta = rasterize(*s.args(), render_depth=True, background=bg, backend=backend, **kw)
    assert meta.backend == backend
    meta.means2d.retain_grad()
    loss = sum((o * w).sum() for o, w in zip((image, alpha, meta.depth), weights))
    loss.backward()
    grads = {k: getattr(s, k).grad for k in GRAD_FIELDS}
    grads["means2d"] = meta.means2d.grad
    if bg is not None:
        grads["background"] = bg.grad
    outs = {"image": image.detach(), "alpha": alpha.detach(), "depth": meta.depth.detach()}
    return outs, grads, meta


# (width, height, N, channels, scale_range, opacity_range, dtype, seed, extra kwargs)
CONFIGS = {
    "64x48-200-rgb-f32": (64, 48, 200, 3, (0.02, 0.12), (0.1, 0.9), torch.float32, 0, {}),
    "96x64-800-16ch-f32-bg-normdepth": (
        96, 64, 800, 16, (0.02, 0.1), (0.1, 0.9), torch.float32, 1,
        {"background": torch.linspace(0, 1, 16), "normalize_depth": True},
    ),
    "128x96-2000-32ch-f32": (128, 96, 2000, 32, (0.01, 0.06), (0.1, 0.9), torch.float32, 2, {}),
    "64x48-500-rgb-f64-opaque": (64, 48, 500, 3, (0.05, 0.2), (0.6, 1.0), torch.float64, 3, {"tile_size": 8}),
}


@needs_cpu
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_cpu_binning_matches_reference_sort_and_tile_boxes(dtype):
    """The C++ radix sort + tile boxes give exactly the per-tile lists of `tile_ranges` + a stable
    `torch.argsort` (depth ties in index order, NaN depths last, zero extents dropped)."""
    from abcgs.render.reference import tile_ranges

    g = torch.Generator().manual_seed(7)
    n, width, height, tile = 3000, 77, 53, 16
    means2d = (torch.rand(n, 2, generator=g, dtype=dtype) * 1.4 - 0.2) * torch.tensor([width, height], dtype=dtype)
    extents = torch.rand(n, 2, generator=g, dtype=dtype) * 12
    extents[::11] = 0.0                                     # culled
    extents[5::13] = torch.tensor([0.3, 0.2], dtype=dtype)  # boxes that may miss every pixel centre
    depths = torch.randint(1, 40, (n,), generator=g).to(dtype) * 0.25  # many exact ties
    depths[3::97] = float("nan")
    depths[4::89] = -0.5  # behind-camera values still sort like torch does
    conics = torch.tensor([1.0, 0.0, 1.0], dtype=dtype).repeat(n, 1)
    colors, opacities = torch.rand(n, 3, generator=g, dtype=dtype), torch.full((n,), 0.5, dtype=dtype)
    ext = cpu_backend.load_extension()
    _, _, _, toff, slots, order, _, _ = ext.rasterize_forward(means2d, conics, colors, opacities, depths, extents,
                                                              width, height, tile)
    ids = order[slots.long()]  # each intersection's Gaussian
    vis = torch.nonzero(extents[:, 0] > 0).squeeze(1)
    order_expected = vis[torch.argsort(depths[vis], stable=True)]
    boxes = tile_ranges(means2d, extents, width, height, tile)
    tiles_x = (width + tile - 1) // tile
    expected: dict[int, list[int]] = {}
    for gid in order_expected.tolist():
        tx0, ty0, tx1, ty1 = boxes[gid].tolist()
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                expected.setdefault(ty * tiles_x + tx, []).append(gid)
    n_tiles = tiles_x * ((height + tile - 1) // tile)
    assert toff.numel() == n_tiles + 1
    for t in range(n_tiles):
        assert ids[toff[t] : toff[t + 1]].tolist() == expected.get(t, []), f"tile {t}"
    # `order` is the front-to-back list of Gaussians with a positive extent, and each intersection's slot is its
    # Gaussian's rank in it (so a tile's slots increase along its list)
    assert order.tolist() == order_expected.tolist()
    for t in range(n_tiles):
        s = slots[toff[t] : toff[t + 1]]
        assert bool((s[1:] > s[:-1]).all()), f"tile {t}: slots not increasing"


@needs_cpu
@pytest.mark.parametrize("seed_offset", [0, 100])
@pytest.mark.parametrize("name", list(CONFIGS))
def test_cpu_matches_reference(name, seed_offset):
    """images/alpha/depth ≤ 1e-4 max abs; gradients of every input group ≤ 1e-3 relative (norm)."""
    W, H, N, C, sr, op, dtype, seed, kw = CONFIGS[name]
    seed += seed_offset
    scene = random_scene(N, W, H, dtype, seed, channels=C, scale_range=sr, opacity_range=op)
    g = torch.Generator().manual_seed(seed)
    weights = [torch.randn(H, W, c, generator=g, dtype=torch.float64).to(dtype) for c in (C, 1, 1)]
    if "background" in kw:
        kw = {**kw, "background": kw["background"].to(dtype)}
    ref_out, ref_grads, ref_meta = _render_and_grads(scene, "reference", weights, **dict(kw))
    cpu_out, cpu_grads, cpu_meta = _render_and_grads(scene, "cpu", weights, **dict(kw))

    assert 0.1 < ref_out["alpha"].mean() < 0.99, "degenerate test scene"
    if name.endswith("opaque"):
        assert (ref_out["alpha"] > 0.999).float().mean() > 0.05, "opaque scene should saturate (clamp/stop paths)"
    assert torch.equal(ref_meta.visible, cpu_meta.visible)
    assert torch.equal(ref_meta.radii, cpu_meta.radii)
    torch.testing.assert_close(cpu_meta.means2d, ref_meta.means2d, atol=1e-4, rtol=0)
    torch.testing.assert_close(cpu_meta.depths, ref_meta.depths, atol=1e-5, rtol=1e-6)
    for k in ref_out:
        err = (cpu_out[k] - ref_out[k]).abs().max().item()
        assert err <= 1e-4, f"{k}: max abs difference {err:.3g}"
    for k, ref in ref_grads.items():
        rel = ((cpu_grads[k] - ref).norm() / ref.norm()).item()
        assert ref.norm() > 0, k
        assert rel <= 1e-3, f"d/d{k}: relative difference {rel:.3g}"


def _projection_edge_scene(dtype, n=203, width=64, height=48, seed=11):
    """``n`` random Gaussians (not a multiple of any vector width) with edge cases written over the first rows: behind
    the near plane, a zero quaternion, a centre far outside the view cone (clamped Jacobian), off-screen, an opacity
    below 1/255 (never visible)."""
    scene = random_scene(n, width, height, dtype, seed, scale_range=(0.05, 0.6), opacity_range=(0.2, 0.95))
    means, quats, opac = scene.means.clone(), scene.quats.clone(), scene.opacities.clone()
    cam_to_world = torch.linalg.inv(scene.viewmat.double())
    def world(p):  # camera-space point -> world
        return (cam_to_world[:3, :3] @ torch.tensor(p, dtype=torch.float64) + cam_to_world[:3, 3]).to(dtype)
    means[0] = world([0.1, 0.0, -1.0])     # behind the camera
    means[1] = world([0.0, 0.0, 0.005])    # in front, nearer than the near plane
    quats[2] = 0.0                         # zero quaternion: identity rotation
    means[3] = world([40.0, 1.0, 2.0])     # far outside the view cone: clamped direction, off-screen
    means[4] = world([3.2, -0.2, 2.0])     # just outside the cone on x: clamped, may still touch the image
    means[5] = world([-0.1, 2.9, 3.0])     # clamped on y
    opac[6] = 1e-3                         # alpha never reaches 1/255
    return scene, means, quats, scene.scales.clone(), opac


@needs_cpu
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_cpu_projection_matches_reference_on_many_gaussians_and_edge_cases(dtype):
    """The C++ projection (whole vectors of Gaussians, lane masks for the branches) against projection.py: outputs and
    the gradients to means, quaternions and scales, on 203 Gaussians with the culling and clamping cases; and each
    Gaussian's result does not depend on which lane of which chunk it lands in (the same rows shifted by 5)."""
    scene, means, quats, scales, opac = _projection_edge_scene(dtype)
    w, h = 64, 48
    tight = dict(rtol=1e-9, atol=1e-9) if dtype == torch.float64 else dict(rtol=2e-4, atol=2e-4)
    g = torch.Generator().manual_seed(5)
    wts = [torch.randn(means.shape[0], k, generator=g, dtype=torch.float64).to(dtype) for k in (2, 3, 1)]
    # culled rows' means2d and conics are 0 in the kernel and unused by the rasterizer (the reference leaves values
    # there): the gradients they pass are compared on the projected rows only, as the rasterizer sends them
    shown = project_gaussians(means, quats, scales, opac, scene.viewmat, scene.K, w, h).visible
    wts[0], wts[1] = wts[0] * shown[:, None], wts[1] * shown[:, None]

    def run(project):
        inputs = [t.clone().requires_grad_(True) for t in (means, quats, scales)]
        proj = project(*inputs, opac, scene.viewmat, scene.K, w, h)
        loss = (proj.means2d * wts[0]).sum() + (proj.conics * wts[1]).sum() + (proj.depths * wts[2][:, 0]).sum()
        loss.backward()
        return proj, [t.grad for t in inputs]

    ref, ref_grads = run(project_gaussians)
    cpu, cpu_grads = run(cpu_backend.project_cpu)
    assert not bool(ref.visible[[0, 1, 3, 6]].any()) and bool(ref.visible[2]) and int(ref.visible.sum()) > 150
    assert torch.equal(cpu.visible, ref.visible)
    assert torch.equal(cpu.radii, ref.radii)
    for name in ("means2d", "conics"):
        torch.testing.assert_close(getattr(cpu, name)[shown], getattr(ref, name)[shown], **tight, msg=name)
    for name in ("depths", "extents"):
        torch.testing.assert_close(getattr(cpu, name), getattr(ref, name), **tight, msg=name)
    for name, a, b in zip(("means", "quats", "scales"), cpu_grads, ref_grads):
        torch.testing.assert_close(a, b, **tight, msg=f"d/d{name}")
    assert not bool(cpu_grads[1][0].any()) and not bool(cpu_grads[2][0].any())  # behind the camera: no rotation/scale grad

    ext = cpu_backend.load_extension()
    args = (w, h, 0.01, 1e10, 0.3)
    full = ext.project_forward(means, quats, scales, opac, scene.viewmat, scene.K, *args)
    shifted = ext.project_forward(means[5:], quats[5:], scales[5:], opac[5:], scene.viewmat, scene.K, *args)
    for a, b in zip(full, shifted):
        assert torch.equal(a[5:], b)
    grads_in = [x.detach() for x in wts]
    full_b = ext.project_backward(means, quats, scales, scene.viewmat, scene.K, *args, grads_in[0], grads_in[1],
                                  grads_in[2][:, 0].contiguous())
    shifted_b = ext.project_backward(means[5:], quats[5:], scales[5:], scene.viewmat, scene.K, *args, grads_in[0][5:],
                                     grads_in[1][5:], grads_in[2][5:, 0].contiguous())
    for a, b in zip(full_b, shifted_b):
        assert torch.equal(a[5:], b)


def _tiny_projected(dtype=torch.float64, seed=7, n=8, width=21, height=13):
    scene = random_scene(n, width, height, dtype, seed, scale_range=(0.2, 0.7), opacity_range=(0.3, 0.95), channels=4)
    proj = project_gaussians(scene.means, scene.quats, scene.scales, scene.opacities, scene.viewmat, scene.K, width, height)
    assert bool(proj.visible.any())
    return scene, proj


def test_tiled_reference_matches_brute_force():
    """Tile binning loses nothing: every tile size equals the untiled oracle (odd image size, partial tiles)."""
    scene, proj = _tiny_projected()
    args = (proj.means2d, proj.conics, scene.colors, scene.opacities, proj.depths, proj.extents, scene.width, scene.height)
    bf_img, bf_alpha = rasterize_brute_force(*args)
    assert bf_alpha.max() > 0.5
    for tile in (4, 8, 16, 32):
        for chunk in (3, 512):  # depth chunking carries T across chunks
            img, alpha = rasterize_reference(*args, tile_size=tile, chunk=chunk)
            torch.testing.assert_close(img, bf_img, atol=1e-6, rtol=0)
            torch.testing.assert_close(alpha, bf_alpha, atol=1e-6, rtol=0)


@needs_cpu
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_tiled_cpu_matches_brute_force_and_tile_sizes(dtype):
    scene, proj = _tiny_projected(dtype)
    args = (proj.means2d, proj.conics, scene.colors, scene.opacities, proj.depths, proj.extents, scene.width, scene.height)
    bf_img, bf_alpha = rasterize_brute_force(*args)
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    for tile in (8, 16, 32):
        img, alpha = cpu_backend.rasterize_cpu(*args, tile_size=tile)
        torch.testing.assert_close(img, bf_img, atol=tol, rtol=0)
        torch.testing.assert_close(alpha, bf_alpha, atol=tol, rtol=0)


@needs_cpu
def test_tile_size_invariance_full_pipeline():
    """Same image and gradients from rasterize() with tile sizes 8, 16, 32 (both backends, float64)."""
    scene = random_scene(60, 40, 30, torch.float64, 4, scale_range=(0.05, 0.3), channels=3)
    weights = [torch.randn(30, 40, c, generator=torch.Generator().manual_seed(0), dtype=torch.float64) for c in (3, 1, 1)]
    results = {}
    for backend in ("reference", "cpu"):
        for tile in (8, 16, 32):
            results[backend, tile] = _render_and_grads(scene, backend, weights, tile_size=tile)
    base_out, base_grads, _ = results["reference", 16]
    for key, (out, grads, _) in results.items():
        for k in base_out:
            torch.testing.assert_close(out[k], base_out[k], atol=1e-10, rtol=0, msg=f"{key} {k}")
        for k in base_grads:
            torch.testing.assert_close(grads[k], base_grads[k], atol=1e-9, rtol=1e-9, msg=f"{key} d/d{k}")


@needs_cpu
def test_cpu_deterministic_across_calls_and_threads():
    """Bit-identical images and gradients: repeated calls, 1 vs 2 vs 3 kernel threads (the kernels' own, csrc/
    parallel.h) and 1 vs 2 torch intra-op threads (float32, many tiles)."""
    scene = random_scene(1500, 128, 96, torch.float32, 5, scale_range=(0.02, 0.1), channels=8)
    weights = [torch.randn(96, 128, c, generator=torch.Generator().manual_seed(1)) for c in (8, 1, 1)]
    runs = []
    for threads, kernel in ((1, 1), (2, 2), (1, 2), (1, 3), (2, 1)):
        with torch_threads(threads), cpu_backend.kernel_threads(kernel):
            out, grads, _ = _render_and_grads(scene, "cpu", weights)
        runs.append((out, grads))
    out0, grads0 = runs[0]
    for out, grads in runs[1:]:
        for k in out0:
            assert torch.equal(out[k], out0[k]), k
        for k in grads0:
            assert torch.equal(grads[k], grads0[k]), f"d/d{k}"


# ---------------------------------------------------------------------------------------------- selection


def _tiny_scene():
    return random_scene(3, 8, 6, torch.float32, 0)


def test_unknown_backend_raises_value_error_naming_options():
    with pytest.raises(ValueError) as info:
        rasterize(*_tiny_scene().args(), backend="vulkan")
    msg = str(info.value)
    assert "vulkan" in msg
    for name in BACKENDS:
        assert name in msg


def test_gsplat_on_cpu_tensors_is_unavailable():
    with pytest.raises(BackendUnavailable):
        rasterize(*_tiny_scene().args(), backend="gsplat")


@needs_cpu
def test_env_var_overrides_auto(monkeypatch):
    scene = _tiny_scene()
    monkeypatch.setenv("ABCGS_RENDER_BACKEND", "reference")
    assert rasterize(*scene.args())[2].backend == "reference"
    assert rasterize(*scene.args(), backend="auto")[2].backend == "reference"
    # an explicit backend wins over the environment
    assert rasterize(*scene.args(), backend="cpu")[2].backend == "cpu"
    monkeypatch.setenv("ABCGS_RENDER_BACKEND", "cpu")
    assert rasterize(*scene.args())[2].backend == "cpu"
    monkeypatch.setenv("ABCGS_RENDER_BACKEND", "bogus")
    with pytest.raises(ValueError, match="bogus"):
        rasterize(*scene.args())
    monkeypatch.delenv("ABCGS_RENDER_BACKEND")
    assert select_backend(torch.device("cpu")) == "cpu"


def test_auto_falls_back_to_reference_with_warning(monkeypatch):
    def broken(verbose=False):
        raise BackendUnavailable("no compiler (test)")

    monkeypatch.delenv("ABCGS_RENDER_BACKEND", raising=False)
    monkeypatch.setattr(cpu_backend, "load_extension", broken)
    monkeypatch.setattr(rasterize_module, "_warned", set())
    with pytest.warns(RuntimeWarning, match="no compiler"):
        assert rasterize(*_tiny_scene().args())[2].backend == "reference"
    with pytest.raises(BackendUnavailable, match="no compiler"):
        rasterize(*_tiny_scene().args(), backend="cpu")
    with warnings.catch_warnings():  # warned once only
        warnings.simplefilter("error")
        assert select_backend(torch.device("cpu")) == "reference"


def test_invalid_image_size():
    s = _tiny_scene()
    with pytest.raises(ValueError):
        rasterize(s.means, s.quats, s.scales, s.opacities, s.colors, s.viewmat, s.K, 0, 5)


def test_a_stale_build_lock_is_removed_and_a_fresh_one_waited_for(tmp_path) -> None:
    """A lock left by a process killed mid-compile would make torch's loader wait forever: old locks go."""
    import os
    import threading
    import time

    from abcgs.render.cpu import _clear_stale_build_lock

    lock = tmp_path / "lock"
    lock.touch()
    old = time.time() - 3600
    os.utime(lock, (old, old))
    _clear_stale_build_lock(tmp_path, stale_s=600)
    assert not lock.exists()
    lock.touch()  # fresh: a live build; wait until its holder removes it
    threading.Timer(0.3, lock.unlink).start()
    t0 = time.perf_counter()
    _clear_stale_build_lock(tmp_path, stale_s=600, poll_s=0.05)
    assert not lock.exists() and time.perf_counter() - t0 >= 0.25


def test_another_checkout_loads_the_built_extension_without_recompiling(tmp_path) -> None:
    """The build compiles copies of the sources inside its content-keyed folder, so a checkout elsewhere (a
    benchmark's clean copy, a dvc queue's temp folder) with the same sources reuses the build: ninja would
    recompile everything if the build commands named each checkout's own paths."""
    import os
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    if not cpu_backend.is_available():
        pytest.skip("the CPU extension cannot be built here (no compiler)")
    build = cpu_backend._build_dir()
    so = build / "abcgs_rasterize_cpu.so"
    staged = cpu_backend.staged_sources(build)
    assert [p.parent for p in staged] == [build / "src"] * len(staged)
    assert all(p.read_bytes() == s.read_bytes() for p, s in zip(staged, cpu_backend._SOURCES))
    before = so.stat().st_mtime_ns
    shutil.copytree(Path(cpu_backend.__file__).parents[1], tmp_path / "abcgs",
                    ignore=shutil.ignore_patterns("__pycache__", "*.gz"))
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    proc = subprocess.run([sys.executable, "-c", "import abcgs.render.cpu as c; c.load_extension(); print(c.__file__)"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == str(tmp_path / "abcgs" / "render" / "cpu.py")  # the copy was imported
    assert so.stat().st_mtime_ns == before, "the copy recompiled the extension"
