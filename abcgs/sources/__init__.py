"""Where a scene comes from: one reader per dataset format, behind one contract (:mod:`abcgs.sources.base`).

- :mod:`~abcgs.sources.registry`: the readers by format: the ``READER`` of every module of
  :mod:`abcgs.sources.formats` (``photos``: structure from motion, ``colmap``, ``nerfstudio``, ``blender``,
  ``llff``, ``splat``: a bare splat) and of the plugin folders in ``ABCGS_READERS``; each declares its name, its
  detection and priority, its options model in ``params.yaml`` and its reading. Adding a format is adding a module.
- :mod:`~abcgs.sources.detect`: :func:`detect_format` asks the readers, in priority order, which takes the folder.
- :mod:`~abcgs.sources.read`: :func:`~abcgs.sources.read.load` (or :func:`~abcgs.sources.read.read_source` for a
  known format) runs the format's reader and checks the cameras it read (:mod:`~abcgs.sources.validate`).
- :mod:`~abcgs.sources.params`: ``data.scenes`` of ``params.yaml``, whose ``source:`` is a tagged union of the
  registered readers' options.
- The reading code of the built-in formats, one module each: :mod:`~abcgs.sources.photos`,
  :mod:`~abcgs.sources.colmap`, :mod:`~abcgs.sources.nerfstudio`, :mod:`~abcgs.sources.blender`,
  :mod:`~abcgs.sources.llff`, :mod:`~abcgs.sources.bare_splat`; :mod:`~abcgs.sources.transforms_json`: the
  ``transforms.json`` conventions nerfstudio and Blender share; :mod:`~abcgs.sources.lens`: image sizes and lenses.
- :mod:`~abcgs.sources.model`: what the ``reconstruct`` stage writes for a scene with cameras (the undistorted COLMAP
  layout every later stage reads, with points triangulated from the given poses where the dataset has none).

This package's ``__init__`` imports only the light modules (the contract, the registry and detection; the format
modules load their reading code when a scene is read): :mod:`abcgs.preflight`, which every stage imports, detects
formats, and must not load the readers' dependencies. It loads OpenCV first because three readers import pycolmap
(the import-order hazard in :mod:`abcgs.sfm`).
"""

import cv2  # noqa: F401  (must be loaded before pycolmap, see abcgs/sfm/__init__.py)

from abcgs.sources.detect import detect_format
from abcgs.sources.registry import formats, reader_of

__all__ = ["detect_format", "formats", "reader_of"]
