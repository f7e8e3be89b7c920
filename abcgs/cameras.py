"""Pinhole cameras.

Convention (shared with COLMAP, OpenCV and gsplat): camera looks down +z, x right, y down; ``viewmat``
maps world → camera coordinates; ``K`` maps camera coordinates to pixels with pixel centres at +0.5
(pixel (0, 0) covers [0, 1) x [0, 1)).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

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
