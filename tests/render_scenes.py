"""Random Gaussian scenes for the renderer tests (importable helper, not a test module).

    scene = random_scene(8, 12, 10, torch.float64, seed=0, scale_range=(0.3, 0.8))
    image, alpha, meta = rasterize(*scene.args(), backend="reference")

Gaussians are generated in camera space inside the view frustum (optionally with a margin so some
straddle the border), then mapped to world space through a random rigid camera pose, so the
world→camera transform is exercised too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import torch
from torch import Tensor

from abcgs.render.projection import ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_EPS, project_gaussians
from abcgs.render.sh import num_sh_bases
from abcgs.runtime import torch_threads  # noqa: F401  (re-exported for the tests)

GRAD_FIELDS = ("means", "quats", "scales", "opacities", "colors")


@dataclass
class Scene:
    means: Tensor  # (N, 3) world
    quats: Tensor  # (N, 4) wxyz, not normalised
    scales: Tensor  # (N, 3) world units
    opacities: Tensor  # (N,)
    colors: Tensor  # (N, C) or SH (N, K, 3)
    viewmat: Tensor  # (4, 4) world -> camera
    K: Tensor  # (3, 3)
    width: int
    height: int

    def args(self) -> tuple:
        """Positional arguments of :func:`abcgs.render.rasterize`."""
        return (
            self.means, self.quats, self.scales, self.opacities, self.colors, self.viewmat, self.K, self.width, self.height
        )

    def leaves(self, names=GRAD_FIELDS) -> Scene:
        """A copy whose ``names`` fields are fresh leaf tensors requiring grad."""
        return replace(self, **{n: getattr(self, n).detach().clone().requires_grad_(True) for n in names})

    def to(self, dtype: torch.dtype) -> Scene:
        kw = {}
        for f in fields(self):
            v = getattr(self, f.name)
            kw[f.name] = v.detach().to(dtype) if isinstance(v, Tensor) and v.is_floating_point() else v
        return replace(self, **kw)

    @property
    def n(self) -> int:
        return self.means.shape[0]


def look_rotation(rng: torch.Generator, max_angle: float, dtype: torch.dtype) -> Tensor:
    """A random rotation matrix of angle ≤ ``max_angle`` rad (Rodrigues)."""
    axis = torch.randn(3, generator=rng, dtype=torch.float64)
    axis = axis / axis.norm()
    ang = float(torch.rand((), generator=rng, dtype=torch.float64)) * max_angle
    Kx = torch.tensor([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]], dtype=torch.float64)
    R = torch.eye(3, dtype=torch.float64) + math.sin(ang) * Kx + (1 - math.cos(ang)) * Kx @ Kx
    return R.to(dtype)


def random_scene(
    n: int,
    width: int,
    height: int,
    dtype: torch.dtype = torch.float32,
    seed: int = 0,
    *,
    scale_range: tuple[float, float] = (0.03, 0.3),
    depth_range: tuple[float, float] = (2.0, 5.0),
    opacity_range: tuple[float, float] = (0.1, 0.9),
    channels: int = 3,
    sh_degree: int | None = None,
    margin: float = 0.1,
    focal: float | None = None,
    max_rotation: float = 0.5,
) -> Scene:
    """N random Gaussians in front of a pinhole camera.

    Args:
        scale_range: per-axis standard deviations, log-uniform, in world units (a Gaussian of scale s at
            depth z has a screen sigma of about ``focal · s / z`` px; ``focal`` defaults to ``width``).
        depth_range: camera-space z of the centres.
        margin: centres fall in the image widened by this fraction on each side.
        channels: colour channels (ignored when ``sh_degree`` is set: colours are then SH ``(N, K, 3)``).
        max_rotation: camera pose rotation angle bound (rad).
    """
    g = torch.Generator().manual_seed(seed)
    f64 = torch.float64

    def U(lo, hi, *shape):
        return lo + (hi - lo) * torch.rand(*shape, generator=g, dtype=f64)

    fx = float(focal if focal is not None else width)
    cx, cy = width / 2.0, height / 2.0
    K = torch.tensor([[fx, 0.0, cx], [0.0, fx, cy], [0.0, 0.0, 1.0]], dtype=f64)
    z = U(*depth_range, n)
    u = U(-margin * width, (1 + margin) * width, n)
    v = U(-margin * height, (1 + margin) * height, n)
    p_cam = torch.stack([(u - cx) / fx * z, (v - cy) / fx * z, z], -1)

    R = look_rotation(g, max_rotation, f64)  # world -> camera rotation
    t = torch.randn(3, generator=g, dtype=f64)
    viewmat = torch.eye(4, dtype=f64)
    viewmat[:3, :3], viewmat[:3, 3] = R, t
    means = (p_cam - t) @ R  # inverse rigid transform: R^T (p - t)

    quats = torch.randn(n, 4, generator=g, dtype=f64)
    lo, hi = math.log(scale_range[0]), math.log(scale_range[1])
    scales = torch.exp(U(lo, hi, n, 3))
    opacities = U(*opacity_range, n)
    if sh_degree is None:
        colors = torch.rand(n, channels, generator=g, dtype=f64)
    else:
        colors = 0.3 * torch.randn(n, num_sh_bases(sh_degree), 3, generator=g, dtype=f64)
        colors[:, 0] += 1.0
    return Scene(means, quats, scales, opacities, colors, viewmat, K, width, height).to(dtype)


def blend_margins(scene: Scene, **proj_kwargs) -> dict[str, float]:
    """How far a scene is from the blending rule's discontinuities, over all (pixel, Gaussian) pairs.

    Returns the smallest relative distance of the raw alpha ``o·exp(-sigma)`` to the 1/255 skip threshold
    and to the 0.99 clamp, and of the running transmittance ``T·(1-alpha)`` to the 1e-4 stop, along
    each pixel's depth-sorted list (brute force; tiny scenes only). A finite-difference step that changes
    alpha by a relative amount well below these margins cannot flip a skip/clamp/stop decision.
    Also counts the (pixel, Gaussian) pairs whose alpha is clamped and the pixels where blending stops,
    so that a test can assert it exercises those branches.
    """
    with torch.no_grad():
        s = scene.to(torch.float64)
        proj = project_gaussians(s.means, s.quats, s.scales, s.opacities, s.viewmat, s.K, s.width, s.height, **proj_kwargs)
        vis = torch.nonzero(proj.visible).squeeze(1)
        vis = vis[torch.argsort(proj.depths[vis], stable=True)]
        ys, xs = torch.meshgrid(
            torch.arange(s.height, dtype=torch.float64) + 0.5,
            torch.arange(s.width, dtype=torch.float64) + 0.5,
            indexing="ij",
        )
        px, py = xs.reshape(-1), ys.reshape(-1)
        m, con, o = proj.means2d[vis], proj.conics[vis], s.opacities[vis]
        dx, dy = px[:, None] - m[None, :, 0], py[:, None] - m[None, :, 1]
        sigma = 0.5 * (con[None, :, 0] * dx * dx + con[None, :, 2] * dy * dy) + con[None, :, 1] * dx * dy
        raw = o[None] * torch.exp(-sigma)
        inf = torch.tensor(float("inf"), dtype=torch.float64)
        thr = (raw / ALPHA_THRESHOLD).log().abs().min() if raw.numel() else inf
        clamp = (raw / MAX_ALPHA).log().abs().min() if raw.numel() else inf
        alpha = torch.where(raw >= ALPHA_THRESHOLD, raw.clamp(max=MAX_ALPHA), torch.zeros_like(raw))
        logT = torch.cumsum(torch.log1p(-alpha), dim=1)
        stop = (logT - math.log(TRANSMITTANCE_EPS)).abs().min() if raw.numel() else inf
        clamped = int((raw > MAX_ALPHA).sum())
        stopped = int((logT <= math.log(TRANSMITTANCE_EPS)).any(dim=1).sum()) if raw.numel() else 0
    return {"threshold": float(thr), "clamp": float(clamp), "stop": float(stop), "clamped": clamped, "stopped": stopped}


def finite_difference_check(
    f, inputs: dict[str, Tensor], eps: float = 1e-6, atol: float = 1e-6, rtol: float = 1e-5
) -> dict[str, tuple[float, float]]:
    """Compare autograd with central differences for every element of every input.

    ``f(**inputs)`` returns a vector of ``K`` scalar losses (e.g. one per output kind); all K gradients
    come from one forward pass per perturbation. Raises AssertionError naming the worst (loss, input)
    pair when ``|analytic - numeric| > atol + rtol·|numeric|`` anywhere; returns
    ``{input: (max abs error, max |numeric|)}``.
    """
    leaves = {k: v.detach().clone().requires_grad_(True) for k, v in inputs.items()}
    losses = f(**leaves)
    assert losses.dim() == 1 and losses.dtype == torch.float64
    analytic = {k: torch.zeros((losses.numel(),) + v.shape, dtype=torch.float64) for k, v in inputs.items()}
    for j in range(losses.numel()):
        grads = torch.autograd.grad(losses[j], list(leaves.values()), retain_graph=True, allow_unused=True)
        for k, g in zip(leaves, grads):
            if g is not None:
                analytic[k][j] = g
    report, failures = {}, []
    with torch.no_grad():
        for k, v in inputs.items():
            flat = v.detach().clone().reshape(-1)
            numeric = torch.zeros(losses.numel(), flat.numel(), dtype=torch.float64)
            for i in range(flat.numel()):
                x0 = flat[i].item()
                flat[i] = x0 + eps
                fp = f(**{**inputs, k: flat.view(v.shape)})
                flat[i] = x0 - eps
                fm = f(**{**inputs, k: flat.view(v.shape)})
                flat[i] = x0
                numeric[:, i] = (fp - fm) / (2 * eps)
            a = analytic[k].reshape(losses.numel(), -1)
            err = (a - numeric).abs()
            report[k] = (float(err.max()) if err.numel() else 0.0, float(numeric.abs().max()) if err.numel() else 0.0)
            bad = err > atol + rtol * numeric.abs()
            if bad.any():
                j, i = (int(t[0]) for t in torch.nonzero(bad, as_tuple=True))
                failures.append(
                    f"d loss[{j}] / d {k}.flat[{i}]: autograd {a[j, i].item():.10g} vs FD {numeric[j, i].item():.10g}"
                )
    assert not failures, "gradient mismatch:\n" + "\n".join(failures) + f"\n(max abs err, max |grad|) per input: {report}"
    return report
