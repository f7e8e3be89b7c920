"""Pinhole cameras.

Convention (shared with COLMAP, OpenCV and gsplat): camera looks down +z, x right, y down; ``viewmat``
maps world → camera coordinates; ``K`` maps camera coordinates to pixels with pixel centres at +0.5
(pixel (0, 0) covers [0, 1) x [0, 1)).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from abcgs.errors import InputError

if TYPE_CHECKING:  # torch is imported by the two methods that make tensors: stages without tensors skip its import
    import torch


@dataclass(frozen=True)
class Camera:
    """One calibrated view.

    Attributes:
        name: image file name (stem used to pair images, masks and renders).
        K: ``(3, 3) float64`` intrinsics in pixels.
        viewmat: ``(4, 4) float64`` world→camera rigid transform.
        width, height: image size in pixels.
    """

    name: str
    K: np.ndarray
    viewmat: np.ndarray
    width: int
    height: int
    meta: dict = field(default_factory=dict, compare=False)

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, ``(3,)``."""
        R, t = self.viewmat[:3, :3], self.viewmat[:3, 3]
        return -R.T @ t

    def scaled(self, factor: float) -> Camera:
        """The same view at ``factor`` × resolution (intrinsics scaled, pixel-centre convention kept)."""
        w, h = max(1, round(self.width * factor)), max(1, round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        K = self.K.copy()
        K[0] *= sx
        K[1] *= sy
        return Camera(self.name, K, self.viewmat.copy(), w, h, dict(self.meta))

    def torch_viewmat(self, device: torch.device | str = "cpu") -> torch.Tensor:
        import torch

        return torch.as_tensor(self.viewmat, dtype=torch.float32, device=device)

    def torch_K(self, device: torch.device | str = "cpu") -> torch.Tensor:
        import torch

        return torch.as_tensor(self.K, dtype=torch.float32, device=device)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """World→camera ``(4, 4)`` matrix for a camera at ``eye`` looking at ``target`` (OpenCV axes, y down;
    ``up`` defaults to world -y)."""
    up = np.array([0.0, -1.0, 0.0]) if up is None else np.asarray(up, float)
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross(up, z)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(np.array([1.0, 0.0, 0.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = -R @ np.asarray(eye, float)
    return M


def intrinsics(focal: float, width: int, height: int, cx: float | None = None, cy: float | None = None) -> np.ndarray:
    """``(3, 3)`` pinhole intrinsics with the principal point at the image centre by default."""
    return np.array(
        [[focal, 0.0, width / 2.0 if cx is None else cx], [0.0, focal, height / 2.0 if cy is None else cy], [0.0, 0.0, 1.0]]
    )


MAX_IMAGE_SIDE = 100_000
"""Largest image width or height (px) a camera may state; more is a corrupt file, not a photo."""
FOCAL_RANGE = (0.02, 1000.0)
"""Plausible focal lengths, as multiples of the image's larger side: from a 175° field of view to a 0.06° one."""
ROTATION_TOLERANCE = 1e-3
"""Largest ``|Rᵀ R − I|`` and ``|det R − 1|`` of a matrix taken as a rotation (poses stored as text lose digits)."""


def check_intrinsics(fx: float, fy: float, cx: float, cy: float, width: float, height: float, where: str,
                     fix: str = "re-export the cameras from the tool that made them") -> None:
    """Raise :class:`~abcgs.errors.InputError` naming ``where`` and ``fix`` unless the image size (px) is a positive
    whole size up to :data:`MAX_IMAGE_SIDE`, the focal lengths (px) are finite and within :data:`FOCAL_RANGE` of
    it, and the principal point (px) is finite and within one image size of the image."""
    vals = [float(v) for v in (fx, fy, cx, cy, width, height)]
    if not all(np.isfinite(vals)):
        raise InputError(f"{where}: the intrinsics (fx, fy, cx, cy, w, h) = {_fmt(vals)} are not all finite; {fix}")
    w, h = vals[4], vals[5]
    if not (1 <= w <= MAX_IMAGE_SIDE and 1 <= h <= MAX_IMAGE_SIDE and w == int(w) and h == int(h)):
        raise InputError(f"{where}: the image size {w:g} x {h:g} is not a size in pixels (1 .. {MAX_IMAGE_SIDE}); {fix}")
    lo, hi = FOCAL_RANGE[0] * max(w, h), FOCAL_RANGE[1] * max(w, h)
    for name, f in (("fx", vals[0]), ("fy", vals[1])):
        if not lo <= f <= hi:
            raise InputError(f"{where}: focal length {name} = {f:g} px is not plausible for a {w:g} x {h:g} image "
                             f"({lo:g} .. {hi:g} px); {fix}")
    if not (-w <= vals[2] <= 2 * w and -h <= vals[3] <= 2 * h):
        raise InputError(f"{where}: the principal point ({vals[2]:g}, {vals[3]:g}) px lies far outside the "
                         f"{w:g} x {h:g} image; {fix}")


def check_rotation(R, where: str, fix: str = "re-export the poses from the tool that made them") -> None:
    """Raise :class:`~abcgs.errors.InputError` naming ``where`` and ``fix`` unless ``R`` is a finite ``(3, 3)``
    rotation: orthonormal and with determinant +1 within :data:`ROTATION_TOLERANCE`."""
    R = np.asarray(R, np.float64)
    if R.shape != (3, 3) or not np.isfinite(R).all():
        raise InputError(f"{where}: the rotation is not a finite 3x3 matrix; {fix}")
    det = float(np.linalg.det(R))
    if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOLERANCE or abs(det - 1.0) > ROTATION_TOLERANCE:
        raise InputError(f"{where}: the rotation is not a proper rotation (orthonormal, det +1; its det is {det:.3f}); "
                         f"{fix}")


def _fmt(vals: list[float]) -> str:
    return "(" + ", ".join(f"{v:g}" for v in vals) + ")"
