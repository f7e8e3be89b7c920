"""COLMAP models (https://colmap.github.io/format.html): the one reader and the one writer of this project.

    model = read_model("data/garden/sparse/0")        # *.bin, else *.txt; checked (below); points by id
    cameras = model.cameras()                          # abcgs.cameras.Cameras of the images, sorted by name
    write_model(out / "sparse", cameras, xyz, rgb)     # cameras.bin, images.bin, points3D.bin (or text=True)

The reader is numpy only (no pycolmap), so the stages that only read a scene run where no pycolmap wheel exists. It
treats every file as untrusted: a record count is refused when that many records cannot fit the bytes left, a name
must be UTF-8 and end, the files must end where their records do, the text variant's fields must be numbers; then
:func:`check_model` (plausible intrinsics, finite poses and points, unique ids and names, cameras present). Every
problem is an :class:`~abcgs.errors.InputError` naming the file and what to do.

The 3-D points come in one canonical order, by point id, whatever order the file lists them in; the 2-D points of
images and the points' tracks are stepped over (no stage uses them). The writer writes one camera per image (camera
id = image id unless given), the points with ids 1 … M in the order given and empty tracks; pycolmap reads what it
writes.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from abcgs.cameras import (
    CAMERA_MODELS,
    PINHOLE_MODEL,
    SINGLE_FOCAL_MODELS,
    Camera,
    Cameras,
    Distortion,
    check_intrinsics,
)
from abcgs.errors import InputError
from abcgs.io.guarded import read_bounded, read_text

FIX = "re-export the model from COLMAP (or run the reconstruct stage again)"
FILES = ("cameras", "images", "points3D")
"""The files of a model, ``.bin`` or ``.txt``."""

_CAMERA = struct.calcsize("<iiQQ")
_IMAGE_MIN = struct.calcsize("<idddddddi") + 1 + 8  # the pose, an empty name's NUL and the 2-D point count
_POINT_MIN = struct.calcsize("<QdddBBBd") + 8  # the point and its track length
_POINT2D = struct.calcsize("<ddq")
_TRACK = struct.calcsize("<ii")


@dataclass(frozen=True)
class ColmapCamera:
    """One camera record: COLMAP's ``model_id`` (:data:`abcgs.cameras.CAMERA_MODELS`), image size in px and the model's
    full parameter vector (px for focal lengths and principal point)."""

    model_id: int
    width: int
    height: int
    params: tuple[float, ...]

    @property
    def model(self) -> str:
        return CAMERA_MODELS[self.model_id][0]

    @property
    def pinhole(self) -> tuple[float, float, float, float]:
        """``fx, fy, cx, cy`` (px) of the model."""
        p = self.params
        return (p[0], p[0], p[1], p[2]) if self.model_id in SINGLE_FOCAL_MODELS else (p[0], p[1], p[2], p[3])


@dataclass(frozen=True)
class ColmapImage:
    """One image record: its id, name, COLMAP's ``cam_from_world`` pose (unit quaternion ``w, x, y, z`` and
    translation in world units) and its camera's id."""

    image_id: int
    name: str
    qvec: np.ndarray
    tvec: np.ndarray
    camera_id: int

    @property
    def viewmat(self) -> np.ndarray:
        """``(4, 4) float64`` world→camera."""
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = quaternion_to_rotation(self.qvec), self.tvec
        return M


@dataclass(frozen=True)
class ColmapModel:
    """A COLMAP model as read (:func:`read_model`).

    Attributes:
        cameras_by_id: camera id → :class:`ColmapCamera`.
        images: the image records, sorted by name.
        point_ids: ``(M,) uint64`` the 3-D points' ids, ascending (the canonical order).
        points: ``(M, 3) float64`` their positions (world units).
        colors: ``(M, 3) uint8`` their RGB colours.
    """

    cameras_by_id: dict[int, ColmapCamera]
    images: tuple[ColmapImage, ...]
    point_ids: np.ndarray
    points: np.ndarray
    colors: np.ndarray

    def view(self, image: ColmapImage) -> tuple[Camera, Distortion | None]:
        """The image's camera (its model's focal length(s) and principal point) and its lens (``None`` for
        ``PINHOLE`` and ``SIMPLE_PINHOLE``)."""
        cam = self.cameras_by_id[image.camera_id]
        fx, fy, cx, cy = cam.pinhole
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        lens = None if cam.model_id in (0, PINHOLE_MODEL) else Distortion(cam.model, cam.params)
        return Camera(image.name, K, image.viewmat, cam.width, cam.height), lens

    def cameras(self) -> Cameras:
        """The images' :class:`~abcgs.cameras.Cameras`, sorted by name."""
        views = [self.view(im) for im in self.images]
        return Cameras.from_list([c for c, _ in views], [d for _, d in views])


def quaternion_to_rotation(q) -> np.ndarray:
    """``(3, 3)`` rotation of the quaternion ``w, x, y, z`` (normalised here)."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rotation_to_quaternion(R) -> np.ndarray:
    """Unit quaternion ``w, x, y, z`` (``w ≥ 0``) of a ``(3, 3)`` rotation (Shepperd's method: the largest of the four
    squared components decides, so no division by a small number)."""
    R = np.asarray(R, np.float64)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    k = int(np.argmax([tr, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.asarray(q) / np.linalg.norm(q)
    return -q if q[0] < 0 else q


# ------------------------------------------------------------------------------------------------ reading
MAX_MODEL_BYTES = 8 << 30
"""Largest COLMAP model file read (bytes; a 10 M-point model with its tracks takes about 2 GB)."""


class _Bytes:
    """A binary model file read with every count and length bounded by the bytes it has."""

    def __init__(self, path: Path) -> None:
        self.path, self.data, self.pos = path, read_bounded(path, "COLMAP model file", MAX_MODEL_BYTES), 0

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


_Raw = tuple[dict[int, ColmapCamera], list[ColmapImage], list[int], list, list]


def _add_camera(cams: dict[int, ColmapCamera], path: Path, cid: int, cam: ColmapCamera) -> None:
    if cid in cams:
        raise InputError(f"{path}: camera id {cid} appears twice; {FIX}")
    cams[cid] = cam


def _read_bin(model_dir: Path) -> _Raw:
    r = _Bytes(model_dir / "cameras.bin")
    cams: dict[int, ColmapCamera] = {}
    for _ in range(r.count("cameras", _CAMERA + 8 * 3)):
        cam_id, model_id, width, height = r.take("iiQQ")
        if not 0 <= model_id < len(CAMERA_MODELS):
            raise InputError(f"{r.path}: camera {cam_id} has unknown COLMAP camera model id {model_id} (a corrupt "
                             f"model); {FIX}")
        _add_camera(cams, r.path, cam_id, ColmapCamera(model_id, width, height, r.take("d" * CAMERA_MODELS[model_id][1])))
    r.end()
    r = _Bytes(model_dir / "images.bin")
    images = []
    for _ in range(r.count("images", _IMAGE_MIN)):
        image_id, qw, qx, qy, qz, tx, ty, tz, cam_id = r.take("idddddddi")
        name = r.name()
        r.skip(r.take("Q")[0], _POINT2D, f"2-D points of image {name!r}")
        images.append(ColmapImage(image_id, name, np.array([qw, qx, qy, qz]), np.array([tx, ty, tz]), cam_id))
    r.end()
    r = _Bytes(model_dir / "points3D.bin")
    ids, xyz, rgb = [], [], []
    for _ in range(r.count("3-D points", _POINT_MIN)):
        vals = r.take("QdddBBBd")
        ids.append(vals[0])
        xyz.append(vals[1:4])
        rgb.append(vals[4:7])
        r.skip(r.take("Q")[0], _TRACK, f"track entries of point {vals[0]}")
    r.end()
    return cams, images, ids, xyz, rgb


def _lines(path: Path) -> list[str]:
    return [ln for ln in _text(path).splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def _text(path: Path) -> str:
    """A text model file (:func:`abcgs.io.guarded.read_text`: a regular file of at most :data:`MAX_MODEL_BYTES`)."""
    return read_text(path, "COLMAP model file", MAX_MODEL_BYTES)


def _read_txt(model_dir: Path) -> _Raw:
    try:
        return _parse_txt(model_dir)
    except UnicodeDecodeError:
        raise InputError(f"{model_dir}: a model file is not UTF-8 text (a corrupt COLMAP model); {FIX}") from None
    except InputError:
        raise
    except (ValueError, IndexError, OverflowError) as exc:  # int()/float() of a field that is not a number
        raise InputError(f"{model_dir}: a line of the text model is not COLMAP's ({exc}); {FIX}") from None


def _parse_txt(model_dir: Path) -> _Raw:
    ids_of = {name: i for i, (name, _) in enumerate(CAMERA_MODELS)}
    path = model_dir / "cameras.txt"
    cams: dict[int, ColmapCamera] = {}
    for ln in _lines(path):
        cid, model, w, h, *params = ln.split()
        if model not in ids_of:
            raise InputError(f"{path}: unknown COLMAP camera model {model}; {FIX}")
        n = CAMERA_MODELS[ids_of[model]][1]
        if len(params) != n:
            raise InputError(f"{path}: camera {cid} is {model} with {len(params)} parameters; that model has {n}; {FIX}")
        _add_camera(cams, path, int(cid), ColmapCamera(ids_of[model], int(w), int(h), tuple(float(p) for p in params)))
    images = []
    path = model_dir / "images.txt"
    # two lines per image, the pose and its 2-D points; the points line may be empty, so blank lines count here
    rows = [ln for ln in _text(path).splitlines() if not ln.startswith("#")]
    k = 0
    while k < len(rows):
        f = rows[k].split()
        if not f:
            k += 1
            continue
        if len(f) < 10:
            raise InputError(f"{path}: line {rows[k][:80]!r} is not an image pose (IMAGE_ID QW QX QY QZ TX TY TZ "
                             f"CAMERA_ID NAME); {FIX}")
        images.append(ColmapImage(int(f[0]), " ".join(f[9:]), np.array(f[1:5], float), np.array(f[5:8], float),
                                  int(f[8])))
        k += 2
    ids, xyz, rgb = [], [], []
    path = model_dir / "points3D.txt"
    for ln in _lines(path) if path.is_file() else []:
        f = ln.split()
        ids.append(int(f[0]))
        if not 0 <= ids[-1] < 2**64:
            raise InputError(f"{path}: point id {f[0]} is not an unsigned 64-bit number; {FIX}")
        xyz.append([float(v) for v in f[1:4]])
        rgb.append([int(v) for v in f[4:7]])
        float(f[7])  # the reprojection error
        if not all(0 <= c <= 255 for c in rgb[-1]) or (len(f) - 8) % 2:
            raise InputError(f"{path}: point {f[0]}: colour {rgb[-1]} is not 8-bit RGB or its track is not (IMAGE_ID, "
                             f"POINT2D_IDX) pairs; {FIX}")
        [int(v) for v in f[8:]]
    return cams, images, ids, xyz, rgb


def check_model(model_dir: Path, cams: dict[int, ColmapCamera], images: list[ColmapImage]) -> None:
    """The checks every COLMAP model gets before use; :class:`InputError` naming the file and record: a camera's
    size and focal length(s) and principal point plausible (:func:`abcgs.cameras.check_intrinsics`) and its other
    parameters finite; each image's pose finite with a non-zero quaternion, its camera present, its id and name
    unique."""
    for cid, cam in cams.items():
        where = f"{model_dir} camera {cid} ({cam.model})"
        if not np.isfinite(cam.params).all():
            raise InputError(f"{where}: its parameters {list(cam.params)[:8]} are not all finite; {FIX}")
        check_intrinsics(*cam.pinhole, cam.width, cam.height, where, FIX)
    names: set[str] = set()
    ids: set[int] = set()
    for im in images:
        where = f"{model_dir} image {im.name!r}"
        if im.image_id in ids:
            raise InputError(f"{model_dir}: image id {im.image_id} appears twice; {FIX}")
        ids.add(im.image_id)
        if im.name in names:
            raise InputError(f"{where} appears twice; each image has one pose; {FIX}")
        names.add(im.name)
        if not im.name or len(im.name) > 4096 or "\0" in im.name or any(len(p) > 255 for p in im.name.split("/")):
            raise InputError(f"{model_dir}: an image name {im.name[:60]!r} is not a file name; {FIX}")
        if not (np.isfinite(im.qvec).all() and np.isfinite(im.tvec).all()) or np.linalg.norm(im.qvec) < 1e-6:
            raise InputError(f"{where}: its pose (quaternion {list(im.qvec)}, translation {list(im.tvec)}) is not a "
                             f"finite rotation and position; {FIX}")
        if im.camera_id not in cams:
            raise InputError(f"{where} names camera {im.camera_id}, which the model does not have; {FIX}")


def model_format(model_dir: str | os.PathLike) -> str | None:
    """``"bin"`` or ``"txt"``: the variant of the model in ``model_dir`` (binary first), ``None`` when it holds none."""
    model_dir = Path(model_dir)
    for ext in ("bin", "txt"):
        if (model_dir / f"cameras.{ext}").is_file():
            return ext
    return None


def read_model(model_dir: str | os.PathLike) -> ColmapModel:
    """The COLMAP model in ``model_dir`` (``*.bin``, else ``*.txt``), checked (module docstring), its images sorted by
    name and its points by id."""
    model_dir = Path(model_dir)
    ext = model_format(model_dir)
    if ext is None:
        raise InputError(f"{model_dir} is not a COLMAP model (no cameras.bin/.txt); run the reconstruct stage first")
    needed = ("images", "points3D") if ext == "bin" else ("images",)
    for name in needed:
        if not (model_dir / f"{name}.{ext}").is_file():
            raise InputError(f"{model_dir} has cameras.{ext} but no {name}.{ext}; copy the whole COLMAP model")
    cams, images, ids, xyz, rgb = _read_bin(model_dir) if ext == "bin" else _read_txt(model_dir)
    check_model(model_dir, cams, images)
    point_ids = np.array(ids, np.uint64)
    if len(np.unique(point_ids)) != len(point_ids):
        raise InputError(f"{model_dir}: a 3-D point id appears twice; {FIX}")
    points = np.array(xyz, np.float64).reshape(-1, 3)
    if not np.isfinite(points).all():
        bad = int((~np.isfinite(points).all(axis=1)).sum())
        raise InputError(f"{model_dir}: {bad} 3-D points have a NaN or infinite position; {FIX}")
    order = np.argsort(point_ids, kind="stable")
    return ColmapModel(cams, tuple(sorted(images, key=lambda im: im.name)), point_ids[order], points[order],
                       np.array(rgb, np.uint8).reshape(-1, 3)[order])


# ------------------------------------------------------------------------------------------------ writing
def _records(cameras: Cameras, ids: list[tuple[int, int]] | None):
    """Per view: ``(camera_id, image_id, model_id, params, qvec, tvec)``."""
    out = []
    for i, cam in enumerate(cameras):
        camera_id, image_id = ids[i] if ids is not None else (i + 1, i + 1)
        lens = cameras.distortion(i)
        model_id = PINHOLE_MODEL if lens is None else [m for m, _ in CAMERA_MODELS].index(lens.model)
        params = tuple(float(v) for v in cameras.intrinsics[i]) if lens is None else lens.params
        R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
        out.append((camera_id, image_id, model_id, params, rotation_to_quaternion(R), np.asarray(t, np.float64)))
    return out


def write_model(model_dir: str | os.PathLike, cameras: Cameras, points: np.ndarray | None = None,
                colors: np.ndarray | None = None, *, ids: list[tuple[int, int]] | None = None,
                text: bool = False) -> None:
    """Write ``cameras`` (one COLMAP camera per view, its model and parameters) and ``points`` ``(M, 3)`` with
    ``colors`` ``(M, 3)`` RGB in ``[0, 1]`` (rounded to 8 bits; default grey) as a COLMAP model into ``model_dir``
    (created): binary, or text with ``text``. ``ids``: ``(camera_id, image_id)`` per view (a feature database's),
    else 1 … C. Points get ids 1 … M in the given order, empty tracks and error 0."""
    model_dir = Path(model_dir)
    model_dir.mkdir(parents=True, exist_ok=True)
    xyz = np.zeros((0, 3)) if points is None else np.asarray(points, np.float64).reshape(-1, 3)
    rgb = np.full(xyz.shape, 0.5) if colors is None else np.asarray(colors, np.float64).reshape(-1, 3)
    if rgb.shape != xyz.shape:
        raise ValueError(f"{len(xyz)} points but colours of shape {rgb.shape}")
    rgb8 = np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)
    records = _records(cameras, ids)
    for ext in ("bin", "txt"):  # one model in the folder (the reader takes the binary one first), no stale rigs
        for name in (*FILES, "rigs", "frames"):
            (model_dir / f"{name}.{ext}").unlink(missing_ok=True)
    if text:
        _write_txt(model_dir, cameras, records, xyz, rgb8)
    else:
        _write_bin(model_dir, cameras, records, xyz, rgb8)


def _write_bin(model_dir: Path, cameras: Cameras, records, xyz: np.ndarray, rgb8: np.ndarray) -> None:
    cams = [struct.pack("<Q", len(records))]
    imgs = [struct.pack("<Q", len(records))]
    for (camera_id, image_id, model_id, params, q, t), name, (w, h) in zip(records, cameras.names, cameras.sizes):
        cams.append(struct.pack(f"<iiQQ{len(params)}d", camera_id, model_id, int(w), int(h), *params))
        imgs.append(struct.pack("<idddddddi", image_id, *q, *t, camera_id) + name.encode("utf-8") + b"\0"
                    + struct.pack("<Q", 0))
    pts = np.zeros(len(xyz), np.dtype([("id", "<u8"), ("xyz", "<f8", 3), ("rgb", "u1", 3), ("error", "<f8"),
                                       ("track", "<u8")]))
    pts["id"], pts["xyz"], pts["rgb"] = np.arange(1, len(xyz) + 1), xyz, rgb8
    (model_dir / "cameras.bin").write_bytes(b"".join(cams))
    (model_dir / "images.bin").write_bytes(b"".join(imgs))
    (model_dir / "points3D.bin").write_bytes(struct.pack("<Q", len(xyz)) + pts.tobytes())


def _write_txt(model_dir: Path, cameras: Cameras, records, xyz: np.ndarray, rgb8: np.ndarray) -> None:
    cams = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    imgs = ["# Image list with two lines of data per image:", "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
            "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    for (camera_id, image_id, model_id, params, q, t), name, (w, h) in zip(records, cameras.names, cameras.sizes):
        cams.append(" ".join([str(camera_id), CAMERA_MODELS[model_id][0], str(int(w)), str(int(h))]
                             + [repr(float(p)) for p in params]))
        imgs.append(" ".join([str(image_id)] + [repr(float(v)) for v in (*q, *t)] + [str(camera_id), name]))
        imgs.append("")
    pts = ["# 3D point list with one line of data per point:",
           "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
    pts += [f"{k} {p[0]!r} {p[1]!r} {p[2]!r} {c[0]} {c[1]} {c[2]} 0.0"
            for k, (p, c) in enumerate(zip(xyz.tolist(), rgb8.tolist()), start=1)]
    for name, lines in (("cameras", cams), ("images", imgs), ("points3D", pts)):
        (model_dir / f"{name}.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")
