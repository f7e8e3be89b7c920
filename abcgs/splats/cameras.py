"""Cameras made around a splat that comes without any, so that a bare ``.splat``/``.ply``/``.spz`` can be stylized.

    cams, kind = cameras_around(model, "auto", count=24, width=480, height=360)

Sizes come from robust bounds of the Gaussians (opacity-weighted 5 % / 95 % quantiles of the means along their
principal axes, :func:`splat_frame`), so floaters and a far background do not push the cameras away:

- ``orbit``: a ring around the axis of least spread (the "up" of an object on a table), 20° above its equator, at the
  distance where the bounds fill the field of view (× 1.2), every camera looking at the centre; image "down" is
  that axis;
- ``forward``: a 4 × ⌈count/4⌉ grid of cameras in a plane facing the splat along its size gradient (below), spread
  over ±15 % of the width, from the side of the small Gaussians, at the distance where the 10–90 % quantiles across
  fill the field of view, all looking at their centre;
- ``auto``: ``forward`` when the Gaussians grow across the splat: a splat trained from one side has Gaussians whose
  size grows with their distance from the cameras (each covers a few pixels there), so ``log σ_max`` regressed on
  position (opacity-weighted, inside the bounds) has a gradient pointing away from them; when it changes ``log σ_max``
  by :data:`FORWARD_MIN_LOG_GROWTH` or more across the bounds, the views come from the small side (fern: 2.9, its
  gradient 16° from the capture's mean viewing direction). Else ``orbit`` (an object seen from all round).

The roll of the views follows the principal axes, whose sign is arbitrary, so a generated view may be tilted or upside
down relative to the capture that trained the splat; stylization does not depend on it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel

FORWARD_MIN_LOG_GROWTH = 0.7
"""``auto`` picks forward-facing views when the Gaussians' ``log σ_max`` grows by this much across the bounds
(σ × 2 at 0.69)."""
QUANTILE = 0.05
FORWARD_QUANTILE = 0.1
"""Forward-facing views frame the 10–90 % quantiles across and along the viewing direction (a facing capture's
floaters and far background would otherwise push the cameras back)."""


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


def cameras_around(
    model: GaussianModel, kind: Literal["auto", "orbit", "forward"] = "auto", count: int = 24,
    width: int = 480, height: int = 360, fov_deg: float = 50.0,
) -> tuple[list[Camera], str]:
    """``count`` pinhole cameras ``width`` × ``height`` with horizontal field of view ``fov_deg`` placed around
    ``model`` (module docstring); returns them and the kind used (``orbit`` or ``forward``, also in each camera's
    ``meta["views_kind"]``)."""
    if count < 1:
        raise InputError(f"views.count must be at least 1, got {count}")
    fr = splat_frame(model)
    used = kind
    if kind == "auto":
        used = "forward" if fr.log_growth() >= FORWARD_MIN_LOG_GROWTH else "orbit"
    focal = width / 2 / np.tan(np.radians(fov_deg) / 2)
    K = intrinsics(focal, width, height)
    tan_half = min(width, height) / 2 / focal  # the narrower half-angle: the bounds must fit both ways
    a0, a1, a2 = fr.axes
    out = []
    if used == "orbit":
        radius = 1.2 * float(np.linalg.norm(fr.half_extent)) / tan_half
        up = a2
        elev = np.radians(20.0)
        for i, t in enumerate(np.linspace(0.0, 2 * np.pi, count, endpoint=False)):
            eye = fr.centre + radius * (np.cos(elev) * (np.cos(t) * a0 + np.sin(t) * a1) + np.sin(elev) * up)
            out.append(Camera(f"view_{i:03d}.png", K.copy(), look_at(eye, fr.centre, up=-up), width, height,
                              {"views_kind": used}))
    elif used == "forward":
        g = fr.size_gradient
        a2 = g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else fr.axes[2]  # viewing direction: towards larger
        a0 = fr.axes[0] - (fr.axes[0] @ a2) * a2 if abs(fr.axes[0] @ a2) < 0.9 else fr.axes[1] - (fr.axes[1] @ a2) * a2
        a0 /= np.linalg.norm(a0)
        a1 = np.cross(a2, a0)
        with torch.no_grad():
            x = model.means.double().cpu().numpy() - fr.centre
            w = model.opacities.double().cpu().numpy() + 1e-6
        q = np.stack([_wquantile(x @ a, w, (FORWARD_QUANTILE, 1 - FORWARD_QUANTILE)) for a in (a0, a1, a2)])
        h0, h1, h2 = np.maximum((q[:, 1] - q[:, 0]) / 2, 1e-6)
        centre = fr.centre + np.stack([a0, a1, a2]).T @ q.mean(axis=1)
        dist = max(h0, h1 * width / height) / np.tan(np.radians(fov_deg) / 2) + h2
        side = -1.0  # cameras on the small-Gaussian side
        cols = 4 if count >= 4 else count
        rows = -(-count // cols)
        spread = 0.15 * h0
        for i in range(count):
            r, c = divmod(i, cols)
            u = (c / max(cols - 1, 1) - 0.5) * 2 * spread
            v = (r / max(rows - 1, 1) - 0.5) * 2 * spread * height / width if rows > 1 else 0.0
            eye = centre + side * dist * a2 + u * a0 + v * a1
            out.append(Camera(f"view_{i:03d}.png", K.copy(), look_at(eye, centre, up=-a1), width, height,
                              {"views_kind": used}))
    else:
        raise InputError(f"views.kind must be auto, orbit or forward, got {kind!r}")
    return out, used
