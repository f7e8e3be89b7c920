"""The gsplat backend (``rasterize(..., backend="gsplat")``) against abcgs's CPU kernel, on the same scenes.

Each test runs twice, through the ``gsplat_impl`` fixture:

- ``torch``: gsplat 1.5's own Python code (``gsplat.rasterization`` and abcgs's adapter) with its five CUDA
  wrappers replaced by PyTorch twins that follow the CUDA kernels (``tests/gsplat_torch.py``), on CPU tensors.
  Always runs (gsplat is in the ``test`` extra).
- ``cuda`` (``@pytest.mark.cuda``): gsplat's CUDA kernels on a GPU; the scene is moved to CUDA for gsplat, abcgs's
  kernel renders it on the CPU, and the results are compared on the CPU. Skipped, with the reason, without a GPU:
  ``pytest -m cuda tests/test_gsplat_adapter.py`` on a GPU machine.

The scenes (64×48 px, 150 Gaussians + 12 behind the camera or the near plane) have off-screen and partly
off-screen Gaussians, opacities up to 0.98 (below abcgs's 0.99 alpha cap, see ``test_alpha_cap_differs``), and
are checked to stay clear of the blending rule's discontinuities (alpha = 1/255, T = 1e-4) by a relative margin
far above float32 rounding, so that the comparisons hold to tolerances of float arithmetic.
"""

from __future__ import annotations

import importlib
import re
import types
import warnings
from dataclasses import dataclass, fields, replace
from pathlib import Path

import gsplat
import gsplat_torch
import pytest
import torch
from render_scenes import GRAD_FIELDS, blend_margins, random_scene

from abcgs.fit.strategy import DefaultStrategy
from abcgs.render import BackendUnavailable, accumulate_weights, rasterize
from abcgs.render import cpu as cpu_backend

rasterize_module = importlib.import_module("abcgs.render.rasterize")
WIDTH, HEIGHT = 64, 48


@dataclass(frozen=True)
class Tolerances:
    """Largest differences accepted between gsplat and abcgs's CPU kernel (float32 scenes).

    Attributes:
        value: images and alpha, absolute.
        depth: depth maps and per-Gaussian depths, relative to the largest depth.
        means2d: screen positions, px.
        conic: conics, relative to each Gaussian's largest conic entry.
        grad: gradients of each input, relative to that input's largest gradient entry.
    """

    value: float
    depth: float
    means2d: float
    conic: float
    grad: float


# Measured on the torch twins (float32): images and alpha ≤ 3.3e-6, means2d ≤ 7.7e-6 px, conics ≤ 4.2e-6, gradients
# ≤ 6.2e-6 of the largest (≤ 9.6e-5 with expected depth: see ED_GRAD_FACTOR).
CPU_TOLERANCES = Tolerances(value=1e-5, depth=1e-5, means2d=1e-4, conic=1e-5, grad=2e-5)
# gsplat's CUDA build uses --use_fast_math (__expf, __logf: a few ulp), its backward recovers T by dividing by
# (1 - alpha) instead of replaying the product, and it sums per-Gaussian gradients with atomicAdd in no fixed
# order: 10× looser for values and positions, 50× for gradients.
CUDA_TOLERANCES = Tolerances(value=1e-4, depth=1e-4, means2d=1e-3, conic=1e-4, grad=1e-3)
ED_GRAD_FACTOR = 10
"""Gradient tolerance factor for scenes rendered with expected depth ("RGB+ED"): d(D/alpha) grows as 1/alpha², so
the float32 rounding of pixels at alpha ≈ 1/255 dominates the gradients."""


@dataclass(frozen=True)
class GsplatImpl:
    """Which gsplat implementation a test drives, on which device, within which tolerances."""

    name: str
    device: torch.device
    tol: Tolerances


@pytest.fixture(params=["torch", pytest.param("cuda", marks=pytest.mark.cuda)])
def gsplat_impl(request, monkeypatch) -> GsplatImpl:
    if request.param == "torch":
        gsplat_torch.install(monkeypatch)
        return GsplatImpl("torch", torch.device("cpu"), CPU_TOLERANCES)
    if not torch.cuda.is_available():
        pytest.skip("needs a CUDA GPU (torch.cuda.is_available() is False) and gsplat's CUDA kernels")
    from gsplat.cuda._backend import _C

    if _C is None:
        pytest.fail("a CUDA GPU is present but gsplat's CUDA kernels do not load (see gsplat's build message above)")
    return GsplatImpl("cuda", torch.device("cuda"), CUDA_TOLERANCES)


@dataclass(frozen=True)
class Case:
    """One test scene: colours (plain with ``channels``, or SH of ``sh_degree``), background, depth mode, planes."""

    sh_degree: int | None
    channels: int = 3
    background: bool = False
    normalize_depth: bool = False
    """The expected depth (``RGB+ED``) instead of the accumulated depth (``RGB+D``)."""
    near: float = 0.01
    far: float = 1e10
    dense: bool = False
    seed: int = 0

    @property
    def render_mode(self) -> str:
        return "RGB+ED" if self.normalize_depth else "RGB+D"


# each seed: the first from a round number whose scene passes test_scene_covers_the_edge_cases
CASES = {
    "rgb-D-dense": Case(None, dense=True, seed=0),
    "40ch-bg-D": Case(None, channels=40, background=True, seed=101),
    "sh0-bg-ED": Case(0, background=True, normalize_depth=True, seed=200),
    "sh1-ED-near2.5": Case(1, normalize_depth=True, near=2.5, seed=312),
    "sh2-bg-D-far4": Case(2, background=True, far=4.0, seed=400),
    "sh3-D": Case(3, seed=500),
    "sh3-bg-ED-dense": Case(3, background=True, normalize_depth=True, dense=True, seed=607),
}


def make_scene(case: Case, dtype=torch.float32):
    """150 random Gaussians (centres up to 30 % of the image size outside it; ``dense``: 300 larger, more opaque
    ones, so that blending stops at T ≤ 1e-4 in some pixels), then 12 more moved to camera z in [-1.5, 0.009]:
    behind the camera or between it and the default near plane (0.01)."""
    n, scales, opacities = (300, (0.08, 0.4), (0.5, 0.98)) if case.dense else (150, (0.02, 0.25), (0.05, 0.98))
    s = random_scene(n + 12, WIDTH, HEIGHT, torch.float64, seed=case.seed, margin=0.3, scale_range=scales,
                     opacity_range=opacities, channels=case.channels, sh_degree=case.sh_degree)
    R, t = s.viewmat[:3, :3], s.viewmat[:3, 3]
    p = s.means @ R.T + t
    p[-12:, 2] = torch.linspace(-1.5, 0.009, 12, dtype=torch.float64)
    return replace(s, means=(p - t) @ R).to(dtype)


def on(scene, device):
    """``scene`` with its tensors on ``device``."""
    return replace(scene, **{f.name: getattr(scene, f.name).to(device) for f in fields(scene)
                             if isinstance(getattr(scene, f.name), torch.Tensor)})


def render(scene, case: Case, backend: str, device: torch.device, weights):
    """Render ``scene`` on ``device`` and backprop a fixed random weighting of image, alpha and depth; outputs and
    gradients come back on the CPU."""
    s = on(scene, device).leaves()
    bg = None
    if case.background:
        bg = torch.linspace(0.1, 0.9, scene.colors.shape[-1], dtype=scene.means.dtype)
        bg = bg.to(device).requires_grad_(True)
    image, alpha, meta = rasterize(
        *s.args(), sh_degree=case.sh_degree, background=bg, render_mode=case.render_mode,
        near=case.near, far=case.far, backend=backend,
    )
    assert meta.backend == backend
    assert image.device.type == device.type
    meta.means2d.retain_grad()
    loss = sum((o * w.to(device)).sum() for o, w in zip((image, alpha, meta.depth), weights))
    loss.backward()
    grads = {k: getattr(s, k).grad.cpu() for k in GRAD_FIELDS}
    grads["means2d"] = meta.means2d.grad.cpu()
    if bg is not None:
        grads["background"] = bg.grad.cpu()
    out = {"image": image.detach().cpu(), "alpha": alpha.detach().cpu(), "depth": meta.depth.detach().cpu()}
    meta = types.SimpleNamespace(**{k: (v.detach().cpu() if isinstance(v, torch.Tensor) else v) for k, v in vars(meta).items()})
    return out, grads, meta


def loss_weights(scene, case: Case):
    """Fixed random weights of image ``(H, W, C)``, alpha and depth in the test loss."""
    g = torch.Generator().manual_seed(1000 + case.seed)
    return [torch.randn(HEIGHT, WIDTH, k, generator=g).to(scene.means.dtype) for k in (scene.colors.shape[-1], 1, 1)]


def assert_grads_close(got: dict, want: dict, rel: float):
    for k, w in want.items():
        scale = w.abs().max().item()
        assert scale > 0, f"d/d{k} is zero: the scene does not exercise it"
        err = (got[k] - w).abs().max().item()
        assert err <= rel * scale, f"d/d{k}: max abs difference {err:.3g} > {rel:g} × max |grad| {scale:.3g}"


def assert_max_abs(name: str, got, want, atol: float):
    err = (got - want).abs().max().item()
    assert err <= atol, f"{name}: max abs difference {err:.3g} > {atol:g}"


@pytest.mark.parametrize("name", list(CASES))
def test_scene_covers_the_edge_cases(name):
    """Every scene has Gaussians behind the near plane, off-screen and partly off-screen, and stays clear of the
    blending rule's discontinuities by a relative margin ≫ float32 rounding."""
    case = CASES[name]
    scene = make_scene(case)
    _, _, meta = rasterize(*scene.args(), sh_degree=case.sh_degree, near=case.near, far=case.far, backend="cpu")
    centre_in = (meta.means2d[:, 0] >= 0) & (meta.means2d[:, 0] < WIDTH) & (meta.means2d[:, 1] >= 0) & (meta.means2d[:, 1] < HEIGHT)
    in_depth = (meta.depths > case.near) & (meta.depths < case.far)
    assert int((meta.depths < 0.01).sum()) == 12
    assert int((in_depth & ~meta.visible).sum()) >= 5, "off-screen Gaussians"
    assert int((meta.visible & ~centre_in).sum()) >= 5, "partly off-screen Gaussians"
    margins = blend_margins(scene, near=case.near, far=case.far)
    assert margins["threshold"] > 3e-5 and margins["stop"] > 3e-5, margins
    assert margins["clamped"] == 0
    if case.dense:
        assert margins["stopped"] >= 10, "pixels where blending stops at T ≤ 1e-4"


@pytest.mark.parametrize("name", list(CASES))
def test_projection_matches_cpu_kernel(gsplat_impl, name):
    """gsplat's projection (means2d, conics, depths, per-axis opacity-aware radii) against abcgs's."""
    case, tol = CASES[name], gsplat_impl.tol
    scene = make_scene(case)
    ours = cpu_backend.project_cpu(scene.means, scene.quats, scene.scales, scene.opacities, scene.viewmat, scene.K,
                                   WIDTH, HEIGHT, near=case.near, far=case.far, eps2d=0.3)
    s = on(scene, gsplat_impl.device)
    radii, means2d, depths, conics, _ = gsplat.fully_fused_projection(
        s.means, None, s.quats, s.scales, s.viewmat[None], s.K[None], WIDTH, HEIGHT, eps2d=0.3, near_plane=case.near,
        far_plane=case.far, opacities=s.opacities,
    )
    radii, means2d, depths, conics = (x[0].cpu() for x in (radii, means2d, depths, conics))
    assert radii.shape == (scene.n, 2) and radii.dtype == torch.int32
    vis = (radii > 0).all(-1)
    # gsplat keeps what abcgs keeps (but for a rounding at an integer box edge, where the Gaussian reaches no pixel
    # centre); it may keep a few more (its integer box is larger) that reach no pixel centre either
    assert int((ours.visible & ~vis).sum()) <= 2
    assert int((vis & ~ours.visible).sum()) <= 0.05 * int(vis.sum())
    v = ours.visible
    assert_max_abs("means2d", means2d[v], ours.means2d[v], tol.means2d)
    assert_max_abs("depths", depths[v], ours.depths[v], tol.depth * ours.depths[v].abs().max().item())
    rel = ((conics[v] - ours.conics[v]).abs().amax(-1) / ours.conics[v].abs().amax(-1)).max().item()
    assert rel <= tol.conic, f"conics: relative difference {rel:.3g}"
    # radius rule: ceil(min(3.33, sqrt(2 ln(255 o))) · sqrt(diag of the 2-D covariance)), per axis
    a, b, c = ours.conics[v].double().unbind(-1)
    det = a * c - b * b
    sd = torch.stack([c / det, a / det], -1).sqrt()
    extend = torch.sqrt(2 * torch.log(255 * scene.opacities[v].double())).clamp(max=3.33)
    expected = torch.ceil(extend[:, None] * sd).int()
    off = (radii[v] - expected).abs()
    assert int(off.max()) <= 1 and (off == 0).float().mean() >= 0.98, "opacity-aware radii"
    assert (radii[v] <= ours.radii[v]).all(), "gsplat's radii are never above the 3.33-sigma ones"
    assert (radii[v] < ours.radii[v]).any()


@pytest.mark.parametrize("name", list(CASES))
def test_render_matches_cpu_kernel(gsplat_impl, name):
    """Images, alpha, depth (accumulated or expected), RenderMeta and the gradients of every input: the gsplat
    backend against abcgs's CPU kernel."""
    case, tol = CASES[name], gsplat_impl.tol
    scene = make_scene(case)
    weights = loss_weights(scene, case)
    want, want_g, want_m = render(scene, case, "cpu", torch.device("cpu"), weights)
    got, got_g, got_m = render(scene, case, "gsplat", gsplat_impl.device, weights)

    assert 0.2 < want["alpha"].mean() < 0.995, "degenerate scene"
    for k in ("image", "alpha"):
        assert got[k].shape == want[k].shape
        assert_max_abs(k, got[k], want[k], tol.value)
    assert got["depth"].shape == want["depth"].shape == (HEIGHT, WIDTH, 1)
    # expected depth = accumulated / alpha: its rounding error grows as 1/alpha, so it is compared times alpha
    weight = want["alpha"] if case.normalize_depth else 1.0
    assert_max_abs("depth", got["depth"] * weight, want["depth"] * weight, tol.depth * want_m.depths.abs().max().item())

    assert got_m.means2d.shape == (scene.n, 2) and got_m.radii.shape == (scene.n, 2)
    assert got_m.radii.dtype == torch.int32 and got_m.depths.shape == (scene.n,) and got_m.visible.dtype == torch.bool
    assert_same_visible(got_m.visible, want_m.visible, got_g["means2d"], want_g["means2d"])
    both = want_m.visible & got_m.visible
    assert_max_abs("means2d", got_m.means2d[both], want_m.means2d[both], tol.means2d)
    assert_max_abs("depths", got_m.depths, want_m.depths, tol.depth * want_m.depths.abs().max().item())
    diff = (got_m.radii[both] - want_m.radii[both]).abs()
    assert int(diff.max()) <= 1 and (diff == 0).float().mean() >= 0.98, "3.33-sigma radii"
    assert (got_m.radii[~got_m.visible] == 0).all()
    assert_grads_close(got_g, want_g, tol.grad * (ED_GRAD_FACTOR if case.normalize_depth else 1))


def assert_same_visible(got, want, got_grad2d, want_grad2d):
    """Equal visibility, except (by rounding at a box edge) for Gaussians that reach no pixel on either backend."""
    differ = got != want
    assert int(differ.sum()) <= 2, f"visible differs for {int(differ.sum())} Gaussians"
    assert (got_grad2d[differ] == 0).all() and (want_grad2d[differ] == 0).all()


@pytest.mark.parametrize("name", ["sh3-bg-ED-dense", "40ch-bg-D"])
def test_adapter_equals_gsplat_rasterization(gsplat_impl, name):
    """abcgs's adapter composes gsplat's steps as ``gsplat.rasterization`` does (SH + 0.5 clamped at 0, background,
    "RGB+D" / "RGB+ED", 32-channel chunks): same outputs and gradients as gsplat's public function."""
    case, tol = CASES[name], gsplat_impl.tol
    scene = on(make_scene(case), gsplat_impl.device)
    weights = [w.to(gsplat_impl.device) for w in loss_weights(scene, case)]
    bg = torch.linspace(0.1, 0.9, scene.colors.shape[-1], device=gsplat_impl.device)
    results = []
    for use_public in (False, True):
        s = scene.leaves()
        if use_public:
            out, alpha, info = gsplat.rasterization(
                *s.args()[:5], s.viewmat[None], s.K[None], WIDTH, HEIGHT, sh_degree=case.sh_degree, packed=False,
                backgrounds=bg[None], render_mode=case.render_mode,
            )
            image, depth, alpha = out[0, ..., :-1], out[0, ..., -1:], alpha[0]
            vis = (info["radii"][0] > 0).all(-1)
        else:
            image, alpha, meta = rasterize(*s.args(), sh_degree=case.sh_degree, background=bg,
                                           render_mode=case.render_mode, backend="gsplat")
            depth, vis = meta.depth, meta.visible
        loss = sum((o * w).sum() for o, w in zip((image, alpha, depth), weights))
        loss.backward()
        grads = {k: getattr(s, k).grad.cpu() for k in GRAD_FIELDS}
        results.append(({"image": image.detach().cpu(), "alpha": alpha.detach().cpu(), "depth": depth.detach().cpu()},
                        grads, vis.cpu()))
    (ours, ours_g, ours_vis), (theirs, theirs_g, theirs_kept) = results
    assert ours_vis.any() and not (ours_vis & ~theirs_kept).any()
    for k in ours:
        assert_max_abs(k, ours[k], theirs[k], tol.value * (ours["depth"].abs().max().item() if k == "depth" else 1.0))
    assert_grads_close(ours_g, theirs_g, tol.grad * (ED_GRAD_FACTOR if case.normalize_depth else 1))


def test_conventions_identical_in_float64(monkeypatch):
    """In float64 (gsplat's torch twins) the two renderers agree to rounding: no convention differs."""
    gsplat_torch.install(monkeypatch)
    case = CASES["sh3-bg-ED-dense"]
    scene = make_scene(case, torch.float64)
    weights = loss_weights(scene, case)
    want, want_g, _ = render(scene, case, "cpu", torch.device("cpu"), weights)
    got, got_g, _ = render(scene, case, "gsplat", torch.device("cpu"), weights)
    for k in want:
        assert_max_abs(k, got[k], want[k], 1e-11)
    assert_grads_close(got_g, want_g, 1e-11)


def test_densifier_statistics_match(gsplat_impl):
    """``meta.means2d.retain_grad()`` then ``.grad`` works through the gsplat backend, in the same px units as the
    CPU kernel: the densifier accumulates the same screen-gradient norms, counts and radii."""
    case = CASES["sh3-D"]
    scene = make_scene(case)
    weights = loss_weights(scene, case)
    stats = []
    for backend, device in (("cpu", torch.device("cpu")), ("gsplat", gsplat_impl.device)):
        s = on(scene, device).leaves()
        strategy = DefaultStrategy()
        model = types.SimpleNamespace(num_gaussians=scene.n, device=device)
        state = strategy.initialize_state(model)
        image, alpha, meta = rasterize(*s.args(), sh_degree=case.sh_degree, backend=backend)
        strategy.step_pre_backward(model, None, state, 1, meta)
        ((image * weights[0].to(device)).sum() + (alpha * weights[1].to(device)).sum()).backward()
        assert strategy.step_post_backward(model, None, state, 1, meta) is None
        stats.append({k: v.cpu() for k, v in state.items()})
    want, got = stats
    assert want["grad2d"].abs().max() > 0 and want["count"].sum() > 50
    assert_max_abs("grad2d", got["grad2d"], want["grad2d"], gsplat_impl.tol.grad * want["grad2d"].abs().max().item())
    assert_same_visible(got["count"] > 0, want["count"] > 0, got["grad2d"], want["grad2d"])
    same = (got["count"] > 0) == (want["count"] > 0)
    assert ((got["max_radii"] - want["max_radii"])[same].abs() <= 1).all()


def test_accumulate_weights_through_gsplat(gsplat_impl):
    """ABC-GS Eq. 2 lifting through the gsplat backend: 40 label channels (two chunks of gsplat's 32)."""
    scene = make_scene(CASES["rgb-D-dense"])
    g = torch.Generator().manual_seed(7)
    labels = torch.randint(0, 40, (HEIGHT, WIDTH), generator=g)
    masks = torch.nn.functional.one_hot(labels, 40).float()
    args = (scene.means, scene.quats, scene.scales, scene.opacities, scene.viewmat, scene.K)
    want = accumulate_weights(*args, masks, backend="cpu")
    got = accumulate_weights(*(a.to(gsplat_impl.device) for a in args), masks.to(gsplat_impl.device), backend="gsplat")
    assert got.shape == (scene.n, 40)
    assert want[:, 32:].abs().max() > 0, "the second chunk carries weight"
    assert_max_abs("weights", got.cpu(), want, gsplat_impl.tol.grad * want.abs().max().item())


def test_nothing_in_view(gsplat_impl):
    """Every Gaussian behind the camera or the near plane: background only, zero gradients, nothing visible."""
    case = CASES["sh3-bg-ED-dense"]
    scene = make_scene(case)
    R, t = scene.viewmat[:3, :3], scene.viewmat[:3, 3]
    p = scene.means @ R.T + t
    p[:, 2] = torch.linspace(-2.0, 0.009, scene.n)
    scene = replace(scene, means=(p - t) @ R)
    out, grads, meta = render(scene, case, "gsplat", gsplat_impl.device, loss_weights(scene, case))
    assert not meta.visible.any() and (meta.radii == 0).all()
    assert (out["alpha"] == 0).all() and (out["depth"] == 0).all()
    torch.testing.assert_close(out["image"], torch.linspace(0.1, 0.9, 3).expand(HEIGHT, WIDTH, 3))
    for k in GRAD_FIELDS + ("means2d",):
        assert (grads[k] == 0).all(), k
    torch.testing.assert_close(meta.depths, p[:, 2], rtol=1e-5, atol=1e-5)


def test_alpha_cap_differs(gsplat_impl):
    """The one convention that differs: alpha is capped at 0.99 by abcgs (3DGS) and 0.999 by gsplat, so an opaque
    Gaussian's centre pixel has alpha 0.99 on the CPU backends and 0.999 with gsplat. (The test scenes keep
    opacities ≤ 0.98, where no cap applies.)"""
    f32 = torch.float32
    # centred on pixel (32, 24)'s centre: sigma = 0 there, so o·exp(-sigma) = 1 hits each cap
    args = (torch.tensor([[0.0, 0.0, 2.0]], dtype=f32), torch.tensor([[1.0, 0, 0, 0]]), torch.full((1, 3), 0.2), torch.ones(1), torch.ones(1, 3),
            torch.eye(4), torch.tensor([[64.0, 0, 32.5], [0, 64.0, 24.5], [0, 0, 1]]), WIDTH, HEIGHT)
    _, alpha_cpu, _ = rasterize(*args, backend="cpu")
    _, alpha_gs, _ = rasterize(*(a.to(gsplat_impl.device) if isinstance(a, torch.Tensor) else a for a in args),
                               backend="gsplat")
    assert alpha_cpu[24, 32, 0].item() == pytest.approx(0.99, abs=1e-6)
    assert alpha_gs[24, 32, 0].item() == pytest.approx(0.999, abs=1e-6)


@pytest.mark.parametrize("version", ["1.5.0", "1.5.3", "1.5.3+cu124", "1.5.9.dev1"])
def test_tested_gsplat_versions_pass(monkeypatch, version):
    monkeypatch.setattr(gsplat, "__version__", version)
    monkeypatch.setattr(rasterize_module, "_warned", set())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert rasterize_module._import_gsplat() is gsplat


@pytest.mark.parametrize("version", ["1.4.0", "1.3.0", "0.1.12"])
def test_old_gsplat_is_refused(monkeypatch, version):
    monkeypatch.setattr(gsplat, "__version__", version)
    with pytest.raises(BackendUnavailable) as info:
        rasterize_module._import_gsplat()
    msg = str(info.value)
    assert version in msg and "gsplat>=1.5,<1.6" in msg and "pip install" in msg


@pytest.mark.parametrize("version", ["1.6.0", "2.0.1", "nightly"])
def test_untested_gsplat_warns(monkeypatch, version):
    monkeypatch.setattr(gsplat, "__version__", version)
    monkeypatch.setattr(rasterize_module, "_warned", set())
    with pytest.warns(RuntimeWarning, match=r"gsplat>=1\.5,<1\.6") as record:
        assert rasterize_module._import_gsplat() is gsplat
    assert version in str(record[0].message)


def test_pyproject_pins_the_tested_versions():
    """The ``cuda`` extra pins the range the adapter is tested with; the ``test`` extra installs the gsplat these
    tests run."""
    text = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
    extras = dict(re.findall(r"^(\w+) = \[(.*)\]$", text, flags=re.M))
    assert f'"gsplat{rasterize_module.GSPLAT_TESTED}"' in extras["cuda"]
    assert f'"gsplat=={gsplat.__version__}"' in extras["test"]
    assert rasterize_module.gsplat_version_problem(gsplat.__version__) is None
