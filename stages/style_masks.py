"""Stage ``style_masks``: one painting's region map of ``data.style_masks``, copied under ``out/styles/`` as PNG.

    dvc repro style_masks@tiny_paint     # its command, with every input and output path: dvc.yaml or --help

As the ``styles`` stage does for the painting: the stages that read region maps (colormatch, stylize) read the copy,
so DVC re-runs them when the map's content changes. The map is checked against its painting by the preflight stage.
"""

from __future__ import annotations

import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.io.images import copy_as_png
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser

SPEC = StageSpec("style_masks", foreach="data.style_masks", params=("data.style_masks.{key}",), deps=(
    Dep("labels", "{item}", "the painting's region map (data.style_masks.<key>)"),
), outs=(Out(layout.StylesDir(layout.STYLES).labels("{key}"), "out", help="the region map as PNG"),))


def main(args, params) -> None:
    copy_as_png(args.labels, args.out)


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
