"""abcgs — ABC-GS (alignment-based controllable style transfer for 3D Gaussian Splatting).

The library is organised one module per concept:

- :mod:`abcgs.types`    — the modes (``Literal``) and interfaces (``Protocol``) shared across packages.
- :mod:`abcgs.params`   — the ``params.yaml`` schema (pydantic) and its loader.
- :mod:`abcgs.dotted`   — dotted params keys (``stylize.fast.k``) and DVC's ``${...}`` interpolation.
- :mod:`abcgs.io`       — atomic writes, image loading, INRIA-layout PLY.
- :mod:`abcgs.cameras`  — pinhole cameras and COLMAP-model reading.
- :mod:`abcgs.render`   — the differentiable Gaussian rasterizer (reference, fast CPU, gsplat backends).
- :mod:`abcgs.sfm`      — structure from motion through pycolmap.
- :mod:`abcgs.scene`    — the embedded synthetic default scene.
- :mod:`abcgs.fit`      — baseline 3DGS fitting (views, losses, densification strategies, training loop, evaluation).
- :mod:`abcgs.style`    — ABC-GS: VGG features, FAST loss, colour match, style isolation, mask lifting.

A module imports only from its own floor or lower ones: foundations (errors, types, io, cameras), rendering,
scenes and features, losses, methods (fit, masks, stylize, evaluation), presentation (view, report),
orchestration (params, pipeline, preflight, cluster); ``tests/test_layers.py`` checks it.
"""

import os
import sys

# The CPU path alternates torch's OpenMP regions (VGG, Adam, small tensor ops) with the extension's own
# kernel threads (abcgs.render.cpu: rasterizer, SSIM, neighbour search). Under GNU OpenMP's default wait
# policy torch's idle workers spin after each region and take cores from those kernel threads; passive
# waiting makes the fit and the stylization faster with identical results (docs/SCALING.md "One machine: the
# queue", "Threads and `-j`", has the measurement). libgomp reads the variable when it loads, i.e. at torch's first
# import, so this only acts when abcgs is imported first; a value set by the user always wins.
if "torch" not in sys.modules:
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# Import OpenCV before pycolmap can be imported anywhere: pycolmap's bundled zlib otherwise captures
# libz's internal calls and the next cv2.imencode of a PNG aborts with "double free or corruption".
import cv2  # noqa: F401,E402

__version__ = "0.1.0"
