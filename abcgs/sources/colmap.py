"""Reader ``colmap``: a COLMAP model (``sparse/0/`` or ``sparse/``, binary or text) and its images.

Mip-NeRF 360, Tanks and Temples, INRIA's 3DGS data and LLFF releases ship this layout::

    <scene>/images/…            the images the model was made from (or images_2/4/8: `images:` in params)
    <scene>/sparse/0/cameras.bin, images.bin, points3D.bin   (or .txt; or directly in sparse/)

The model is read by :mod:`abcgs.io.colmap` (every file checked as untrusted input; points by id). Any COLMAP
camera model is accepted: a distorting one is carried as the view's
:class:`~abcgs.sources.base.Distortion` and undistorted by the ``reconstruct`` stage as it undistorts its own SfM
model. A model calibrated at another size than the images used (full-size model, ``images_8``) is scaled to the
images (:func:`abcgs.sources.lens.fit_to_image`), with an error when they are not the same picture at another scale.
The scene frame is the model's world frame.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.io.colmap import read_model
from abcgs.sources.base import ReadOptions
from abcgs.sources.detect import DEFAULT_IMAGES, colmap_model_dir, image_files
from abcgs.sources.lens import fit_to_image, image_size, pinhole_and_lens
from abcgs.sources.validate import check_count, check_inside
from abcgs.types import SourceScene, View

log = logging.getLogger(__name__)


def _examples(names: list[str], n: int = 3) -> str:
    return ", ".join(names[:n]) + (f" … (+{len(names) - n} more)" if len(names) > n else "")


def read_colmap_source(folder: str | os.PathLike, images: str | None = None) -> SourceScene:
    """Read ``folder``'s COLMAP model and the images in ``folder/images`` (module docstring)."""
    folder = Path(folder)
    model_dir = colmap_model_dir(folder)
    if model_dir is None:
        raise InputError(f"{folder}: no COLMAP model (looked for sparse/0/cameras.bin|txt and sparse/cameras.bin|txt); "
                         "copy the model there, or set the scene's `format:` to the dataset's kind")
    images_dir = folder / (images or DEFAULT_IMAGES)
    files = image_files(images_dir)
    if not files:
        raise InputError(f"{images_dir} holds no images, but the COLMAP model {model_dir} needs them; put them there, or "
                         "name the image folder in the scene's entry (`images: images_4`)")
    model = read_model(model_dir)  # record counts against file sizes, plausible intrinsics, finite poses
    posed = list(model.images)
    if not posed:
        raise InputError(f"the COLMAP model {model_dir} has no registered images; re-run its reconstruction")
    check_count(len(posed), str(model_dir))
    for im in posed:
        check_inside(folder, images_dir / im.name, f"{model_dir} image {im.name!r}")
    on_disk = {p.name for p in files}
    found = [im for im in posed if (images_dir / im.name).is_file()]
    if not found:
        raise InputError(
            f"none of the {len(posed)} images of the COLMAP model {model_dir} is in {images_dir} (the model names "
            f"{_examples([im.name for im in posed])}; the folder holds {_examples(sorted(on_disk))}); use the image "
            "folder the model was made from (the scene entry's `images:`)")
    notes = []
    missing = [im.name for im in posed if not (images_dir / im.name).is_file()]
    if missing:
        notes.append(f"{len(missing)} image(s) of the model are not in {images_dir} and are left out: {_examples(missing)}")
    extra = sorted(on_disk - {Path(im.name).name for im in posed})
    if extra:
        notes.append(f"{len(extra)} image(s) in {images_dir} have no camera in the model and are left out: "
                     f"{_examples(extra)}")
    views, scaled = [], set()
    for im in found:
        cam = model.cameras_by_id[im.camera_id]
        K, lens = pinhole_and_lens(cam.model, np.asarray(cam.params), cam.width, cam.height)
        path = images_dir / im.name
        camera, lens = fit_to_image(Camera(im.name, K, im.viewmat, int(cam.width), int(cam.height)), lens,
                                    image_size(path), f"{model_dir} camera {im.camera_id} and {path}")
        if (camera.width, camera.height) != (cam.width, cam.height):
            scaled.add((cam.width, cam.height, camera.width, camera.height))
        views.append(View(im.name, path, camera, lens))
    for wm, hm, wi, hi in sorted(scaled):
        notes.append(f"cameras calibrated at {wm}x{hm} scaled to the {wi}x{hi} images of {images_dir.name}/")
    xyz = model.points.astype(np.float32)
    rgb = model.colors.astype(np.float32) / 255.0
    return SourceScene.from_views(views, points=xyz if len(xyz) else None, colors=rgb if len(xyz) else None,
                            format="colmap", notes=tuple(notes))


def read(folder: Path, options: ReadOptions) -> SourceScene:
    """The ``colmap`` format's reading (its ``READER``: :mod:`abcgs.sources.formats.colmap`)."""
    return read_colmap_source(folder, options.images)
