"""Cameras made around a splat that comes without any, so that a bare ``.splat``/``.ply``/``.spz`` can be stylized.

    cams, kind = cameras_around(model, SplatViewsParams(count=24, width=480, height=360))

Every view is upright: the world direction ``params.up`` (``auto``: ``-y``, the COLMAP/INRIA convention that 3DGS
trainers save in) points up in the image.

- ``orbit`` (an object): ``count`` views on rings at elevations spread over ``params.elevation_deg`` above the
  horizon (3 rings from 12 views, 2 from 6), each ring's azimuths offset by half a step from the one below, all
  looking at the centre of the box around the Gaussians that matter (opacity ≥ ``params.min_opacity``), from one
  distance: the least at which every such Gaussian, two standard deviations around its centre, lies inside every view
  (:func:`framing_distance`), × :data:`FRAME_MARGIN`. The whole object is in every view; nothing is cropped.
- ``forward`` (a scene seen from one side): a 4 × ⌈count/4⌉ grid of views on a sphere around the splat's centre,
  ``params.parallax_deg`` between the outermost columns (a quarter of it between the outermost rows), facing the
  splat along its size gradient (below) from the side of the small Gaussians, at the distance where the 10–90 %
  quantiles across fill the field of view (floaters and a far background would otherwise push the cameras back).
  An object on nothing (``object_scene``: its scene has a background, as every bare splat in the stages) is framed
  as by orbit views instead: looking at the centre of the box around the Gaussians that matter, from the least
  distance at which all of them lie inside every view, × :data:`FRAME_MARGIN`; a flat object seen from one side is
  whole in every view.
- ``auto``: ``forward`` when the Gaussians grow across the splat: a splat trained from one side has Gaussians whose
  size grows with their distance from the cameras (each covers a few pixels there), so ``log σ_max`` regressed on
  position (opacity-weighted, inside the robust bounds of :func:`splat_frame`) has a gradient pointing away from them;
  when it changes ``log σ_max`` by :data:`FORWARD_MIN_LOG_GROWTH` or more across the bounds, the views come from the
  small side (fern: 2.9, its gradient 16° from the capture's mean viewing direction). Else ``orbit``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.splats.params import SplatViewsParams, UpAxis

FORWARD_MIN_LOG_GROWTH = 0.7
"""``auto`` picks forward-facing views when the Gaussians' ``log σ_max`` grows by this much across the bounds
(σ × 2 at 0.69)."""
QUANTILE = 0.05
FORWARD_QUANTILE = 0.1
"""Forward-facing views frame the 10–90 % quantiles across and along the viewing direction (a facing capture's
floaters and far background would otherwise push the cameras back)."""
FRAME_MARGIN = 1.08
"""Orbit views stand this much further back than the least distance that frames every Gaussian that matters."""
SIGMA_EXTENT = 2.0
"""A Gaussian that matters must lie inside a view with this many standard deviations around its centre."""
UP_AXES: dict[str, tuple[float, float, float]] = {
    "+x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0), "+y": (0.0, 1.0, 0.0), "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0),
}


@dataclass(frozen=True)
class SplatFrame:
    """Robust bounds of a splat along its principal axes.

    Attributes:
        centre: ``(3,)`` opacity-weighted median of the means (world units).
        axes: ``(3, 3)`` rows: unit principal axes, largest spread first.
        half_extent: ``(3,)`` half the 5–95 % quantile range along each axis (world units).
        size_gradient: ``(3,)`` world gradient of ``log σ_max`` (per world unit), opacity-weighted least squares over
            the Gaussians inside the bounds.
    """

    centre: np.ndarray
    axes: np.ndarray
    half_extent: np.ndarray
    size_gradient: np.ndarray

    def log_growth(self) -> float:
        """How much ``log σ_max`` changes across the bounds along the size gradient."""
        return float(np.abs(self.axes @ self.size_gradient) @ (2 * self.half_extent))


def _wquantile(v: np.ndarray, w: np.ndarray, qs: tuple[float, ...]) -> np.ndarray:
    order = np.argsort(v)
    cw = np.cumsum(w[order])
    return np.array([v[order][min(np.searchsorted(cw, q * cw[-1]), len(v) - 1)] for q in qs])


def splat_frame(model: GaussianModel) -> SplatFrame:
    """The robust bounds of ``model`` (see the module docstring)."""
    if model.num_gaussians < 4:
        raise InputError(f"a splat of {model.num_gaussians} Gaussians has no extent to place cameras around")
    with torch.no_grad():
        x = model.means.double().cpu().numpy()
        w = model.opacities.double().cpu().numpy() + 1e-6
        log_size = model.log_scales.double().max(dim=1).values.cpu().numpy()
    if not np.isfinite(x).all():
        raise InputError("the splat has NaN/Inf positions; it is corrupt")
    med = np.array([_wquantile(x[:, a], w, (0.5,))[0] for a in range(3)])
    d = x - med
    cov = (d * w[:, None]).T @ d / w.sum()
    vals, vecs = np.linalg.eigh(cov)
    axes = vecs[:, np.argsort(vals)[::-1]].T
    proj = d @ axes.T
    qs = np.stack([_wquantile(proj[:, a], w, (QUANTILE, 0.5, 1 - QUANTILE)) for a in range(3)])
    half = np.maximum((qs[:, 2] - qs[:, 0]) / 2, 1e-6)
    inside = ((proj >= qs[:, 0]) & (proj <= qs[:, 2])).all(axis=1)
    a = np.c_[np.ones(inside.sum()), proj[inside]] * np.sqrt(w[inside])[:, None]
    coef, *_ = np.linalg.lstsq(a, log_size[inside] * np.sqrt(w[inside]), rcond=None)
    return SplatFrame(med + axes.T @ ((qs[:, 0] + qs[:, 2]) / 2), axes, half, axes.T @ coef[1:])


def world_up(up: UpAxis) -> np.ndarray:
    """``(3,)`` the unit world direction that ``up`` names (``auto``: ``-y``)."""
    return np.array(UP_AXES["-y" if up == "auto" else up])


def view_basis(direction: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image right and image down ``(3,)`` (world, unit) of a camera looking along ``-direction`` with ``up`` up in the
    image; a view along ``up`` itself takes the world axis least aligned with it as its up."""
    forward = -direction / np.linalg.norm(direction)
    u = up - (up @ forward) * forward
    if np.linalg.norm(u) < 1e-6:
        alt = np.eye(3)[int(np.argmin(np.abs(forward)))]
        u = alt - (alt @ forward) * forward
    u /= np.linalg.norm(u)
    right = np.cross(-u, forward)  # OpenCV axes: x = y × z with y = -u (down), z = forward
    return right, -u


def framing_distance(points: np.ndarray, radii: np.ndarray, centre: np.ndarray, directions: np.ndarray,
                     up: np.ndarray, tan_half_x: float, tan_half_y: float) -> float:
    """The least distance from ``centre`` along every unit ``directions`` ``(V, 3)`` at which a camera looking at
    ``centre`` sees every ball (``points`` ``(N, 3)``, ``radii`` ``(N,)``, world units) inside its field of view
    (half-angle tangents ``tan_half_x``, ``tan_half_y``), and stands outside them all.

    For a point ``p`` (from the centre) with image offsets ``x``, ``y`` and depth ``d - p·v`` from a camera at distance
    ``d`` along ``v``, it is inside when ``|x| + r ≤ tan_half_x · (d - p·v)`` (and likewise for ``y``), so
    ``d = max(|x| + r) / tan_half_x + p·v`` over the points, the larger of the two axes, the largest over the views.
    """
    p = points - centre
    need = float(np.max(np.linalg.norm(p, axis=1) + radii))  # outside every ball
    for v in directions:
        right, down = view_basis(v, up)
        along = p @ v
        x = (np.abs(p @ right) + radii) / tan_half_x + along
        y = (np.abs(p @ down) + radii) / tan_half_y + along
        need = max(need, float(np.max(np.maximum(x, y))))
    return need


def orbit_directions(count: int, elevation_deg: tuple[float, float], up: np.ndarray) -> np.ndarray:
    """``(count, 3)`` unit directions from the centre: rings at elevations spread over ``elevation_deg`` (3 rings from
    12 views, 2 from 6, else 1, lowest first), ``count`` split as evenly as possible, each ring's azimuths offset
    by half a step from the ring below."""
    rings = 3 if count >= 12 else 2 if count >= 6 else 1
    lo, hi = np.radians(elevation_deg[0]), np.radians(elevation_deg[1])
    elevations = [0.5 * (lo + hi)] if rings == 1 else np.linspace(lo, hi, rings)
    sizes = [count // rings + (1 if r < count % rings else 0) for r in range(rings)]
    a = np.eye(3)[int(np.argmin(np.abs(up)))]
    e0 = a - (a @ up) * up
    e0 /= np.linalg.norm(e0)
    e1 = np.cross(up, e0)
    out = []
    for r, (elev, n) in enumerate(zip(elevations, sizes)):
        for t in (np.arange(n) + 0.5 * (r % 2)) * (2 * np.pi / n):
            out.append(np.cos(elev) * (np.cos(t) * e0 + np.sin(t) * e1) + np.sin(elev) * up)
    return np.asarray(out)


def visible_balls(model: GaussianModel, min_opacity: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Gaussians that matter (opacity ≥ ``min_opacity``; the 4 most opaque when fewer do) as balls: centres
    ``(N, 3)``, radii :data:`SIGMA_EXTENT` × σ_max ``(N,)`` (world units), and the centre ``(3,)`` of their box."""
    with torch.no_grad():
        x = model.means.double().cpu().numpy()
        opacity = model.opacities.double().cpu().numpy()
        sigma = model.scales.double().max(dim=1).values.cpu().numpy()
    keep = opacity >= min_opacity
    if keep.sum() < 4:
        keep = opacity >= np.sort(opacity)[-4]
    pts, radii = x[keep], SIGMA_EXTENT * sigma[keep]
    return pts, radii, 0.5 * ((pts - radii[:, None]).min(axis=0) + (pts + radii[:, None]).max(axis=0))


def forward_directions(count: int, parallax_deg: float, right: np.ndarray, down: np.ndarray,
                       along: np.ndarray) -> np.ndarray:
    """``(count, 3)`` unit directions from the target to the cameras of a 4 × ⌈count/4⌉ grid facing ``along`` (the
    central view's image ``right`` and ``down``): ``parallax_deg`` between the outermost columns, a quarter of it
    between the outermost rows."""
    cols = 4 if count >= 4 else count
    rows = -(-count // cols)
    half_az, half_el = np.radians(parallax_deg) / 2, np.radians(parallax_deg) / 8
    out = []
    for i in range(count):
        r, c = divmod(i, cols)
        az = (c / max(cols - 1, 1) - 0.5) * 2 * half_az if cols > 1 else 0.0
        el = (r / max(rows - 1, 1) - 0.5) * 2 * half_el if rows > 1 else 0.0
        out.append(-along * np.cos(az) * np.cos(el) + right * np.sin(az) * np.cos(el) - down * np.sin(el))
    return np.asarray(out)


def _quantile_framing(model: GaussianModel, fr: SplatFrame, axes: np.ndarray, fov_deg: float,
                      aspect: float) -> tuple[np.ndarray, float]:
    """A forward-facing scene's target ``(3,)`` and distance: the 10–90 % quantiles along ``axes`` (rows: image right,
    image down, viewing direction) fill the field of view (``fov_deg`` across, ``aspect`` = width / height)."""
    with torch.no_grad():
        x = model.means.double().cpu().numpy()
        w = model.opacities.double().cpu().numpy() + 1e-6
    q = np.stack([_wquantile((x - fr.centre) @ a, w, (FORWARD_QUANTILE, 1 - FORWARD_QUANTILE)) for a in axes])
    h0, h1, h2 = np.maximum((q[:, 1] - q[:, 0]) / 2, 1e-6)
    return fr.centre + axes.T @ q.mean(axis=1), max(h0, h1 * aspect) / np.tan(np.radians(fov_deg) / 2) + h2


def cameras_around(model: GaussianModel, params: SplatViewsParams | None = None, *,
                   object_scene: bool = False) -> tuple[list[Camera], str]:
    """The pinhole cameras of ``params`` (count, size, horizontal field of view, kind, up; module docstring) around
    ``model``; returns them and the kind used (``orbit`` or ``forward``, also in each camera's
    ``meta["views_kind"]``). ``object_scene``: the splat is an object on nothing (its scene has a background), so
    forward views too frame every Gaussian that matters, as orbit views always do; else they frame its quantiles."""
    params = params or SplatViewsParams()
    count, width, height, fov_deg = params.count, params.width, params.height, params.fov_deg
    if count < 1:
        raise InputError(f"views.count must be at least 1, got {count}")
    if params.kind not in ("auto", "orbit", "forward"):
        raise InputError(f"views.kind must be auto, orbit or forward, got {params.kind!r}")
    fr = splat_frame(model)
    used = params.kind
    if used == "auto":
        used = "forward" if fr.log_growth() >= FORWARD_MIN_LOG_GROWTH else "orbit"
    focal = width / 2 / np.tan(np.radians(fov_deg) / 2)
    K = intrinsics(focal, width, height)
    up = world_up(params.up)
    if used == "orbit":
        dirs = orbit_directions(count, params.elevation_deg, up)
    else:
        g = fr.size_gradient
        a2 = g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else fr.axes[2]  # viewing direction: towards larger
        a0, a1 = view_basis(-a2, up)  # image right and down of the central view
        dirs = forward_directions(count, params.parallax_deg, a0, a1, a2)
    if used == "orbit" or object_scene:
        pts, radii, target = visible_balls(model, params.min_opacity)
        dist = FRAME_MARGIN * framing_distance(pts, radii, target, dirs, up, width / 2 / focal, height / 2 / focal)
    else:
        target, dist = _quantile_framing(model, fr, np.stack([a0, a1, a2]), fov_deg, width / height)
    return [Camera(f"view_{i:03d}.png", K.copy(), look_at(target + dist * v, target, up=-up), width, height,
                   {"views_kind": used}) for i, v in enumerate(dirs)], used
