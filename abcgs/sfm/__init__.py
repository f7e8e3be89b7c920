"""Structure from motion through pycolmap (:mod:`abcgs.sfm.colmap`) and the scene on disk that the ``reconstruct``
stage writes and every later stage reads (:mod:`abcgs.sfm.model`: :func:`~abcgs.sfm.model.write_scene`,
:func:`~abcgs.sfm.model.read_scene`).

Import-order hazard: pycolmap 4.x's ``_core`` module carries its own (exported) zlib. If ``pycolmap``
is imported before ``cv2``, the system ``libz`` that both load binds its internal calls to
pycolmap's copy, and the next ``cv2.imencode('.png', ...)`` aborts with "double free or corruption".
Importing ``cv2`` first (as done here and in :mod:`abcgs.sfm.colmap`) avoids it; never import
``pycolmap`` at the top of a module before ``cv2`` (:func:`abcgs.runtime.setup` loads it first).
"""

import cv2  # noqa: F401  (must be loaded before pycolmap, see above)
