"""Cameras made around a splat that comes without any, so that a bare ``.splat``/``.ply``/``.spz`` can be stylized.

    cams, kind = cameras_around(model, "auto", count=24, width=480, height=360)

Sizes come from robust bounds of the Gaussians (opacity-weighted 5 % / 95 % quantiles of the means along their
principal axes, :func:`splat_frame`), so floaters and a far background do not push the cameras away:

- ``orbit``: a ring around the axis of least spread (the "up" of an object on a table), 20° above its equator, at the
  distance where the bounds fill the field of view (× 1.2), every camera looking at the centre; image "down" is
  that axis;
- ``forward``: a 4 × ⌈count/4⌉ grid of cameras in a plane facing the bounds along the depth axis, spread over ±15 % of
  the width, from the side of the shorter tail, all looking at the centre; the widest of the two other axes runs
  across the image;
- ``auto``: ``forward`` when one principal axis is lopsided — the distance from the median to one quantile exceeds
  the other by :data:`FORWARD_MIN_ASYMMETRY` of the range or more, as a forward-facing capture's far background
  makes it (that axis is the depth axis) — else ``orbit`` (a compact or symmetric splat, e.g. an object with the
  room around it).
 The sign of a principal axis is
arbitrary, so a generated view may be upside down relative to the capture that trained the splat; stylization does
not depend on it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel

FORWARD_MIN_ASYMMETRY = 0.3
"""``auto`` picks forward-facing views when an axis's quantile tails differ by this fraction of its 5–95 % range."""
QUANTILE = 0.05


@dataclass(frozen=True)
class SplatFrame:
    """Robust bounds of a splat along its principal axes.

    Attributes:
        centre: ``(3,)`` opacity-weighted median of the means (world units).
        axes: ``(3, 3)`` rows: unit principal axes, largest spread first.
        half_extent: ``(3,)`` half the 5–95 % quantile range along each axis (world units).
        tails: ``(3,)`` for each axis, (95 % − median) − (median − 5 %): positive when the far tail is on the + side.
    """

    centre: np.ndarray
    axes: np.ndarray
    half_extent: np.ndarray
    tails: np.ndarray


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
    tails = (qs[:, 2] - qs[:, 1]) - (qs[:, 1] - qs[:, 0])
    return SplatFrame(med + axes.T @ ((qs[:, 0] + qs[:, 2]) / 2), axes, half, tails)


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
    asym = np.abs(fr.tails) / (2 * fr.half_extent)
    used = kind
    if kind == "auto":
        used = "forward" if asym.max() >= FORWARD_MIN_ASYMMETRY else "orbit"
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
        depth = int(np.argmax(asym))
        across, down = (i for i in range(3) if i != depth)  # principal order: the wider spread runs across
        a0, a1, a2 = fr.axes[across], fr.axes[down], fr.axes[depth]
        h0, h1, h2 = fr.half_extent[across], fr.half_extent[down], fr.half_extent[depth]
        side = -1.0 if fr.tails[depth] > 0 else 1.0  # cameras on the short-tail side
        dist = 1.2 * max(h0, h1 * width / height) / np.tan(np.radians(fov_deg) / 2) + h2
        cols = 4 if count >= 4 else count
        rows = -(-count // cols)
        spread = 0.15 * h0
        for i in range(count):
            r, c = divmod(i, cols)
            u = (c / max(cols - 1, 1) - 0.5) * 2 * spread
            v = (r / max(rows - 1, 1) - 0.5) * 2 * spread * height / width if rows > 1 else 0.0
            eye = fr.centre + side * dist * a2 + u * a0 + v * a1
            out.append(Camera(f"view_{i:03d}.png", K.copy(), look_at(eye, fr.centre, up=-a1), width, height,
                              {"views_kind": used}))
    else:
        raise InputError(f"views.kind must be auto, orbit or forward, got {kind!r}")
    return out, used


@dataclass
class SourceView:
    """One view of a source scene: its image file and calibrated camera (``distortion``: OpenCV coefficients or
    ``None``; ``mask_path``: a label PNG or ``None``)."""

    name: str
    image_path: Path
    camera: Camera
    distortion: np.ndarray | None = None
    mask_path: Path | None = None


@dataclass
class SourceScene:
    """A scene read from a source (here: a bare splat) before the reconstruct stage writes it as a COLMAP model.

    Attributes:
        format: the source's kind. views: the views. points: ``(M, 3) float32`` world points or ``None``.
        colors: ``(M, 3) float32`` their RGB in ``[0, 1]``. frame: ``(4, 4)`` source frame → scene frame.
    """

    format: str
    views: list[SourceView]
    points: np.ndarray | None = None
    colors: np.ndarray | None = None
    frame: np.ndarray = field(default_factory=lambda: np.eye(4))
