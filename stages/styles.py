"""Stage ``styles``: one painting of ``data.styles``, checked and copied under ``out/styles/`` as PNG.

    dvc repro styles@tiny_paint     # its command, with every input and output path: dvc.yaml or --help

The params hold a painting's path; this stage's dependency on the file itself is what makes DVC re-run the stages that
read paintings (colormatch, stylize, evaluate, report: they read the copies) when the painting is replaced. The copy
holds the decoded pixels as they are (:func:`abcgs.io.images.copy_as_png`), so results do not change.
"""

from __future__ import annotations

import logging
import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.io.images import copy_as_png
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser

SPEC = StageSpec("styles", foreach="data.styles", params=("data.styles.{key}",), deps=(
    Dep("painting", "{item}", "the painting (data.styles.<key>)"),
), outs=(Out(layout.StylesDir(layout.STYLES).painting("{key}"), "out", help="the painting as PNG"),))
log = logging.getLogger("styles")


def main(args, params) -> None:
    w, h = copy_as_png(args.painting, args.out)
    log.info("%s: %d x %d", args.painting, w, h)


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
