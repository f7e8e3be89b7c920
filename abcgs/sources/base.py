"""What a scene reader is: a format's name, its ``read(folder, options)`` and how a folder of it is recognised.

A reader (one module per format in :mod:`abcgs.sources`) turns a dataset folder into an :class:`abcgs.types.Scene`
(the one scene contract: batched :class:`~abcgs.types.Cameras`, images, optional points and masks):

- its cameras are in the *scene frame* with OpenCV camera axes (x right, y down, z forward), ``viewmats``
  world→camera, intrinsics at the pixel size of the view's image file as it lies on disk (pixel centres at +0.5);
- a view whose lens has distortion carries it as a COLMAP camera model (``Cameras.camera_models`` and
  ``distortion_params``); the ``reconstruct`` stage undistorts it as it undistorts its own SfM model;
- the views are sorted by name (:meth:`abcgs.types.Scene.from_views` sorts them);
- the scene frame is the dataset's own world frame up to the similarity :attr:`abcgs.types.Scene.frame` that the
  reader undoes (nerfstudio's ``applied_transform`` / ``applied_scale``); nothing is re-centred or re-scaled, so that a
  splat trained on the same dataset lines up with the cameras.

This module imports nothing heavier than numpy: :mod:`abcgs.preflight` (which every stage imports) reaches it
through :mod:`abcgs.sources.detect`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_args

from abcgs.types import Scene, SceneFormat

FORMATS: tuple[str, ...] = get_args(SceneFormat)


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
        read: ``(folder, options) → Scene``.
        marker: what a scene of the format is recognised by (for messages: ``sparse/0``, ``transforms.json``).
        detect: whether auto-detection takes a folder for this format, for a reader added at run time; the built-in
            formats are told apart by :func:`abcgs.sources.detect.detect_format`, which reads no reader module.
        check: whether the cameras read are checked (:func:`abcgs.sources.validate.check_cameras`); a bare splat's
            are made around it and not read.
    """

    name: str
    read: Callable[[Path, ReadOptions], Scene]
    marker: str
    detect: Callable[[Path], bool] | None = None
    check: bool = True
