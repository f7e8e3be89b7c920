"""Reader ``photos``: a folder of photos without cameras; structure from motion finds them
(:func:`abcgs.sfm.colmap.reconstruct`: SIFT, matching, incremental mapping, undistortion).

    <scene>/images/…   the photos (another subfolder: the scene entry's `images:`)
    <scene>/masks/…    optional label PNGs named like the photos
"""

from __future__ import annotations

import os
from pathlib import Path

from abcgs.sfm.colmap import ReconstructionReport, reconstruct
from abcgs.sfm.model import layout_scene, write_scene
from abcgs.sfm.params import ReconstructParams
from abcgs.sources.base import ReadOptions, SceneReader
from abcgs.sources.detect import DEFAULT_IMAGES
from abcgs.types import Background, Scene


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


def _read(folder: Path, options: ReadOptions) -> Scene:
    raise ValueError("a photos scene has no cameras to read: structure from motion finds them (abcgs.sources.photos)")


READER = SceneReader("photos", _read, "images/")
