"""The calibrated scene every stage after ``reconstruct`` reads, and the one way it is written and read back.

The ``reconstruct`` stage leaves a COLMAP layout (:class:`abcgs.layout.ColmapDir`)::

    sparse/{cameras,images,points3D}.bin   undistorted PINHOLE model: the cameras and the sparse points
    images/                                the views (undistorted)
    alpha/, masks/                         an object's alpha maps, the views' label maps (when there are any)
    scene.json                             everything else the scene is (below)

:func:`write_scene` writes a :class:`~abcgs.types.CalibratedScene` there and :func:`read_scene` reads it back; every stage,
the viewer, the benchmarks and the tests that take a reconstructed scene read it through :func:`read_scene` only
(a writer of the layout reads the scene it has staged with :func:`layout_scene`). ``scene.json``
(version :data:`SCENE_VERSION`) holds the scene's format, its frame (``4 × 4`` float64, written as JSON numbers,
which Python reads back to the same bits), its :class:`~abcgs.types.Background`, the splat it names, its depth
range, notes and metadata, and per view its name and the paths of its image, alpha map and label map relative to
the folder. The cameras and points live in ``sparse/`` alone, read by :mod:`abcgs.io.colmap` (no pycolmap needed,
so the stages that only read a scene run where no pycolmap wheel exists); points come in the model's canonical
order, by point id.

``scene.json`` is untrusted input: it is read through :func:`abcgs.io.guarded.load_json` (size and depth bounded)
and every value is checked for its type and finiteness; a missing file or one of another version is refused in one
line that says to re-run the ``reconstruct`` stage.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from abcgs.cameras import CAMERA_MODELS
from abcgs.errors import InputError
from abcgs.io.atomic import write_json
from abcgs.io.colmap import read_model, write_model
from abcgs.io.guarded import load_json
from abcgs.io.images import image_header
from abcgs.layout import ColmapDir
from abcgs.types import FRAME_FILLING, Background, CalibratedScene

SCENE_VERSION = 1
"""The version of ``scene.json`` this code writes and reads."""
LABEL_MODES = ("1", "L", "I", "I;16", "I;16B", "I;16L")
"""PIL's modes of a single-channel image, what a view's label map must be."""

MAX_SCENE_JSON_BYTES = 64 << 20
"""Largest ``scene.json`` read (a scene of 1000 views writes about 150 kB)."""


def _model_scene(model_dir: Path, images_dir: Path) -> CalibratedScene:
    """The model part of :func:`read_scene` and :func:`layout_scene`: the undistorted COLMAP model ``model_dir``
    (``*.bin`` or ``*.txt``, PINHOLE or SIMPLE_PINHOLE cameras) and its images in ``images_dir`` as a
    :class:`~abcgs.types.CalibratedScene` (views sorted by image name; ``alpha_paths`` from ``alpha/`` beside ``images/``
    when the reconstruct stage wrote it)."""
    model = read_model(model_dir)
    if not model.images:
        raise InputError(f"COLMAP model {model_dir} has no registered images")
    for im in model.images:
        cam = model.cameras_by_id[im.camera_id]
        if cam.model_id not in (0, 1):
            raise InputError(
                f"image {im.name} of {model_dir} uses a {CAMERA_MODELS[cam.model_id][0]} camera; a scene's layout "
                "holds an undistorted (PINHOLE) model, the sparse/ folder the reconstruct stage writes")
    cameras = model.cameras()
    paths = tuple(images_dir / name for name in cameras.names)
    missing = [p.name for p in paths if not p.is_file()]
    if missing:
        raise InputError(f"{len(missing)} image(s) of the model are missing from {images_dir}: {', '.join(missing[:10])}")
    alpha_dir = images_dir.parent / "alpha"
    alphas = tuple(alpha_dir / name for name in cameras.names) if alpha_dir.is_dir() else None
    if alphas is not None and not all(p.is_file() for p in alphas):
        raise InputError(f"{alpha_dir} lacks the alpha map of some views; re-run the reconstruct stage")
    return CalibratedScene(cameras, paths, model.points.astype("float32"), (model.colors / 255.0).astype("float32"),
                 alpha_paths=alphas)


def layout_scene(root: str | os.PathLike, **fields: Any) -> CalibratedScene:
    """The scene of the COLMAP layout ``root`` as a writer of it left it (the model in ``sparse/``, the views in
    ``images/``, alpha maps from ``alpha/``, each view's label map ``masks/<stem>.png`` where there is one), with the
    :class:`~abcgs.types.CalibratedScene` ``fields`` the model does not hold (format, frame, background, …): what
    :func:`write_scene` is given once that layout is complete (``background=None``: a frame-filling scene)."""
    d = ColmapDir(Path(root))
    scene = _model_scene(d.sparse, d.images)
    masks = tuple(d.masks / f"{PurePosixPath(n).stem}.png" for n in scene.cameras.names)
    masks = tuple(m if m.is_file() else None for m in masks)
    background = fields.pop("background", None) or FRAME_FILLING
    return CalibratedScene(scene.cameras, scene.image_paths, scene.points, scene.colors, background=background,
                           label_paths=masks if any(m is not None for m in masks) else None,
                           alpha_paths=scene.alpha_paths, **fields)


# ------------------------------------------------------------------------------------------------ writing
def _relative(path: Path | None, root: Path, what: str) -> str | None:
    if path is None:
        return None
    try:
        return Path(path).resolve().relative_to(root.resolve()).as_posix()
    except ValueError:
        raise ValueError(f"the {what} {path} is not inside {root}: write_scene stores a scene whose files lie in its "
                         "folder (stage them there first)") from None


def _model_holds(model_dir: Path, scene: CalibratedScene) -> bool:
    """Whether the COLMAP model in ``model_dir`` reads back as exactly ``scene``'s cameras and points."""
    if not model_dir.is_dir() or not any(model_dir.glob("images.*")):
        return False
    model = read_model(model_dir)
    cams, ours = model.cameras(), scene.cameras
    if cams.names != ours.names or not all(np.array_equal(getattr(cams, k), getattr(ours, k)) for k in (
            "viewmats", "intrinsics", "sizes", "camera_models", "distortion_params")):
        return False
    points = np.zeros((0, 3), np.float32) if scene.points is None else np.asarray(scene.points, np.float32)
    colors = np.zeros((0, 3), np.float32) if scene.colors is None else np.asarray(scene.colors, np.float32)
    return (np.array_equal(model.points.astype(np.float32), points)
            and np.array_equal((model.colors / 255.0).astype(np.float32), colors))


def write_scene(scene: CalibratedScene, root: str | os.PathLike) -> Path:
    """Write ``scene`` into the folder ``root``: its cameras and points as the COLMAP model ``sparse/`` (kept as it
    is when it already reads back as exactly these: the model structure from motion or the undistorter wrote) and
    the rest as ``scene.json`` (module docstring). The scene's images, alpha and label maps must lie inside ``root``
    (the ``reconstruct`` stage stages them there) and its cameras be pinhole ones; returns ``scene.json``'s path."""
    d = ColmapDir(Path(root))
    if scene.cameras.distorted.any():
        raise ValueError("write_scene stores an undistorted scene (PINHOLE cameras); undistort it first")
    frame = np.asarray(scene.frame, np.float64)
    if frame.shape != (4, 4) or not np.isfinite(frame).all():
        raise ValueError(f"CalibratedScene.frame must be a finite 4 x 4 matrix, got {frame.tolist()}")
    c = len(scene.cameras)
    alphas = scene.alpha_paths or (None,) * c
    masks = scene.label_paths or (None,) * c
    views = [{"name": name, "image": _relative(image, d.root, "image"), "alpha": _relative(alpha, d.root, "alpha map"),
              "mask": _relative(mask, d.root, "label map")}
             for name, image, alpha, mask in zip(scene.cameras.names, scene.image_paths, alphas, masks)]
    if not _model_holds(d.sparse, scene):
        write_model(d.sparse, scene.cameras, scene.points, scene.colors)
    background = scene.background
    write_json(d.scene, {
        "version": SCENE_VERSION, "format": scene.format, "frame": frame.tolist(), "background": background.to_json(),
        "splat": None if scene.splat is None else str(scene.splat),
        "depth_range": None if scene.depth_range is None else [float(v) for v in scene.depth_range],
        "notes": list(scene.notes), "metadata": dict(scene.metadata), "views": views})
    return d.scene


# ------------------------------------------------------------------------------------------------ reading
class _Bad(Exception):
    """A value of ``scene.json`` that is not what it must be (the reason)."""


def _check_finite(value: Any, where: str) -> None:
    """:class:`_Bad` for a non-finite number anywhere in the parsed JSON ``value`` (Python's parser reads ``NaN``)."""
    if isinstance(value, float) and not math.isfinite(value):
        raise _Bad(f"{where} holds {value}, not a finite number")
    if isinstance(value, Mapping):
        for k, v in value.items():
            _check_finite(v, f"{where}.{k}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _check_finite(v, f"{where}[{i}]")


def _fits(value: Any, shape: tuple[int, ...]) -> bool:
    """Whether ``value`` is nested lists of ``shape`` whose leaves are numbers (booleans are not)."""
    if not shape:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    return isinstance(value, list) and len(value) == shape[0] and all(_fits(v, shape[1:]) for v in value)


def _numbers(value: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    """The nested list ``value`` of numbers as a float64 array of ``shape``."""
    if not _fits(value, shape):
        raise _Bad(f"{where} must be {' x '.join(map(str, shape))} numbers, got {str(value)[:80]}")
    return np.array(value, dtype=np.float64)


def _typed(doc: Mapping, key: str, kinds: tuple[type, ...], where: str = "") -> Any:
    """``doc[key]`` when it is one of ``kinds`` (a boolean only where ``bool`` is one of them)."""
    if key not in doc:
        raise _Bad(f"{where}{key} is missing")
    value = doc[key]
    if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
        raise _Bad(f"{where}{key} is {type(value).__name__} {str(value)[:60]}")
    return value


def _inside(root: Path, rel: str | None, where: str) -> Path | None:
    """``root / rel`` for a relative POSIX path that stays inside ``root``."""
    if rel is None:
        return None
    p = PurePosixPath(rel)
    if p.is_absolute() or ".." in p.parts or not p.parts:
        raise _Bad(f"{where} {rel!r} is not a path inside the scene's folder")
    return root / p


def _background(doc: Mapping) -> Background:
    bg = _typed(doc, "background", (dict,))
    color = _numbers(_typed(bg, "color", (list,), "background."), (3,), "background.color")
    if ((color < 0) | (color > 1)).any():
        raise _Bad(f"background.color {color.tolist()} lies outside [0, 1]")
    rgb = (float(color[0]), float(color[1]), float(color[2]))
    transparent = _typed(bg, "transparent", (bool,), "background.")
    return Background(rgb, transparent, _typed(bg, "object", (bool,), "background."))


def _views(root: Path, doc: Mapping, names: Sequence[str]
           ) -> tuple[tuple[Path, ...], list[Path | None], list[Path | None]]:
    """The images, alpha maps and label maps of ``doc``'s views, which must be the model's ``names`` in order."""
    views = _typed(doc, "views", (list,))
    if len(views) != len(names):
        raise _Bad(f"views lists {len(views)} views; sparse/ holds {len(names)}")
    images, alphas, masks = [], [], []
    for i, (v, name) in enumerate(zip(views, names)):
        where = f"views[{i}]."
        if not isinstance(v, dict) or _typed(v, "name", (str,), where) != name:
            raise _Bad(f"views[{i}] is not the model's view {name!r}")
        images.append(_inside(root, _typed(v, "image", (str,), where), where + "image"))
        alphas.append(_inside(root, _typed(v, "alpha", (str, type(None)), where), where + "alpha"))
        masks.append(_inside(root, _typed(v, "mask", (str, type(None)), where), where + "mask"))
    missing = [str(p) for p in (*images, *alphas, *masks) if p is not None and not p.is_file()]
    if missing:
        raise _Bad(f"{len(missing)} file(s) it names are missing: {', '.join(missing[:5])}")
    seen: dict[Path, str] = {}
    for kind, paths in (("image", images), ("alpha", alphas), ("mask", masks)):
        for i, path in enumerate(paths):
            if path is None:
                continue
            key = path.resolve()
            if key in seen:
                raise _Bad(f"views[{i}].{kind} {path} is also {seen[key]}: each view has files of its own")
            seen[key] = f"views[{i}].{kind}"
    for i, path in enumerate(masks):
        if path is not None and (mode := image_header(path, "label map")[2]) not in LABEL_MODES:
            raise _Bad(f"views[{i}].mask {path} is a {mode} image, not a single-channel label map")
    return tuple(images), alphas, masks


def _frame(doc: Mapping) -> np.ndarray:
    """``frame``: a similarity, a rotation times a positive scale and a translation over ``[0, 0, 0, 1]``."""
    frame = _numbers(_typed(doc, "frame", (list,)), (4, 4), "frame")
    if not np.allclose(frame[3], [0.0, 0.0, 0.0, 1.0]):
        raise _Bad(f"frame's last row is {frame[3].tolist()}, not [0, 0, 0, 1]")
    m = frame[:3, :3]
    det = float(np.linalg.det(m))
    if not det > 0:
        raise _Bad(f"frame's rotation part has determinant {det:.3g}: not a rotation times a positive scale")
    r = m / np.cbrt(det)
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-6):
        raise _Bad("frame's rotation part is not a rotation times a positive scale (its columns are not orthogonal "
                   "and of one length)")
    return frame


def _depth_range(doc: Mapping) -> tuple[float, float] | None:
    """``depth_range``: None, or near and far with 0 < near < far (world units)."""
    depth = _typed(doc, "depth_range", (list, type(None)))
    if depth is None:
        return None
    near, far = (float(v) for v in _numbers(depth, (2,), "depth_range"))
    if not 0 < near < far:
        raise _Bad(f"depth_range [{near}, {far}] is not a near and a far distance with 0 < near < far")
    return near, far


def _fields(root: Path, doc: Any, names: Sequence[str]) -> dict:
    """The :class:`~abcgs.types.CalibratedScene` fields of the parsed ``scene.json`` ``doc`` besides the model's."""
    if not isinstance(doc, dict):
        raise _Bad(f"it holds a {type(doc).__name__}, not an object")
    _check_finite(doc, "scene")
    images, alphas, masks = _views(root, doc, names)
    splat = _typed(doc, "splat", (str, type(None)))
    notes = _typed(doc, "notes", (list,))
    if not all(isinstance(n, str) for n in notes):
        raise _Bad("notes must be strings")
    return {"image_paths": images, "format": _typed(doc, "format", (str,)),
            "frame": _frame(doc), "background": _background(doc), "splat": None if splat is None else Path(splat),
            "depth_range": _depth_range(doc),
            "notes": tuple(notes), "metadata": _typed(doc, "metadata", (dict,)),
            "alpha_paths": tuple(alphas) if all(a is not None for a in alphas) else None,  # type: ignore[arg-type]
            "label_paths": tuple(masks) if any(m is not None for m in masks) else None}


def read_scene(root: str | os.PathLike) -> CalibratedScene:
    """The :class:`~abcgs.types.CalibratedScene` that :func:`write_scene` (the ``reconstruct`` stage) wrote into ``root``: the
    cameras and points of ``sparse/``, everything else from ``scene.json``. :class:`~abcgs.errors.InputError` in one
    line naming the file for a missing ``scene.json``, one of another version, or any value of the wrong type, not
    finite, or naming a file outside ``root`` or absent."""
    d = ColmapDir(Path(root))
    rerun = "re-run the reconstruct stage of this scene (dvc repro reconstruct@<scene>)"
    if not d.scene.exists() and not d.scene.is_symlink():
        raise InputError(f"{d.scene} does not exist: {d.root} was not written by this version of the reconstruct "
                         f"stage; {rerun}")
    doc = load_json(d.scene, "scene record", MAX_SCENE_JSON_BYTES)  # a FIFO, a device or a link loop: one line
    version = doc.get("version") if isinstance(doc, dict) else None
    if not isinstance(version, int) or isinstance(version, bool):
        raise InputError(f"{d.scene} holds version {type(version).__name__} {str(version)[:20]!r}, not the integer "
                         f"version of a scene record (this abcgs reads {SCENE_VERSION}): {rerun}")
    if version != SCENE_VERSION:
        raise InputError(f"{d.scene} is scene record version {version}; this abcgs reads version "
                         f"{SCENE_VERSION}: {rerun}")
    base = _model_scene(d.sparse, d.images)
    try:
        fields = _fields(d.root, doc, base.cameras.names)
    except _Bad as exc:
        raise InputError(f"{d.scene} is not a scene record ({exc}); {rerun}") from None
    return CalibratedScene(base.cameras, points=base.points, colors=base.colors, **fields)
