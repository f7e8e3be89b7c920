"""Reading a scene of any format: :func:`resolve_format` (the params' ``format`` or detection) and
:func:`read_source` (the format's reader, then :func:`abcgs.sources.validate.check_cameras`).

Kept apart from :mod:`abcgs.sources.detect` so that :mod:`abcgs.preflight`, which every stage imports, does not
depend on the readers (a change to one reader re-runs only the stages that read scenes).
"""

from __future__ import annotations

import os
from pathlib import Path

from abcgs.errors import InputError
from abcgs.sources.base import FORMATS, SourceScene
from abcgs.sources.detect import detect_format
from abcgs.types import SceneFormat

MARKER = {"colmap": "sparse/0", "nerfstudio": "transforms.json", "blender": "transforms_train.json",
          "llff": "poses_bounds.npy", "photos": "images/", "splat": "the splat file"}
"""What each format's scene is recognised by (for messages)."""


def resolve_format(folder: str | os.PathLike, fmt: str = "auto", images: str | None = None) -> SceneFormat:
    """``fmt`` when the params name one, else what :func:`abcgs.sources.detect.detect_format` finds."""
    if fmt == "auto":
        return detect_format(folder, images)
    if fmt not in FORMATS:
        raise InputError(f"format {fmt!r} is not one of auto, {', '.join(FORMATS)}")
    return fmt  # type: ignore[return-value]


def read_source(folder: str | os.PathLike, fmt: SceneFormat, *, images: str | None = None,
                background: tuple[float, float, float] | None = None, views=None,
                work: str | os.PathLike | None = None, drop_invalid: bool = False) -> SourceScene:
    """The scene at ``folder`` read as ``fmt`` (not ``photos``: those get their cameras from structure from motion,
    :mod:`abcgs.sources.photos`). ``images``: the image subfolder (``colmap``, ``llff``, ``nerfstudio``; default
    ``images``); ``background``: RGB in ``[0, 1]`` behind RGBA images (``blender``) and a bare splat's renders; ``views``
    (a :class:`~abcgs.splats.params.SplatViewsParams`), ``work`` (a folder for its renders) and ``drop_invalid`` (drop
    its non-finite Gaussians) for a bare splat."""
    from abcgs.sources.validate import check_cameras

    folder = Path(folder)
    if fmt == "colmap":
        from abcgs.sources.colmap import read_colmap_source

        scene = read_colmap_source(folder, images)
    elif fmt == "nerfstudio":
        from abcgs.sources.nerfstudio import read_nerfstudio_source

        scene = read_nerfstudio_source(folder, images)
    elif fmt == "blender":
        from abcgs.sources.blender import read_blender_source

        scene = read_blender_source(folder, background)
    elif fmt == "llff":
        from abcgs.sources.llff import read_llff_source

        scene = read_llff_source(folder, images)
    elif fmt == "splat":
        try:
            from abcgs.sources.splat import read_splat_source
        except ImportError:
            raise InputError("bare splat scenes are not available in this build") from None
        from abcgs.sources.detect import splat_file

        if work is None:
            raise ValueError("a bare splat's views are rendered into `work`; give a folder")
        return read_splat_source(splat_file(folder), Path(work), views, background=background, drop_invalid=drop_invalid)
    elif fmt == "photos":
        raise ValueError("a photos scene has no cameras to read: structure from motion finds them (abcgs.sources.photos)")
    else:
        raise InputError(f"format {fmt!r} is not one of {', '.join(FORMATS)}")
    check_cameras(scene, f"{folder} ({MARKER[fmt]})")
    return scene
