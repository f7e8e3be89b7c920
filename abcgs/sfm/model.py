"""The calibrated scene every stage after ``reconstruct`` reads: :class:`SceneData` from an undistorted COLMAP model.

The reconstruct stage writes ``out/<scene>/colmap/sparse/{cameras,images,points3D}.bin`` with PINHOLE cameras
(COLMAP's binary model format, https://colmap.github.io/format.html). Reading it needs no pycolmap: this module
parses the three files with numpy (the text variant ``*.txt`` too), so the stages that only read a scene (fit,
masks, reference, colour match, stylize, evaluate) run where no pycolmap wheel exists; where pycolmap is installed,
the points come in pycolmap's order (:func:`_pycolmap_point_order`). ``tests/test_sfm.py`` checks the result against
pycolmap's reader.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from abcgs.cameras import Camera
from abcgs.errors import InputError

PINHOLE_MODELS = {0: "SIMPLE_PINHOLE", 1: "PINHOLE"}
"""COLMAP model ids of the undistorted camera models this reader accepts."""
NUM_PARAMS = {0: 3, 1: 4, 2: 4, 3: 5, 4: 8, 5: 8, 6: 12, 7: 5, 8: 4, 9: 5, 10: 12, 11: 16}
"""Parameters per COLMAP camera model id (to step over models this reader refuses with a message)."""
MODEL_NAMES = {0: "SIMPLE_PINHOLE", 1: "PINHOLE", 2: "SIMPLE_RADIAL", 3: "RADIAL", 4: "OPENCV", 5: "OPENCV_FISHEYE",
               6: "FULL_OPENCV", 7: "FOV", 8: "SIMPLE_RADIAL_FISHEYE", 9: "RADIAL_FISHEYE", 10: "THIN_PRISM_FISHEYE",
               11: "RAD_TAN_THIN_PRISM_FISHEYE"}


@dataclass
class SceneData:
    """A calibrated scene as the fit stage consumes it.

    Attributes:
        cameras: one PINHOLE :class:`Camera` per registered image, sorted by image name.
        image_paths: the image file of each camera, same order.
        points: ``(M, 3) float32`` sparse SfM points in world coordinates.
        colors: ``(M, 3) float32`` their RGB colours in ``[0, 1]``.
        alpha_paths: the object's alpha map of each view (single-channel PNG, 0 = empty), same order, when the
            dataset gave one (RGBA views: ``alpha/`` beside ``images/``, :mod:`abcgs.sources.model`); else None.
    """

    cameras: list[Camera]
    image_paths: list[Path]
    points: np.ndarray
    colors: np.ndarray
    alpha_paths: list[Path] | None = None


@dataclass(frozen=True)
class _Intrinsics:
    model_id: int
    width: int
    height: int
    params: tuple[float, ...]


def _K(cam: _Intrinsics) -> np.ndarray:
    if cam.model_id == 0:
        f, cx, cy = cam.params
        fx = fy = f
    else:
        fx, fy, cx, cy = cam.params
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _viewmat(qvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """World→camera ``(4, 4)`` from COLMAP's ``cam_from_world`` rotation (unit quaternion wxyz) and translation."""
    w, x, y, z = np.asarray(qvec, float) / np.linalg.norm(qvec)
    R = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, tvec
    return M


class _Reader:
    def __init__(self, path: Path) -> None:
        self.path, self.data, self.pos = path, path.read_bytes(), 0

    def take(self, fmt: str):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise InputError(f"{self.path} ends early (truncated COLMAP model); run the reconstruct stage again")
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def name(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise InputError(f"{self.path} ends inside an image name (truncated COLMAP model)")
        out = self.data[self.pos : end].decode("utf-8")
        self.pos = end + 1
        return out


def _read_bin(model_dir: Path) -> tuple[dict[int, _Intrinsics], list[tuple[str, np.ndarray, np.ndarray, int]], np.ndarray, np.ndarray]:
    r = _Reader(model_dir / "cameras.bin")
    cams = {}
    for _ in range(r.take("Q")[0]):
        cam_id, model_id, width, height = r.take("iiQQ")
        if model_id not in NUM_PARAMS:
            raise InputError(f"{r.path}: unknown COLMAP camera model id {model_id}")
        cams[cam_id] = _Intrinsics(model_id, width, height, r.take("d" * NUM_PARAMS[model_id]))
    r = _Reader(model_dir / "images.bin")
    images = []
    for _ in range(r.take("Q")[0]):
        _, qw, qx, qy, qz, tx, ty, tz, cam_id = r.take("idddddddi")
        name = r.name()
        n2d = r.take("Q")[0]
        r.pos += n2d * struct.calcsize("<ddq")
        images.append((name, np.array([qw, qx, qy, qz]), np.array([tx, ty, tz]), cam_id))
    r = _Reader(model_dir / "points3D.bin")
    xyz, rgb, ids = [], [], []
    for _ in range(r.take("Q")[0]):
        vals = r.take("QdddBBBd")
        ids.append(vals[0])
        xyz.append(vals[1:4])
        rgb.append(vals[4:7])
        track_length = r.take("Q")[0]
        r.pos += track_length * struct.calcsize("<ii")
    return cams, images, np.array(xyz, np.float64).reshape(-1, 3), np.array(rgb, np.float64).reshape(-1, 3), ids


def _lines(path: Path) -> list[str]:
    return [ln for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def _read_txt(model_dir: Path) -> tuple[dict[int, _Intrinsics], list[tuple[str, np.ndarray, np.ndarray, int]], np.ndarray, np.ndarray]:
    ids = {v: k for k, v in MODEL_NAMES.items()}
    cams = {}
    for ln in _lines(model_dir / "cameras.txt"):
        cid, model, w, h, *params = ln.split()
        if model not in ids:
            raise InputError(f"{model_dir / 'cameras.txt'}: unknown COLMAP camera model {model}")
        cams[int(cid)] = _Intrinsics(ids[model], int(w), int(h), tuple(float(p) for p in params))
    images = []
    # two lines per image, the pose and its 2-D points; the points line may be empty, so blank lines count here
    rows = [ln for ln in (model_dir / "images.txt").read_text(encoding="utf-8").splitlines() if not ln.startswith("#")]
    k = 0
    while k < len(rows):
        f = rows[k].split()
        if not f:
            k += 1
            continue
        if len(f) < 10:
            raise InputError(f"{model_dir / 'images.txt'}: line {rows[k]!r} is not an image pose (IMAGE_ID QW QX QY QZ "
                             "TX TY TZ CAMERA_ID NAME)")
        images.append((" ".join(f[9:]), np.array(f[1:5], float), np.array(f[5:8], float), int(f[8])))
        k += 2
    xyz, rgb, ids = [], [], []
    pts = model_dir / "points3D.txt"
    for ln in _lines(pts) if pts.is_file() else []:
        f = ln.split()
        ids.append(int(f[0]))
        xyz.append([float(v) for v in f[1:4]])
        rgb.append([float(v) for v in f[4:7]])
    return cams, images, np.array(xyz, np.float64).reshape(-1, 3), np.array(rgb, np.float64).reshape(-1, 3), ids


def read_colmap_scene(model_dir: str | os.PathLike, images_dir: str | os.PathLike) -> SceneData:
    """Read an undistorted COLMAP model (``sparse/``: ``*.bin`` or ``*.txt``, PINHOLE or SIMPLE_PINHOLE cameras) and
    its images into :class:`SceneData` (views sorted by image name)."""
    model_dir, images_dir = Path(model_dir), Path(images_dir)
    if (model_dir / "cameras.bin").is_file():
        cams, images, xyz, rgb, ids = _read_bin(model_dir)
    elif (model_dir / "cameras.txt").is_file():
        cams, images, xyz, rgb, ids = _read_txt(model_dir)
    else:
        raise InputError(f"{model_dir} is not a COLMAP model (no cameras.bin/.txt); run the reconstruct stage first")
    if not images:
        raise InputError(f"COLMAP model {model_dir} has no registered images")
    cameras = []
    for name, q, t, cid in sorted(images, key=lambda im: im[0]):
        cam = cams.get(cid)
        if cam is None:
            raise InputError(f"{model_dir}: image {name} names camera {cid}, which the model does not have")
        if cam.model_id not in PINHOLE_MODELS:
            raise InputError(
                f"image {name} uses a {MODEL_NAMES[cam.model_id]} camera; read_colmap_scene needs an undistorted "
                "(PINHOLE) model, i.e. the sparse/ folder written by the reconstruct stage")
        cameras.append(Camera(name, _K(cam), _viewmat(q, t), int(cam.width), int(cam.height)))
    paths = [images_dir / c.name for c in cameras]
    missing = [p.name for p in paths if not p.is_file()]
    if missing:
        raise InputError(f"{len(missing)} image(s) of the model are missing from {images_dir}: {', '.join(missing[:10])}")
    order = _pycolmap_point_order(model_dir, ids)
    xyz, rgb = xyz[order], rgb[order]
    alpha_dir = images_dir.parent / "alpha"
    alphas = [alpha_dir / c.name for c in cameras] if alpha_dir.is_dir() else None
    if alphas is not None and not all(p.is_file() for p in alphas):
        raise InputError(f"{alpha_dir} lacks the alpha map of some views; re-run the reconstruct stage")
    return SceneData(cameras, paths, xyz.astype(np.float32), (rgb / 255.0).astype(np.float32), alphas)


def _pycolmap_point_order(model_dir: Path, ids: list[int]) -> np.ndarray:
    """Indices putting the points in the order pycolmap iterates them (its hash map's), where pycolmap is installed;
    the file's order elsewhere (a GPU machine without it). A fit depends on the order of its initial Gaussians, and
    every fit of this project so far started from pycolmap's order."""
    try:
        import pycolmap
    except ImportError:
        return np.arange(len(ids))
    where = {pid: k for k, pid in enumerate(ids)}
    rec = pycolmap.Reconstruction(str(model_dir))
    order = [where.get(pid) for pid in rec.points3D]
    if len(order) != len(ids) or None in order:
        raise InputError(f"{model_dir}: pycolmap reads other 3-D points than the file lists; the model is damaged")
    return np.asarray(order, np.int64)
