"""Reader ``nerfstudio``: ``transforms.json`` as ``ns-process-data`` writes it.

Keys read (per frame, falling back to the file's top level): ``file_path``, ``transform_matrix`` (camera-to-world,
OpenGL camera axes: x right, y up, z back), ``fl_x``, ``fl_y``, ``cx``, ``cy``, ``w``, ``h``, ``camera_model``
(``OPENCV`` by default, ``OPENCV_FISHEYE``, ``PINHOLE``; ``SIMPLE_PINHOLE``, ``SIMPLE_RADIAL``, ``RADIAL`` as
COLMAP defines them), ``k1 k2 k3 k4 p1 p2``, ``mask_path``; at the top level ``applied_transform`` (3 × 4) and
``applied_scale``, and ``ply_file_path`` (the sparse points, in the file's frame).

Frames: nerfstudio saves poses as ``x_file = applied_scale · (A x_orig)`` with ``A = applied_transform`` (the
rotation ``ns-process-data`` applies to COLMAP's world). The reader undoes both, so the scene frame is the original
data's (COLMAP's) frame and :attr:`abcgs.types.SourceScene.frame` is ``(s·A)⁻¹``. Camera axes become OpenCV's (y and z flipped).
A camera whose ``w``/``h`` differ from its image (``images:`` naming a downscaled folder, ``images_2``) is scaled to
it, as for COLMAP. Masks (``mask_path``: non-zero = keep) are passed to the ``masks`` stage as labels 1 (kept) and
2 (masked out).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path, PurePosixPath

import numpy as np

from abcgs.cameras import Camera, Distortion, check_intrinsics, check_rotation
from abcgs.errors import InputError
from abcgs.sources.base import ReadOptions
from abcgs.sources.detect import DEFAULT_IMAGES
from abcgs.sources.lens import fit_to_image, image_size, pinhole_and_lens
from abcgs.sources.transforms_json import OPENGL_TO_OPENCV, camera_to_world, frames_of, load_json, number, number_array
from abcgs.sources.validate import check_file_name, check_inside
from abcgs.types import SourceScene, View

log = logging.getLogger(__name__)
TRANSFORMS = "transforms.json"
_LENS_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


def applied_similarity(path: Path, meta: dict) -> np.ndarray:
    """``(4, 4)`` similarity from the original data's frame to the file's: ``applied_scale · applied_transform``."""
    A = np.eye(4)
    if "applied_transform" in meta:
        m = number_array(path, "applied_transform", meta["applied_transform"])
        if m.shape not in ((3, 4), (4, 4)):
            raise InputError(f"{path}: applied_transform has shape {m.shape}; nerfstudio writes a 3x4 matrix")
        A[:3] = m[:3]
        check_rotation(A[:3, :3], f"{path}: applied_transform", "nerfstudio writes a rotation and a translation")
    s = number(path, "applied_scale", meta.get("applied_scale", 1.0))
    if not 1e-12 < s < 1e12:  # its cube (the similarity's determinant) stays a normal float64
        raise InputError(f"{path}: applied_scale is {s:g}; a scale between 1e-12 and 1e12 is one nerfstudio writes "
                         "(it is 1 / the scene's extent); re-export the dataset")
    return np.diag([s, s, s, 1.0]) @ A


def to_scene(c2w_file: np.ndarray, file_from_scene: np.ndarray) -> np.ndarray:
    """A camera-to-world pose in the file's frame → the scene's (a rigid pose: the similarity's scale goes into the
    position only)."""
    s = np.cbrt(np.linalg.det(file_from_scene[:3, :3]))
    rot = file_from_scene[:3, :3] / s
    out = np.eye(4)
    out[:3, :3] = rot.T @ c2w_file[:3, :3]
    out[:3, 3] = rot.T @ (c2w_file[:3, 3] / s - file_from_scene[:3, 3] / s)
    return out


def _lens(path: Path, where: str, model: str, fx: float, fy: float, cx: float, cy: float, get) -> list[float] | None:
    k = {key: number(path, f"{where}.{key}", get(key, 0.0)) for key in _LENS_KEYS}
    if model == "OPENCV":
        if k["k3"] or k["k4"]:
            return ["FULL_OPENCV", fx, fy, cx, cy, k["k1"], k["k2"], k["p1"], k["p2"], k["k3"], k["k4"], 0.0, 0.0]
        return ["OPENCV", fx, fy, cx, cy, k["k1"], k["k2"], k["p1"], k["p2"]]
    if model == "OPENCV_FISHEYE":
        return ["OPENCV_FISHEYE", fx, fy, cx, cy, k["k1"], k["k2"], k["k3"], k["k4"]]
    if model == "PINHOLE":
        return None
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        extra = {"SIMPLE_PINHOLE": [], "SIMPLE_RADIAL": [k["k1"]], "RADIAL": [k["k1"], k["k2"]]}[model]
        return [model, 0.5 * (fx + fy), cx, cy, *extra]
    raise InputError(f"{path}: {where} has camera_model {model!r}; abcgs reads OPENCV, OPENCV_FISHEYE, PINHOLE, "
                     "SIMPLE_PINHOLE, SIMPLE_RADIAL and RADIAL (re-process equirectangular captures into perspective "
                     "views)")


def frame_camera(path: Path, meta: dict, frame: dict, index: int, name: str) -> tuple[Camera, Distortion | None]:
    """One frame's camera in the file's frame with OpenCV axes, at the calibrated size ``w`` × ``h``."""
    where = f"frames[{index}] ({frame['file_path']})"

    def get(key: str, default=None):
        return frame.get(key, meta.get(key, default))

    missing = [k for k in ("fl_x", "cx", "cy", "w", "h") if get(k) is None]
    if missing:
        raise InputError(f"{path}: {where} has no {', '.join(missing)} (neither in the frame nor at the top level)")
    num = {k: number(path, f"{where}.{k}", get(k)) for k in ("fl_x", "cx", "cy", "w", "h")}
    fx, cx, cy, w, h = num["fl_x"], num["cx"], num["cy"], num["w"], num["h"]
    fy = number(path, f"{where}.fl_y", get("fl_y", fx))
    check_intrinsics(fx, fy, cx, cy, w, h, f"{path}: {where}", "correct fl_x, fl_y, cx, cy, w and h (pixels of the "
                     "calibrated images), or re-export the dataset")
    w, h = int(w), int(h)
    lens = _lens(path, where, str(get("camera_model", "OPENCV")), fx, fy, cx, cy, get)
    c2w = camera_to_world(path, where, frame["transform_matrix"]) @ OPENGL_TO_OPENCV
    if lens is None:
        K, dist = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), None
    else:
        K, dist = pinhole_and_lens(lens[0], np.asarray(lens[1:], np.float64), w, h)
    return Camera(name, K, np.linalg.inv(c2w), w, h), dist


def _image_path(folder: Path, file_path: str, images: str | None) -> Path:
    rel = PurePosixPath(file_path.replace("\\", "/"))
    if rel.is_absolute():
        return Path(rel)
    if images and images != DEFAULT_IMAGES and rel.parts and rel.parts[0] == DEFAULT_IMAGES:
        rel = PurePosixPath(images, *rel.parts[1:])  # nerfstudio's downscaled copies: images_2/frame_00001.png
    return folder / rel


def view_names(file_paths: list[str]) -> list[str]:
    """Unique view names: the file names, or the paths with ``/`` → ``_`` where file names repeat."""
    base = [PurePosixPath(p.replace("\\", "/")).name for p in file_paths]
    if len(set(base)) == len(base):
        return base
    return [p.replace("\\", "/").lstrip("./").replace("/", "_") for p in file_paths]


def read_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(M, 3)`` positions and ``(M, 3)`` colours in ``[0, 1]`` of a point-cloud PLY (``x y z red green blue``)."""
    from plyfile import PlyData

    try:
        vertex = PlyData.read(str(path))["vertex"]
        xyz = np.stack([vertex[k] for k in "xyz"], axis=1).astype(np.float64)
    except Exception as exc:  # plyfile raises several types for foreign files
        raise InputError(f"{path} is not a point-cloud PLY with x, y, z ({exc})") from None
    if not np.isfinite(xyz).all():
        raise InputError(f"{path}: {int((~np.isfinite(xyz).all(axis=1)).sum())} points have a NaN or infinite "
                         "position; re-export the point cloud")
    names = vertex.data.dtype.names or ()
    if all(k in names for k in ("red", "green", "blue")):
        rgb = np.stack([vertex[k] for k in ("red", "green", "blue")], axis=1).astype(np.float32) / 255.0
    else:
        rgb = np.full((len(xyz), 3), 0.5, np.float32)
    return xyz, rgb


def read_nerfstudio_source(folder: str | os.PathLike, images: str | None = None) -> SourceScene:
    """``folder/transforms.json`` and the images (and masks) it names (module docstring)."""
    folder = Path(folder)
    path = folder / TRANSFORMS
    meta = load_json(path)
    indexed = sorted(enumerate(frames_of(path, meta)), key=lambda kv: str(kv[1]["file_path"]))
    frames = [f for _, f in indexed]
    file_from_scene = applied_similarity(path, meta)
    names = view_names([str(f["file_path"]) for f in frames])
    views = []
    for (i, frame), name in zip(indexed, names):  # i: the frame's index in the file, for messages
        image = check_inside(folder, _image_path(folder, str(frame["file_path"]), images),
                             f"{path}: frames[{i}].file_path {frame['file_path']!r}")
        if not image.is_file() and not image.suffix:
            image = image.with_suffix(".png")
        if not image.is_file():
            raise InputError(f"{path}: frames[{i}].file_path {frame['file_path']!r} names {image}, which does not exist; "
                             "copy the images beside transforms.json (or set the scene entry's `images:` to the "
                             "folder that holds them)")
        cam, lens = frame_camera(path, meta, frame, i, name)
        cam, lens = fit_to_image(cam, lens, image_size(image), f"{path} frames[{i}] and {image}")
        c2w = to_scene(np.linalg.inv(cam.viewmat), file_from_scene)
        cam = Camera(name, cam.K, np.linalg.inv(c2w), cam.width, cam.height)
        mask = None
        if frame.get("mask_path"):
            where = f"{path}: frames[{i}].mask_path"
            mask = check_inside(folder, folder / check_file_name(frame["mask_path"], where), where)
            if not mask.is_file():
                raise InputError(f"{path}: frames[{i}].mask_path names {mask}, which does not exist; copy the mask "
                                 "there or remove the key")
        views.append(View(name, image, cam, lens, mask))
    points = colors = None
    if meta.get("ply_file_path"):
        ply = check_inside(folder, folder / check_file_name(meta["ply_file_path"], f"{path}: ply_file_path"),
                           f"{path}: ply_file_path")
        if not ply.is_file():
            raise InputError(f"{path}: ply_file_path names {ply}, which does not exist; copy it there or remove the key")
        xyz, colors = read_points(ply)
        scene_from_file = np.linalg.inv(file_from_scene)
        points = (xyz @ scene_from_file[:3, :3].T + scene_from_file[:3, 3]).astype(np.float32)
    notes = []
    if not np.allclose(file_from_scene, np.eye(4)):
        notes.append("applied_transform/applied_scale undone: the scene is in the original data's frame")
    return SourceScene.from_views(views, points=points, colors=colors, format="nerfstudio",
                            frame=np.linalg.inv(file_from_scene), notes=tuple(notes))


def read(folder: Path, options: ReadOptions) -> SourceScene:
    """The ``nerfstudio`` format's reading (its ``READER``: :mod:`abcgs.sources.formats.nerfstudio`)."""
    return read_nerfstudio_source(folder, options.images)
