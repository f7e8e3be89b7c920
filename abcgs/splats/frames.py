"""Frames of splat files, and moving Gaussians between them.

A splat file stores its Gaussians in the frame of the tool that trained it; the scene (cameras, photos) lives in the
frame of its dataset. The map between them is a similarity ``x_file = s · R @ x_scene + t`` (:class:`Similarity`, a
proper rotation ``R``, ``s > 0``). Moving Gaussians through it (:func:`transform_model`) moves the means, rotates the
quaternions, adds ``log s`` to the log-scales and rotates every SH band (view-dependent colour follows the rotated
view directions). The maps known here:

- nerfstudio (splatfacto): ``dataparser_transforms.json`` holds ``transform`` ``(3, 4)`` ``[R | t]`` and ``scale``;
  its world is ``scale · (R @ x + t)`` of the dataset's (:func:`nerfstudio_similarity`).
- gsplat's ``simple_trainer`` with ``normalize_world_space`` (its default): the world is re-centred, rotated and
  scaled from the COLMAP cameras and points (``examples/datasets/normalize.py`` and ``colmap.py``'s ``Parser``),
  and nothing in the checkpoint or PLY records it; :func:`gsplat_similarity` recomputes it from the scene.
- OpenSplat (without ``--keep-crs``): the world re-centred on the mean camera centre and scaled by 1 / the largest
  absolute coordinate of the centred camera centres, no rotation (its ``autoScaleAndCenterPoses``):
  :func:`opensplat_similarity`.
- :data:`AXIS_FLIP`: a world whose y and z axes point the other way (OpenGL/Blender "y up, z back" against
  COLMAP/OpenCV "y down, z forward"), a rotation of 180° about x.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.io.guarded import load_json
from abcgs.render.sh import eval_sh
from abcgs.sfm.align import Similarity

IDENTITY = Similarity(1.0, np.eye(3), np.zeros(3))
AXIS_FLIP = Similarity(1.0, np.diag([1.0, -1.0, -1.0]), np.zeros(3))
"""The world's y and z axes reversed (OpenGL vs OpenCV world convention)."""


def similarity_matrix(sim: Similarity) -> np.ndarray:
    """``(4, 4)`` homogeneous matrix of ``sim``."""
    m = np.eye(4)
    m[:3, :3] = sim.scale * np.asarray(sim.R, float)
    m[:3, 3] = sim.t
    return m


def similarity_from_matrix(m: np.ndarray, *, source: str = "transform") -> Similarity:
    """A :class:`Similarity` from a ``(4, 4)`` or ``(3, 4)`` matrix ``[s R | t]``; a shear, a reflection or a
    non-uniform scale raises :class:`InputError` naming ``source``."""
    m = np.asarray(m, float)
    if m.shape not in ((3, 4), (4, 4)) or not np.isfinite(m).all():
        raise InputError(f"{source}: expected a finite 3x4 or 4x4 matrix, got shape {m.shape}")
    a = m[:3, :3]
    det = float(np.linalg.det(a))
    if det <= 0:
        raise InputError(f"{source}: the matrix has determinant {det:.3g}; a frame map must be a rotation with a "
                         "positive scale (no reflection)")
    s = det ** (1.0 / 3.0)
    r = a / s
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-4):
        raise InputError(f"{source}: the 3x3 part is not a uniformly scaled rotation (shear or per-axis scale)")
    u, _, vt = np.linalg.svd(r)
    return Similarity(float(s), u @ vt, m[:3, 3].copy())


def compose(a: Similarity, b: Similarity) -> Similarity:
    """``a ∘ b``: first ``b``, then ``a``."""
    return similarity_from_matrix(similarity_matrix(a) @ similarity_matrix(b), source="composed similarity")


def inverse(sim: Similarity) -> Similarity:
    return similarity_from_matrix(np.linalg.inv(similarity_matrix(sim)), source="inverse similarity")


def is_identity(sim: Similarity, tol: float = 1e-9) -> bool:
    return bool(np.allclose(similarity_matrix(sim), np.eye(4), atol=tol))


# ----------------------------------------------------------------------------------------------- rotations


def rotmat_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(4,)`` wxyz of a rotation matrix (Shepperd's method), ``w ≥ 0``."""
    r = np.asarray(r, float)
    tr = np.trace(r)
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = np.array([0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s])
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
        q = np.array([(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s])
    elif r[1, 1] > r[2, 2]:
        s = math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
        q = np.array([(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s])
    else:
        s = math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
        q = np.array([(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of wxyz quaternions, broadcasting ``(..., 4)``."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], dim=-1)


def _sh_basis(degree: int, dirs: np.ndarray) -> np.ndarray:
    """``(M, K)`` values of the K = (degree+1)² real SH basis functions (the renderer's) at ``dirs (M, 3)``."""
    k = (degree + 1) ** 2
    d = torch.as_tensor(dirs, dtype=torch.float64)
    coeffs = torch.eye(k, dtype=torch.float64).expand(len(d), k, k)
    return eval_sh(degree, coeffs, d).numpy()


@lru_cache(maxsize=1)
def _sample_dirs() -> np.ndarray:
    rng = np.random.default_rng(0)
    d = rng.normal(size=(256, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def sh_rotation(degree: int, r: np.ndarray) -> np.ndarray:
    """``(K, K)`` matrix ``X`` with ``colour'(R d) = colour(d)`` for coefficients ``c' = X @ c`` (all bands up to
    ``degree``, block-diagonal; exact up to float64 round-off: each band is closed under rotation, so the
    least-squares fit over 256 directions has zero residual)."""
    dirs = _sample_dirs()
    b = _sh_basis(degree, dirs)
    b_rot = _sh_basis(degree, dirs @ np.asarray(r, float))  # rows: basis at Rᵀ d
    x, *_ = np.linalg.lstsq(b, b_rot, rcond=None)
    return x.T


def transform_model(model: GaussianModel, sim: Similarity) -> GaussianModel:
    """``model`` moved by ``sim`` (new tensors, float32): means ``s R x + t``, quaternions ``q_R ⊗ q``, log-scales
    ``+ log s``, SH bands rotated (:func:`sh_rotation`); opacities and the DC colour are unchanged."""
    if is_identity(sim):
        return model.detach()
    with torch.no_grad():
        dev = model.device
        r = torch.as_tensor(np.asarray(sim.R), dtype=torch.float64, device=dev)
        means = (sim.scale * model.means.double() @ r.T + torch.as_tensor(sim.t, dtype=torch.float64, device=dev)).float()
        qr = torch.as_tensor(rotmat_to_quat(sim.R), dtype=torch.float64, device=dev)
        quats = quat_multiply(qr, model.quats.double()).float()
        log_scales = (model.log_scales.double() + math.log(sim.scale)).float()
        shn = model.shN
        if shn.shape[1]:
            x = torch.as_tensor(sh_rotation(model.sh_degree, sim.R)[1:, 1:], dtype=torch.float64, device=dev)
            shn = torch.einsum("ij,njc->nic", x, shn.double()).float()
        return GaussianModel(means.contiguous(), quats.contiguous(), log_scales.contiguous(),
                             model.opacity_logits.detach().clone(), model.sh0.detach().clone(), shn.contiguous())


# ----------------------------------------------------------------------------------------------- known frames


MAX_TRANSFORMS_BYTES = 1 << 20
"""Largest ``dataparser_transforms.json`` read (bytes; nerfstudio's is about 300)."""


def nerfstudio_similarity(path: str | Path) -> Similarity:
    """Dataset frame → nerfstudio world, from a ``dataparser_transforms.json`` (``{"transform": 3x4, "scale": s}``):
    ``x_ns = scale · (R x + t)``."""
    path = Path(path)
    data = load_json(path, "splatfacto dataparser transforms", MAX_TRANSFORMS_BYTES)
    try:
        t = np.asarray(data["transform"], float)
        scale = float(data["scale"])
    except (ValueError, KeyError, TypeError, OverflowError) as exc:
        raise InputError(f"{path}: not a nerfstudio dataparser_transforms.json with 'transform' (3x4) and 'scale' "
                         f"({str(exc)[:80]}); pass the file written next to the splatfacto run's config.yml") from None
    if t.shape != (3, 4) or not 1e-12 < scale < 1e12:
        raise InputError(f"{path}: 'transform' must be 3x4 and 'scale' between 1e-12 and 1e12, got {t.shape} and "
                         f"{scale:g}")
    m = np.eye(4)
    m[:3, :] = t
    m[:3, :] *= scale
    return similarity_from_matrix(m, source=str(path))


def _rotation_aligning(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation taking unit vector ``a`` onto unit vector ``b`` (Rodrigues); 180° about x when they are opposite."""
    c = float(a @ b)
    if c <= -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.cross(a, b)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1 + c)


def gsplat_similarity(cameras: list[Camera], points: np.ndarray | None) -> Similarity:
    """Dataset frame → the world of gsplat's ``simple_trainer`` with ``normalize_world_space`` (its default).

    The same three steps as gsplat's COLMAP ``Parser``: (1) rotate the mean camera up (−y) onto +z, centre on the
    median of the points on each optical axis closest to the origin, scale by 1 / the median camera distance;
    (2) rotate the points' principal axes onto x, y, z (largest variance first, z the smallest) about their median;
    (3) turn 180° about x when the points' median height is above their mean (upside-down scenes).
    ``points``: (P, 3) world units; None (a dataset without points) is refused as no points.
    """
    points = np.zeros((0, 3)) if points is None else points
    if len(cameras) < 2 or len(points) < 4:
        raise InputError("gsplat's frame is computed from the scene's cameras and sparse points; the scene has "
                         f"{len(cameras)} camera(s) and {len(points)} point(s)")
    c2w = np.stack([np.linalg.inv(c.viewmat) for c in cameras])
    rots, centres = c2w[:, :3, :3], c2w[:, :3, 3]
    up = (rots @ np.array([0.0, -1.0, 0.0])).mean(0)
    up /= np.linalg.norm(up)
    r_align = _rotation_aligning(up, np.array([0.0, 0.0, 1.0]))
    fwd = (r_align @ rots) @ np.array([0.0, 0.0, 1.0])
    t = centres @ r_align.T
    nearest = t + ((-t) * fwd).sum(-1)[:, None] * fwd
    translate = -np.median(nearest, axis=0)
    scale = 1.0 / float(np.median(np.linalg.norm(t + translate, axis=-1)))
    t1 = Similarity(scale, r_align, scale * translate)
    pts = t1.apply(np.asarray(points, float))
    centroid = np.median(pts, axis=0)
    w, v = np.linalg.eigh(np.cov(pts - centroid, rowvar=False))
    v = v[:, np.argsort(w)[::-1]]
    if np.linalg.det(v) < 0:
        v[:, 0] *= -1
    t2 = Similarity(1.0, v.T, -v.T @ centroid)
    out = compose(t2, t1)
    pts = t2.apply(pts)
    if np.median(pts[:, 2]) > np.mean(pts[:, 2]):
        out = compose(AXIS_FLIP, out)
    return out


def opensplat_similarity(cameras: list[Camera]) -> Similarity:
    """Dataset frame → OpenSplat's world (trained without ``--keep-crs``): ``x' = f (x − c)`` with ``c`` the mean
    camera centre and ``f = 1 / max |centre − c|`` over every coordinate of every camera."""
    if len(cameras) < 2:
        raise InputError(f"OpenSplat's frame is computed from the scene's cameras; the scene has {len(cameras)}")
    centres = np.stack([c.center for c in cameras])
    c = centres.mean(axis=0)
    extent = float(np.abs(centres - c).max())
    if extent <= 0:
        raise InputError("OpenSplat's frame needs cameras at more than one place; every camera centre is the same")
    f = 1.0 / extent
    return Similarity(f, np.eye(3), -f * c)
