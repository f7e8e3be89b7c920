"""Format ``photos``: a folder of photos without cameras; structure from motion finds them
(:mod:`abcgs.sources.photos`: the ``reconstruct`` stage's COLMAP layout made from them).

    <scene>/images/…   the photos (another subfolder: the scene entry's `images:`)
    <scene>/masks/…    optional label PNGs named like the photos
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from abcgs.sources.base import ImagesSource, SceneReader
from abcgs.sources.detect import DEFAULT_IMAGES, image_files


class PhotosSource(ImagesSource):
    """``source: {format: photos}``: photos without cameras (structure from motion finds them)."""

    format: Literal["photos"] = "photos"


def _detect(folder: Path, images: str | None) -> bool:
    return bool(image_files(folder / (images or DEFAULT_IMAGES)))



READER = SceneReader("photos", "photos:read", "images/", detect=_detect, priority=50, order=10, options=PhotosSource,
                     cameras="sfm", reconstruct="photos:reconstruct_photos")
