"""Format ``photos``: a folder of photos without cameras; structure from motion finds them
(:func:`abcgs.sfm.colmap.reconstruct`: SIFT, matching, incremental mapping, undistortion).

    <scene>/images/…   the photos (another subfolder: the scene entry's `images:`)
    <scene>/masks/…    optional label PNGs named like the photos
"""

from __future__ import annotations

import os
from pathlib import Path

from abcgs.sfm.colmap import ReconstructionReport, reconstruct
from abcgs.sfm.model import layout_scene, read_scene, write_scene
from abcgs.sfm.params import ReconstructParams
from abcgs.sources.base import ReadOptions
from abcgs.sources.detect import DEFAULT_IMAGES
from abcgs.types import Background, SourceScene


def reconstruct_photos(folder: str | os.PathLike, out_dir: str | os.PathLike, params: ReconstructParams,
                       images: str | None = None, *, background: Background | None = None,
                       splat: Path | None = None) -> ReconstructionReport:
    """Structure from motion on ``folder/images`` (and its ``masks/``) into ``out_dir`` (the ``reconstruct``
    stage's layout), and the scene written there (:func:`abcgs.sfm.model.write_scene`: the model kept as structure
    from motion wrote it) with its ``background`` (photos have no alpha: an object's own fit says where it is) and
    the ``splat`` it names."""
    folder = Path(folder)
    report = reconstruct(folder / (images or DEFAULT_IMAGES), out_dir, params, masks_dir=folder / "masks")
    write_scene(layout_scene(out_dir, format="photos", background=background, splat=splat), out_dir)
    return report


def read(folder: Path, options: ReadOptions) -> SourceScene:
    """The ``photos`` format's reading (:mod:`abcgs.sources.formats.photos`): structure from motion with the default
    :class:`~abcgs.sfm.params.ReconstructParams` into ``options.work``, and the scene written there read back
    (:func:`abcgs.sfm.model.read_scene`, as a :class:`~abcgs.types.SourceScene`); ``options.background``: an object
    on that colour."""
    if options.work is None:
        raise ValueError("a photos scene's cameras are found by structure from motion into `work`; give a folder")
    background = Background(options.background, object=True) if options.background is not None else Background()
    reconstruct_photos(folder, options.work, ReconstructParams(), options.images, background=background)
    return read_scene(options.work).as_source()
