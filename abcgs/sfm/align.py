"""Similarity (Umeyama) alignment of point sets, e.g. camera centres of two reconstructions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from abcgs.errors import InputError


@dataclass(frozen=True)
class Similarity:
    """``x ↦ scale · R @ x + t``; ``R (3, 3)`` a rotation, ``t (3,)``."""

    scale: float
    R: np.ndarray
    t: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform ``(N, 3)`` points."""
        return self.scale * np.asarray(points, float) @ self.R.T + self.t


def umeyama(src: np.ndarray, dst: np.ndarray, *, with_scale: bool = True) -> Similarity:
    """Least-squares similarity mapping ``src (N, 3)`` onto ``dst (N, 3)`` (Umeyama 1991).

    Minimises ``Σ ‖dst_i − (s R src_i + t)‖²`` over rotations ``R`` (det +1), ``t`` and (optionally) ``s > 0``.
    Needs ``N ≥ 3`` points that are not all collinear.
    """
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise InputError(f"umeyama needs two (N, 3) arrays of equal shape, got {src.shape} and {dst.shape}")
    if src.shape[0] < 3:
        raise InputError(f"umeyama needs at least 3 point pairs, got {src.shape[0]}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = (xs**2).sum() / len(src)
    if var_s < 1e-18:
        raise InputError("umeyama: source points are all identical; cannot estimate a similarity")
    cov = xd.T @ xs / len(src)
    U, S, Vt = np.linalg.svd(cov)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    scale = float(np.trace(np.diag(S) @ D) / var_s) if with_scale else 1.0
    t = mu_d - scale * R @ mu_s
    return Similarity(scale, R, t)


def alignment_residual(src: np.ndarray, dst: np.ndarray) -> tuple[float, float, Similarity]:
    """Align ``src`` onto ``dst`` with :func:`umeyama` and measure what is left.

    Returns ``(rms, relative, sim)``: the RMS distance ``(in dst units)`` between the aligned ``src`` and
    ``dst``, that RMS divided by the extent of ``dst`` (RMS distance of its points from their centroid),
    and the similarity.
    """
    sim = umeyama(src, dst)
    dst = np.asarray(dst, float)
    rms = float(np.sqrt(((sim.apply(src) - dst) ** 2).sum(1).mean()))
    extent = float(np.sqrt(((dst - dst.mean(0)) ** 2).sum(1).mean()))
    return rms, rms / max(extent, 1e-12), sim
