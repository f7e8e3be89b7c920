"""Where a scene comes from: one reader per dataset format, behind one contract (:mod:`abcgs.sources.base`).

- :mod:`~abcgs.sources.detect`: :func:`detect_format` picks the format from the folder's files.
- :mod:`~abcgs.sources.read`: :func:`~abcgs.sources.read.load` (or :func:`~abcgs.sources.read.read_source` for a
  known format) runs the format's reader, found by name, and checks its cameras (:mod:`~abcgs.sources.validate`).
- Readers, one module per format, each with its ``READER`` (:class:`~abcgs.sources.base.SceneReader`: one
  signature, ``read(folder, options)``): :mod:`~abcgs.sources.photos` (structure from motion),
  :mod:`~abcgs.sources.colmap`, :mod:`~abcgs.sources.nerfstudio`, :mod:`~abcgs.sources.blender`,
  :mod:`~abcgs.sources.llff`, :mod:`~abcgs.sources.splat`; :mod:`~abcgs.sources.transforms_json`: the
  ``transforms.json`` conventions nerfstudio and Blender share.
- :mod:`~abcgs.sources.model`: what the ``reconstruct`` stage writes for a scene with cameras (the undistorted COLMAP
  layout every later stage reads, with points triangulated from the given poses where the dataset has none).

This package's ``__init__`` imports only the light modules (the contract and detection): :mod:`abcgs.preflight`,
which every stage imports, detects formats, and must not depend on the readers. It loads OpenCV first because
three readers import pycolmap (the import-order hazard in :mod:`abcgs.sfm`).
"""

import cv2  # noqa: F401  (must be loaded before pycolmap, see abcgs/sfm/__init__.py)

from abcgs.sources.base import FORMATS
from abcgs.sources.detect import detect_format

__all__ = ["FORMATS", "detect_format"]
