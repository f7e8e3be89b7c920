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

from abcgs.cameras import Camera, check_intrinsics
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
    """A calibrated scene as the later stages read it back from the ``reconstruct`` stage's COLMAP layout: the one scene
    type of fitting, splat import and masks.

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


SINGLE_FOCAL = {0, 2, 3, 8, 9}
"""COLMAP model ids whose parameters start ``f, cx, cy`` (the others start ``fx, fy, cx, cy``)."""
FIX = "re-export the model from COLMAP (or run the reconstruct stage again)"
_CAMERA = struct.calcsize("<iiQQ")
_IMAGE_MIN = struct.calcsize("<idddddddi") + 1 + 8  # the pose, an empty name's NUL and the 2-D point count
_POINT_MIN = struct.calcsize("<QdddBBBd") + 8  # the point and its track length
_POINT2D = struct.calcsize("<ddq")
_TRACK = struct.calcsize("<ii")


class _Reader:
    def __init__(self, path: Path) -> None:
        self.path, self.data, self.pos = path, path.read_bytes(), 0

    def take(self, fmt: str):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise InputError(f"{self.path} ends early at byte {len(self.data)} (truncated COLMAP model); {FIX}")
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def count(self, what: str, min_size: int) -> int:
        """A record count, refused when that many records of at least ``min_size`` bytes cannot fit the file."""
        n = self.take("Q")[0]
        left = len(self.data) - self.pos
        if n * min_size > left:
            raise InputError(f"{self.path} states {n} {what} but its {left} remaining bytes hold at most "
                             f"{left // min_size} (a truncated or corrupt COLMAP model); {FIX}")
        return n

    def skip(self, n: int, size: int, what: str) -> None:
        if self.pos + n * size > len(self.data):
            raise InputError(f"{self.path} states {n} {what} past its end (truncated COLMAP model); {FIX}")
        self.pos += n * size

    def name(self) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise InputError(f"{self.path} ends inside an image name (truncated COLMAP model); {FIX}")
        try:
            out = self.data[self.pos : end].decode("utf-8")
        except UnicodeDecodeError:
            raise InputError(f"{self.path}: an image name at byte {self.pos} is not UTF-8 (a corrupt COLMAP model); "
                             f"{FIX}") from None
        self.pos = end + 1
        return out

    def end(self) -> None:
        if self.pos != len(self.data):
            raise InputError(f"{self.path} has {len(self.data) - self.pos} bytes after the records its count states "
                             f"(a corrupt COLMAP model); {FIX}")


_Model = tuple[dict[int, _Intrinsics], list[tuple[str, np.ndarray, np.ndarray, int]], np.ndarray, np.ndarray, list[int]]


def _read_bin(model_dir: Path) -> _Model:
    r = _Reader(model_dir / "cameras.bin")
    cams = {}
    for _ in range(r.count("cameras", _CAMERA + 8 * 3)):
        cam_id, model_id, width, height = r.take("iiQQ")
        if model_id not in NUM_PARAMS:
            raise InputError(f"{r.path}: camera {cam_id} has unknown COLMAP camera model id {model_id} (a corrupt "
                             f"model); {FIX}")
        if cam_id in cams:
            raise InputError(f"{r.path}: camera id {cam_id} appears twice; {FIX}")
        cams[cam_id] = _Intrinsics(model_id, width, height, r.take("d" * NUM_PARAMS[model_id]))
    r.end()
    r = _Reader(model_dir / "images.bin")
    images, image_ids = [], set()
    for _ in range(r.count("images", _IMAGE_MIN)):
        image_id, qw, qx, qy, qz, tx, ty, tz, cam_id = r.take("idddddddi")
        if image_id in image_ids:
            raise InputError(f"{r.path}: image id {image_id} appears twice; {FIX}")
        image_ids.add(image_id)
        name = r.name()
        r.skip(r.take("Q")[0], _POINT2D, f"2-D points of image {name!r}")
        images.append((name, np.array([qw, qx, qy, qz]), np.array([tx, ty, tz]), cam_id))
    r.end()
    r = _Reader(model_dir / "points3D.bin")
    xyz, rgb, ids = [], [], []
    for _ in range(r.count("3-D points", _POINT_MIN)):
        vals = r.take("QdddBBBd")
        ids.append(vals[0])
        xyz.append(vals[1:4])
        rgb.append(vals[4:7])
        r.skip(r.take("Q")[0], _TRACK, f"track entries of point {vals[0]}")
    r.end()
    return cams, images, np.array(xyz, np.float64).reshape(-1, 3), np.array(rgb, np.float64).reshape(-1, 3), ids


def _lines(path: Path) -> list[str]:
    return [ln for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def _read_txt(model_dir: Path) -> _Model:
    try:
        return _parse_txt(model_dir)
    except UnicodeDecodeError:
        raise InputError(f"{model_dir}: a model file is not UTF-8 text (a corrupt COLMAP model); {FIX}") from None
    except InputError:
        raise
    except (ValueError, IndexError) as exc:  # int()/float() of a field that is not a number
        raise InputError(f"{model_dir}: a line of the text model is not COLMAP's ({exc}); {FIX}") from None


def _parse_txt(model_dir: Path) -> _Model:
    ids = {v: k for k, v in MODEL_NAMES.items()}
    cams = {}
    for ln in _lines(model_dir / "cameras.txt"):
        cid, model, w, h, *params = ln.split()
        if model not in ids:
            raise InputError(f"{model_dir / 'cameras.txt'}: unknown COLMAP camera model {model}")
        if len(params) != NUM_PARAMS[ids[model]]:
            raise InputError(f"{model_dir / 'cameras.txt'}: camera {cid} is {model} with {len(params)} parameters; "
                             f"that model has {NUM_PARAMS[ids[model]]}; {FIX}")
        if int(cid) in cams:
            raise InputError(f"{model_dir / 'cameras.txt'}: camera id {cid} appears twice; {FIX}")
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
            raise InputError(f"{model_dir / 'images.txt'}: line {rows[k][:80]!r} is not an image pose (IMAGE_ID QW QX QY "
                             "QZ TX TY TZ CAMERA_ID NAME)")
        images.append((" ".join(f[9:]), np.array(f[1:5], float), np.array(f[5:8], float), int(f[8])))
        k += 2
    xyz, rgb, ids = [], [], []
    pts = model_dir / "points3D.txt"
    for ln in _lines(pts) if pts.is_file() else []:
        f = ln.split()
        ids.append(int(f[0]))
        xyz.append([float(v) for v in f[1:4]])
        rgb.append([int(v) for v in f[4:7]])
        float(f[7])  # the reprojection error
        if not all(0 <= c <= 255 for c in rgb[-1]) or (len(f) - 8) % 2:
            raise InputError(f"{pts}: point {f[0]}: colour {rgb[-1]} is not 8-bit RGB or its track is not (IMAGE_ID, "
                             f"POINT2D_IDX) pairs; {FIX}")
        [int(v) for v in f[8:]]
    return cams, images, np.array(xyz, np.float64).reshape(-1, 3), np.array(rgb, np.float64).reshape(-1, 3), ids


def check_model(model_dir: Path, cams: dict[int, _Intrinsics], images: list) -> None:
    """The checks every COLMAP model gets before use; :class:`InputError` naming the file and record: a camera's
    size and focal length(s) and principal point plausible (:func:`abcgs.cameras.check_intrinsics`) and its other
    parameters finite; each image's pose finite with a non-zero quaternion, its camera present, its name unique."""
    for cid, cam in cams.items():
        p = cam.params
        where = f"{model_dir} camera {cid} ({MODEL_NAMES[cam.model_id]})"
        if len(p) != NUM_PARAMS[cam.model_id]:
            raise InputError(f"{where}: {len(p)} parameters; the model has {NUM_PARAMS[cam.model_id]}; {FIX}")
        if not np.isfinite(p).all():
            raise InputError(f"{where}: its parameters {list(p)[:8]} are not all finite; {FIX}")
        fx, fy, cx, cy = (p[0], p[0], p[1], p[2]) if cam.model_id in SINGLE_FOCAL else p[:4]
        check_intrinsics(fx, fy, cx, cy, cam.width, cam.height, where, FIX)
    seen: set[str] = set()
    for name, q, t, cid in images:
        where = f"{model_dir} image {name!r}"
        if name in seen:
            raise InputError(f"{where} appears twice; each image has one pose; {FIX}")
        seen.add(name)
        if not name or len(name) > 4096 or "\0" in name or any(len(part) > 255 for part in name.split("/")):
            raise InputError(f"{model_dir}: an image name {name[:60]!r} is not a file name; {FIX}")
        if not (np.isfinite(q).all() and np.isfinite(t).all()) or np.linalg.norm(q) < 1e-6:
            raise InputError(f"{where}: its pose (quaternion {list(q)}, translation {list(t)}) is not a finite "
                             f"rotation and position; {FIX}")
        if cid not in cams:
            raise InputError(f"{where} names camera {cid}, which the model does not have; {FIX}")


def read_model(model_dir: str | os.PathLike) -> _Model:
    """``(cameras, images, xyz, rgb, point ids)`` of the COLMAP model in ``model_dir`` (``*.bin``, else ``*.txt``),
    checked (:func:`check_model`; record counts against the file sizes, points finite)."""
    model_dir = Path(model_dir)
    if (model_dir / "cameras.bin").is_file():
        for name in ("images.bin", "points3D.bin"):
            if not (model_dir / name).is_file():
                raise InputError(f"{model_dir} has cameras.bin but no {name}; copy the whole COLMAP model")
        model = _read_bin(model_dir)
    elif (model_dir / "cameras.txt").is_file():
        if not (model_dir / "images.txt").is_file():
            raise InputError(f"{model_dir} has cameras.txt but no images.txt; copy the whole COLMAP model")
        model = _read_txt(model_dir)
    else:
        raise InputError(f"{model_dir} is not a COLMAP model (no cameras.bin/.txt); run the reconstruct stage first")
    check_model(model_dir, model[0], model[1])
    if len(set(model[4])) != len(model[4]):
        raise InputError(f"{model_dir}: a 3-D point id appears twice; {FIX}")
    if not np.isfinite(model[2]).all():
        bad = int((~np.isfinite(model[2]).all(axis=1)).sum())
        raise InputError(f"{model_dir}: {bad} 3-D points have a NaN or infinite position; {FIX}")
    return model


def read_colmap_scene(model_dir: str | os.PathLike, images_dir: str | os.PathLike) -> SceneData:
    """Read an undistorted COLMAP model (``sparse/``: ``*.bin`` or ``*.txt``, PINHOLE or SIMPLE_PINHOLE cameras) and
    its images into :class:`SceneData` (views sorted by image name)."""
    model_dir, images_dir = Path(model_dir), Path(images_dir)
    cams, images, xyz, rgb, ids = read_model(model_dir)
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
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as exc:  # pycolmap raises ValueError, IndexError, … for references this reader does not follow
        raise InputError(f"{model_dir} is not a consistent COLMAP model ({str(exc).strip()[:200]}); {FIX}") from None
    order = [where.get(pid) for pid in rec.points3D]
    if len(order) != len(ids) or None in order:
        raise InputError(f"{model_dir}: pycolmap reads other 3-D points than the file lists; the model is damaged")
    return np.asarray(order, np.int64)
