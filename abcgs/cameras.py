"""Cameras: one pinhole view (:class:`Camera`) and a batch of calibrated views with their lenses (:class:`Cameras`,
:class:`Distortion`, COLMAP's camera models: :data:`CAMERA_MODELS`; the COLMAP codec :mod:`abcgs.io.colmap` reads and
writes them).

Convention (shared with COLMAP, OpenCV and gsplat): camera looks down +z, x right, y down; ``viewmat``
maps world → camera coordinates; ``K`` maps camera coordinates to pixels with pixel centres at +0.5
(pixel (0, 0) covers [0, 1) x [0, 1)).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, overload

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


# ------------------------------------------------------------------------------------------------ lenses
CAMERA_MODELS: tuple[tuple[str, int], ...] = (
    ("SIMPLE_PINHOLE", 3), ("PINHOLE", 4), ("SIMPLE_RADIAL", 4), ("RADIAL", 5), ("OPENCV", 8), ("OPENCV_FISHEYE", 8),
    ("FULL_OPENCV", 12), ("FOV", 5), ("SIMPLE_RADIAL_FISHEYE", 4), ("RADIAL_FISHEYE", 5), ("THIN_PRISM_FISHEYE", 12),
    ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
)
"""COLMAP's camera models, indexed by COLMAP's model id: ``(name, number of parameters)``
(https://colmap.github.io/cameras.html)."""
SINGLE_FOCAL_MODELS = frozenset({0, 2, 3, 8, 9})
"""Model ids whose parameters start ``f, cx, cy``; the others start ``fx, fy, cx, cy``."""
PINHOLE_MODEL = 1
"""The model id of a view without distortion (``PINHOLE``)."""
MAX_DISTORTION_PARAMS = 12
"""Columns of :attr:`Cameras.distortion_params`: the most parameters a model has besides focal length(s) and
principal point."""


def camera_model_id(name: str) -> int:
    """COLMAP's id of the camera model ``name``; ``ValueError`` listing the models for another name."""
    for i, (model, _) in enumerate(CAMERA_MODELS):
        if model == name:
            return i
    raise ValueError(f"unknown COLMAP camera model {name!r}; one of {', '.join(m for m, _ in CAMERA_MODELS)}")


def lens_param_count(model_id: int) -> int:
    """How many parameters of model ``model_id`` are not focal length(s) or principal point."""
    return CAMERA_MODELS[model_id][1] - (3 if model_id in SINGLE_FOCAL_MODELS else 4)


@dataclass(frozen=True)
class Distortion:
    """One view's lens as a COLMAP camera model (a view of :class:`Cameras`' ``camera_models`` and
    ``distortion_params`` with its intrinsics).

    Attributes:
        model: COLMAP's model name (``SIMPLE_RADIAL``, ``OPENCV``, ``OPENCV_FISHEYE``, …).
        params: the model's full parameter vector in COLMAP's order (focal length(s) and principal point included),
            in pixels of the view's image as it lies on disk.
    """

    model: str
    params: tuple[float, ...]


@dataclass(frozen=True, eq=False)
class Cameras:
    """A batch of ``C`` calibrated views (nerfbaselines' ``Cameras``; gsplat's batched ``viewmats``/``Ks``).

    Conventions of this module (:class:`Camera`'s): OpenCV camera axes (x right, y down, z forward), pixel centres at +0.5. The
    arrays are read-only; ``cameras[i]`` is view ``i`` as a :class:`~abcgs.cameras.Camera` (its own copy of row ``i``),
    ``cameras[a:b]`` or ``cameras[index_array]`` a sub-batch; iterating gives the per-view cameras.

    Attributes:
        names: ``(C,)`` the views' names (image file names, unique).
        viewmats: ``(C, 4, 4) float64`` world→camera rigid transforms (world units).
        intrinsics: ``(C, 4) float64`` ``fx, fy, cx, cy`` in pixels of the view's image (the lens model's focal
            length(s) and principal point for a distorted view; ``fx == fy`` for a single-focal model).
        sizes: ``(C, 2) int64`` image ``width, height`` in pixels.
        camera_models: ``(C,) int32`` COLMAP camera model ids (:data:`CAMERA_MODELS`); :data:`PINHOLE_MODEL` (1) for
            a view without distortion.
        distortion_params: ``(C, MAX_DISTORTION_PARAMS) float64`` the model's parameters after focal length(s) and
            principal point, in COLMAP's order (dimensionless), zero-padded (:func:`lens_param_count` are used).
    """

    names: tuple[str, ...]
    viewmats: np.ndarray
    intrinsics: np.ndarray
    sizes: np.ndarray
    camera_models: np.ndarray
    distortion_params: np.ndarray

    def __post_init__(self) -> None:
        c = len(self.names)
        fields = {"viewmats": (np.float64, (c, 4, 4)), "intrinsics": (np.float64, (c, 4)), "sizes": (np.int64, (c, 2)),
                  "camera_models": (np.int32, (c,)), "distortion_params": (np.float64, (c, MAX_DISTORTION_PARAMS))}
        for name, (dtype, shape) in fields.items():
            arr = np.array(getattr(self, name), dtype=dtype)
            if arr.shape != shape:
                raise ValueError(f"Cameras.{name} has shape {arr.shape}; {c} views need {shape}")
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))
        if ((self.camera_models < 0) | (self.camera_models >= len(CAMERA_MODELS))).any():
            raise ValueError(f"Cameras.camera_models holds ids outside 0 .. {len(CAMERA_MODELS) - 1}")

    @classmethod
    def from_list(cls, cameras: Sequence[Camera], distortions: Sequence[Distortion | None] | None = None) -> Cameras:
        """The batch of per-view ``cameras`` (and their lenses, ``None`` = pinhole); a distorted view's intrinsics
        are its lens's focal length(s) and principal point."""
        c = len(cameras)
        distortions = list(distortions) if distortions is not None else [None] * c
        if len(distortions) != c:
            raise ValueError(f"{c} cameras but {len(distortions)} distortions")
        intrinsics = np.array([[cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]] for cam in cameras],
                              np.float64).reshape(c, 4)
        models = np.full(c, PINHOLE_MODEL, np.int32)
        lens = np.zeros((c, MAX_DISTORTION_PARAMS))
        for i, d in enumerate(distortions):
            if d is None:
                continue
            models[i] = camera_model_id(d.model)
            p = np.asarray(d.params, np.float64)
            if len(p) != CAMERA_MODELS[models[i]][1]:
                raise ValueError(f"{cameras[i].name}: a {d.model} lens has {CAMERA_MODELS[models[i]][1]} parameters, "
                                 f"got {len(p)}")
            single = models[i] in SINGLE_FOCAL_MODELS
            intrinsics[i] = (p[0], p[0], p[1], p[2]) if single else p[:4]
            rest = p[3:] if single else p[4:]
            lens[i, : len(rest)] = rest
        return cls(tuple(cam.name for cam in cameras), np.array([cam.viewmat for cam in cameras]).reshape(c, 4, 4),
                   intrinsics, np.array([(cam.width, cam.height) for cam in cameras]).reshape(c, 2), models, lens)

    def __len__(self) -> int:
        return len(self.names)

    @overload
    def __getitem__(self, index: int) -> Camera: ...

    @overload
    def __getitem__(self, index: slice | Sequence[int] | np.ndarray) -> Cameras: ...

    def __getitem__(self, index):
        if isinstance(index, (int, np.integer)):
            i = range(len(self))[index]  # IndexError past the end, negative indices from the end
            fx, fy, cx, cy = self.intrinsics[i]
            K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
            return Camera(self.names[i], K, self.viewmats[i].copy(), int(self.sizes[i, 0]), int(self.sizes[i, 1]))
        idx = np.arange(len(self))[index]
        return Cameras(tuple(self.names[i] for i in idx), self.viewmats[idx], self.intrinsics[idx], self.sizes[idx],
                       self.camera_models[idx], self.distortion_params[idx])

    def __iter__(self) -> Iterator[Camera]:
        return (self[i] for i in range(len(self)))

    @property
    def Ks(self) -> np.ndarray:
        """``(C, 3, 3) float64`` the intrinsics as matrices (zero skew)."""
        K = np.zeros((len(self), 3, 3))
        K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2] = self.intrinsics.T
        K[:, 2, 2] = 1.0
        return K

    @property
    def distorted(self) -> np.ndarray:
        """``(C,) bool``: the views whose model is not a pinhole one."""
        return ~np.isin(self.camera_models, (0, PINHOLE_MODEL))

    def distortion(self, i: int) -> Distortion | None:
        """View ``i``'s lens with its full COLMAP parameter vector, ``None`` for a pinhole view."""
        model = int(self.camera_models[i])
        if not self.distorted[i]:
            return None
        fx, fy, cx, cy = (float(v) for v in self.intrinsics[i])
        head = (fx, cx, cy) if model in SINGLE_FOCAL_MODELS else (fx, fy, cx, cy)
        rest = tuple(float(v) for v in self.distortion_params[i, : lens_param_count(model)])
        return Distortion(CAMERA_MODELS[model][0], head + rest)
