"""Fast C++ backend vs the reference backend, tiling invariance, determinism and backend selection."""

from __future__ import annotations

import importlib
import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import torch
from render_scenes import GRAD_FIELDS, random_scene, torch_threads

from abcgs.render import BACKENDS, BackendUnavailable, kernel_variants, project_gaussians, rasterize, select_backend
from abcgs.render import cpu as cpu_backend
from abcgs.render.reference import rasterize_brute_force, rasterize_reference

# the package re-exports the function `rasterize`, which shadows the submodule attribute of the same name
rasterize_module = importlib.import_module("abcgs.render.rasterize")
REPO = Path(__file__).resolve().parents[1]

needs_cpu = pytest.mark.skipif(not cpu_backend.is_available(), reason="C++ backend not built")


def _render_and_grads(scene, backend, weights, **kw):
    """Render, backprop a random weighting of image/alpha/depth; return outputs and input gradients."""
    s = scene.leaves()
    bg = kw.pop("background", None)
    if bg is not None:
        bg = bg.clone().requires_grad_(True)
    image, alpha, meta = rasterize(*s.args(), background=bg, backend=backend, **{"render_mode": "RGB+D", **kw})
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
        {"background": torch.linspace(0, 1, 16), "render_mode": "RGB+ED"},
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
    _, _, _, toff, slots, order, *_ = ext.rasterize_forward(means2d, conics, colors, opacities, depths, extents,
                                                              width, height, tile, False)
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
        img, alpha = cpu_backend.rasterize_batch_cpu(  # one view: a batch of one
            proj.means2d[None], proj.conics[None], scene.colors, scene.opacities, proj.depths[None],
            proj.extents[None], scene.width, scene.height, tile_size=tile)
        img, alpha = img[0], alpha[0]
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


def _run_python(script: str, env_extra: dict | None = None, cwd: Path = REPO):
    env = {**os.environ, **(env_extra or {})}
    return subprocess.run([sys.executable, "-c", script], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_a_fresh_process_loads_the_installed_kernels_without_compiling(tmp_path) -> None:
    """The kernels are built by the install: a new process imports them in well under a second, never calls
    torch's JIT loader and writes no build folder (a fresh $HOME stays empty of caches)."""
    proc = _run_python(
        "import time, torch.utils.cpp_extension as ce\n"
        "def jit(*a, **k): raise AssertionError('compiled at run time')\n"
        "ce.load = ce.load_inline = jit\n"
        "import abcgs.render.cpu as c\n"
        "t = time.perf_counter(); ext = c.extension_or_none(); t = time.perf_counter() - t\n"
        "print(t, ext.__name__ if ext is not None else None)\n",
        {"HOME": str(tmp_path), "XDG_CACHE_HOME": str(tmp_path / ".cache")},
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    seconds, name = proc.stdout.split()[-2:]
    assert float(seconds) < 5
    assert not (tmp_path / ".cache" / "abcgs").exists() and not (tmp_path / ".cache" / "torch_extensions").exists()
    if cpu_backend.is_available():
        assert name == cpu_backend.load_extension().__name__
        assert name.startswith("abcgs.render." + kernel_variants.MODULE_PREFIX)


@needs_cpu
def test_a_copy_of_the_checkout_uses_the_installed_kernels(tmp_path) -> None:
    """A copy that was not installed itself (a benchmark's clean copy, a dvc exp temp folder) has no modules of its
    own: it loads those of the installed abcgs, checked against its own csrc/."""
    shutil.copytree(REPO / "abcgs", tmp_path / "abcgs", ignore=shutil.ignore_patterns("__pycache__", "_kernels_*"))
    proc = _run_python("import abcgs.render.cpu as c; print(c.__file__, c.load_extension().__file__)", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    module, kernels = map(Path, proc.stdout.split()[-2:])
    assert module == tmp_path / "abcgs" / "render" / "cpu.py"  # the copy was imported
    assert kernels == Path(cpu_backend.load_extension().__file__)


@needs_cpu
def test_the_portable_variant_matches_the_reference_where_it_is_built() -> None:
    """ATEN_CPU_CAPABILITY=default makes a process take the portable (SSE2) build, which renders like the rest."""
    record = next(filter(None, map(cpu_backend.read_build_record, cpu_backend.kernel_dirs())))
    if "portable" not in record["variants"] or len(record["variants"]) < 2:
        pytest.skip("the install built no separate portable variant")
    proc = _run_python(
        "import sys, torch; sys.path.insert(0, 'tests')\n"
        "from render_scenes import random_scene\n"
        "from abcgs.render import rasterize, cpu\n"
        "print(cpu.load_extension().__name__)\n"
        "s = random_scene(200, 64, 48, torch.float32, 0)\n"
        "a, r = (rasterize(*s.args(), backend=b)[0] for b in ('cpu', 'reference'))\n"
        "print(float((a - r).abs().max()))\n",
        {"ATEN_CPU_CAPABILITY": "default"},
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    name, err = proc.stdout.split()[-2:]
    assert name == "abcgs.render._kernels_portable"
    assert float(err) < 1e-4


@pytest.mark.parametrize(
    ("machine", "capability", "bf16", "order"),
    [
        ("x86_64", "AVX512", True, ["x86_64_v4_bf16", "x86_64_v4", "x86_64_v3", "portable"]),
        ("x86_64", "AVX512", False, ["x86_64_v4", "x86_64_v3", "portable"]),
        ("x86_64", "AVX2", True, ["x86_64_v3", "portable"]),
        ("AMD64", "AVX2", False, ["x86_64_v3", "portable"]),
        ("x86_64", "DEFAULT", False, ["portable"]),
        ("aarch64", "SVE256", False, ["portable"]),
    ],
)
def test_kernel_variants_are_ordered_by_what_the_cpu_runs(machine, capability, bf16, order) -> None:
    assert kernel_variants.runnable_variants(machine, capability, bf16) == order
    assert kernel_variants.variants_to_build(machine, capability, bf16) == list(dict.fromkeys([order[0], "portable"]))
    flags = kernel_variants.variant_flags(order[0], machine)
    assert flags[:4] == ["-O3", "-ffp-contract=off", "-fno-trapping-math", "-std=c++17"]
    assert ("-march=x86-64-v4" in flags) == order[0].startswith("x86_64_v4")
    assert not any(f.startswith("-march") for f in flags) or kernel_variants.is_x86_64(machine)


def test_kernels_older_than_their_sources_are_refused_with_the_fix(tmp_path, monkeypatch) -> None:
    """An editable install keeps its modules in the source tree: once csrc/ changes they no longer match the
    sources DVC tracks, and load_extension says to rebuild (auto rendering falls back, warning the same)."""
    csrc = tmp_path / "csrc"
    shutil.copytree(cpu_backend._CSRC, csrc)
    record = {"variants": ["portable"], "torch": torch.__version__, "sources_sha256": kernel_variants.sources_sha256(csrc)}
    assert kernel_variants.build_problem(record, csrc, torch.__version__) is None
    (csrc / "parallel.h").write_text((csrc / "parallel.h").read_text() + "\n// edited\n")
    problem = kernel_variants.build_problem(record, csrc, torch.__version__)
    assert "older than abcgs/render/csrc" in problem and "make install" in problem

    (tmp_path / kernel_variants.RECORD_NAME).write_text(json.dumps(record))
    monkeypatch.setattr(cpu_backend, "_CSRC", csrc)
    monkeypatch.setattr(cpu_backend, "kernel_dirs", lambda: [tmp_path])
    monkeypatch.setattr(cpu_backend, "_module", None)
    monkeypatch.setattr(cpu_backend, "_error", None)
    monkeypatch.setattr(rasterize_module, "_warned", set())
    monkeypatch.delenv("ABCGS_RENDER_BACKEND", raising=False)
    with pytest.raises(BackendUnavailable, match="older than abcgs/render/csrc.*make install"):
        cpu_backend.load_extension()
    with pytest.warns(RuntimeWarning, match="make install"):
        assert rasterize(*_tiny_scene().args())[2].backend == "reference"


def test_a_build_for_another_torch_or_none_at_all_says_how_to_rebuild(tmp_path) -> None:
    no_sources = tmp_path  # an install without csrc/: only the torch version is checked
    other_torch = {"variants": ["portable"], "torch": "2.2.0", "sources_sha256": "0" * 64}
    problem = kernel_variants.build_problem(other_torch, no_sources, "2.13.0+cpu")
    assert "built against torch 2.2.0" in problem and "2.13.0+cpu is running" in problem and "make install" in problem
    assert kernel_variants.build_problem({**other_torch, "torch": "2.13.0+cpu"}, no_sources, "2.13.0+cpu") is None
    not_built = {"variants": [], "torch": None, "error": "torch was not importable when abcgs was built"}
    problem = kernel_variants.build_problem(not_built, no_sources, "2.13.0+cpu")
    assert "torch was not importable" in problem and "pip install torch==2.13.0`" in problem
    assert "--no-build-isolation" in problem and "make install" in problem
    assert "make install" in kernel_variants.build_problem(None, no_sources, "2.13.0+cpu")


def test_the_installed_build_record_matches_this_checkout() -> None:
    """`make install` rebuilds when csrc/ changes (its key hashes it); the record of the kernels in use says so."""
    record = next(filter(None, map(cpu_backend.read_build_record, cpu_backend.kernel_dirs())), None)
    if record is None or not record["variants"]:
        pytest.skip(f"no kernels installed: {kernel_variants.build_problem(record, cpu_backend._CSRC, torch.__version__)}")
    assert record["sources_sha256"] == kernel_variants.sources_sha256(cpu_backend._CSRC)
    assert record["torch"] == torch.__version__
    assert cpu_backend.is_available()
