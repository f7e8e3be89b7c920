"""The contract every scene reader fulfils: a scene is images + calibrated cameras + optional points.

A reader (one module per format in :mod:`abcgs.sources`) turns a dataset folder into a :class:`SourceScene`:

- every view's :class:`abcgs.cameras.Camera` is in the *scene frame* with OpenCV camera axes (x right, y down,
  z forward), ``viewmat`` world→camera, ``K`` at the pixel size of the view's image file as it lies on disk
  (pixel centres at +0.5);
- a view whose lens has distortion carries it as a COLMAP camera model (:class:`Distortion`); the ``reconstruct``
  stage undistorts it as it undistorts its own SfM model;
- the scene frame is the dataset's own world frame up to the similarity :attr:`SourceScene.frame` that the reader
  undoes (nerfstudio's ``applied_transform`` / ``applied_scale``); nothing is re-centred or re-scaled, so that a
  splat trained on the same dataset lines up with the cameras.

This module imports nothing heavier than numpy: :mod:`abcgs.preflight` (which every stage imports) reaches it
through :mod:`abcgs.sources.detect`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, get_args

import numpy as np

from abcgs.types import SceneFormat

if TYPE_CHECKING:
    from abcgs.cameras import Camera

FORMATS: tuple[str, ...] = get_args(SceneFormat)


@dataclass(frozen=True)
class Distortion:
    """A view's lens as a COLMAP camera model.

    Attributes:
        model: COLMAP's model name (``SIMPLE_RADIAL``, ``OPENCV``, ``OPENCV_FISHEYE``, …).
        params: the model's full parameter vector in COLMAP's order (focal length(s) and principal point included),
            in pixels of the view's image as it lies on disk.
    """

    model: str
    params: tuple[float, ...]


@dataclass(frozen=True)
class SourceView:
    """One view of a scene as a reader found it.

    Attributes:
        name: the view's name (unique in the scene; the ``reconstruct`` stage writes the image under it, ``.png``
            for images it converts).
        image_path: the image file on disk.
        camera: pinhole part of the view's camera in the scene frame, OpenCV axes, at the image's pixel size
            (``camera.name == name``). Exact for an undistorted view; for a distorted one its ``K`` holds the
            model's focal length and principal point and :attr:`distortion` the rest.
        distortion: the lens model when it is not a plain pinhole, else ``None``.
        mask_path: a mask of the view (nerfstudio's ``mask_path``: non-zero = keep), or ``None``.
    """

    name: str
    image_path: Path
    camera: Camera
    distortion: Distortion | None = None
    mask_path: Path | None = None


@dataclass(frozen=True)
class SourceScene:
    """A scene as a reader found it (module docstring for the frame conventions).

    Attributes:
        format: the format it was read as.
        views: the views, sorted by name.
        points: ``(M, 3) float32`` sparse points in the scene frame (world units), or ``None`` when the dataset has
            none (the ``reconstruct`` stage then triangulates them from the given cameras).
        colors: ``(M, 3) float32`` their RGB colours in ``[0, 1]``, or ``None`` with ``points``.
        frame: ``(4, 4) float64`` similarity from the dataset files' world frame to the scene frame (identity when
            the reader keeps the files' frame, as for COLMAP, LLFF and Blender).
        background: ``(3,)`` RGB in ``[0, 1]`` that transparent pixels are composited on (Blender), or ``None``.
        depth_range: ``(near, far)`` in world units when the dataset states it (LLFF's bounds), else ``None``.
        notes: what the reader did that the user should know (scaled a model, composited alpha, …), for logs.
    """

    format: SceneFormat
    views: tuple[SourceView, ...]
    points: np.ndarray | None = None
    colors: np.ndarray | None = None
    frame: np.ndarray = field(default_factory=lambda: np.eye(4))
    background: tuple[float, float, float] | None = None
    depth_range: tuple[float, float] | None = None
    notes: tuple[str, ...] = ()

    @property
    def cameras(self) -> list[Camera]:
        """The views' cameras, same order as :attr:`views`."""
        return [v.camera for v in self.views]


@dataclass(frozen=True)
class ReadOptions:
    """What a reader may be told besides the folder; each reader uses the options of its format and ignores the rest.

    Attributes:
        images: the image subfolder (``colmap``, ``llff``, ``nerfstudio``; default ``images``).
        background: RGB in ``[0, 1]`` behind RGBA images (``blender``) and a bare splat's renders.
        views: a :class:`~abcgs.splats.params.SplatViewsParams`: the cameras made around a bare splat.
        work: a folder for a bare splat's renders (its views' images).
        drop_invalid: drop a bare splat's non-finite Gaussians instead of refusing it.
    """

    images: str | None = None
    background: tuple[float, float, float] | None = None
    views: Any = None
    work: Path | None = None
    drop_invalid: bool = False


@dataclass(frozen=True)
class SceneReader:
    """One scene format's reader. Each reader module of :mod:`abcgs.sources` (named like its format) defines
    ``READER``; :func:`abcgs.sources.read.reader_of` finds it, and :func:`abcgs.sources.read.register` adds one at
    run time.

    Attributes:
        name: the format (``params.yaml``'s ``format``; :data:`abcgs.types.SceneFormat` lists the built-in ones).
        read: ``(folder, options) → SourceScene``.
        marker: what a scene of the format is recognised by (for messages: ``sparse/0``, ``transforms.json``).
        detect: whether auto-detection takes a folder for this format, for a reader added at run time; the built-in
            formats are told apart by :func:`abcgs.sources.detect.detect_format`, which reads no reader module.
        check: whether the cameras read are checked (:func:`abcgs.sources.validate.check_cameras`); a bare splat's
            are made around it and not read.
    """

    name: str
    read: Callable[[Path, ReadOptions], SourceScene]
    marker: str
    detect: Callable[[Path], bool] | None = None
    check: bool = True
