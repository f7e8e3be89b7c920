"""``python -m eval.bench.strokes --scene bonsai``: kept as a name for the bonsai case (the same code)."""

from __future__ import annotations

import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
from eval.bench.strokes import main

if __name__ == "__main__":
    main(["--scene", "bonsai", *sys.argv[1:]])
