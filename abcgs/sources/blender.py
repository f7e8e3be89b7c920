"""Reader ``blender``: NeRF-synthetic scenes (``transforms_train.json``, ``transforms_test.json``).

Each split file holds ``camera_angle_x`` (the horizontal field of view, radians; ``camera_angle_y`` when the pixels
are not square) and ``frames`` with ``file_path`` (``./train/r_0``, the ``.png`` implied) and ``transform_matrix``
(camera-to-world, OpenGL camera axes). The focal length is ``0.5 · W / tan(camera_angle_x / 2)`` for an image ``W``
pixels wide, the principal point the image centre. The views of every split present (``train``, ``test``) are
read, named ``<split>_<file name>`` (``train_r_0.png``). The images are RGBA: the ``reconstruct`` stage composites
them on the scene's stated ``background`` (params ``background: [r, g, b]``, default white, as NeRF-synthetic
results are reported). The scene frame is the file's world frame.
"""

from __future__ import annotations

import math
import os
from pathlib import Path, PurePosixPath

import numpy as np

from abcgs.cameras import Camera, check_intrinsics
from abcgs.errors import InputError
from abcgs.sources.base import ReadOptions
from abcgs.sources.lens import image_size
from abcgs.sources.transforms_json import OPENGL_TO_OPENCV, camera_to_world, frames_of, load_json, number
from abcgs.sources.validate import check_inside
from abcgs.types import SourceScene, View

SPLITS = ("train", "test")
DEFAULT_BACKGROUND = (1.0, 1.0, 1.0)


def _angle(path: Path, meta: dict, key: str) -> float | None:
    if key not in meta:
        return None
    a = number(path, key, meta[key])
    if not 0 < a < math.pi:
        raise InputError(f"{path}: {key} is {a}; it is a field of view in radians (0 .. pi)")
    return a


def read_blender_source(folder: str | os.PathLike, background: tuple[float, float, float] | None = None
                        ) -> SourceScene:
    """The views of ``folder/transforms_{train,test}.json`` (module docstring)."""
    folder = Path(folder)
    views = []
    for split in SPLITS:
        path = folder / f"transforms_{split}.json"
        if not path.is_file():
            continue
        meta = load_json(path)
        ax, ay = _angle(path, meta, "camera_angle_x"), _angle(path, meta, "camera_angle_y")
        if ax is None:
            raise InputError(f"{path} has no camera_angle_x (the horizontal field of view in radians)")
        for i, frame in enumerate(frames_of(path, meta)):
            rel = PurePosixPath(str(frame["file_path"]).replace("\\", "/"))
            image = check_inside(folder, folder / rel, f"{path}: frames[{i}].file_path {frame['file_path']!r}")
            if not image.suffix:
                image = image.with_name(image.name + ".png")
            if not image.is_file():
                raise InputError(f"{path}: frames[{i}].file_path {frame['file_path']!r} names {image}, which does not "
                                 "exist; the images lie beside the transforms files (train/, test/)")
            w, h = image_size(image)
            fx = 0.5 * w / math.tan(0.5 * ax)
            fy = 0.5 * h / math.tan(0.5 * ay) if ay is not None else fx
            check_intrinsics(fx, fy, w / 2.0, h / 2.0, w, h, f"{path}: frames[{i}] with {image.name}",
                             "correct camera_angle_x (radians), or the image")
            K = np.array([[fx, 0.0, w / 2.0], [0.0, fy, h / 2.0], [0.0, 0.0, 1.0]])
            c2w = camera_to_world(path, f"frames[{i}]", frame["transform_matrix"]) @ OPENGL_TO_OPENCV
            name = f"{split}_{image.stem}.png"
            views.append(View(name, image, Camera(name, K, np.linalg.inv(c2w), w, h)))
    if not views:
        raise InputError(f"{folder}: no transforms_train.json or transforms_test.json")
    names = [v.name for v in views]
    if len(set(names)) != len(names):
        raise InputError(f"{folder}: two frames of one split name the same image file; each frame needs its own image")
    bg = tuple(float(c) for c in (background if background is not None else DEFAULT_BACKGROUND))
    return SourceScene.from_views(views, format="blender", background=bg)


def read(folder: Path, options: ReadOptions) -> SourceScene:
    """The ``blender`` format's reading (its ``READER``: :mod:`abcgs.sources.formats.blender`)."""
    return read_blender_source(folder, options.background)
