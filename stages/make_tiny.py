"""Stage ``make_tiny``: generate the embedded default scene (views, label maps, cameras, paintings).

    dvc repro make_tiny     # its command, with every input and output path: dvc.yaml or --help

Deterministic for a seed; options: the ``tiny`` section of params.yaml
(:class:`abcgs.scene.synthetic.TinySceneParams`).
"""

from __future__ import annotations

import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs.pipeline import Out, StageSpec, run_stage, stage_parser
from abcgs.scene.synthetic import make_tiny_scene

SPEC = StageSpec("make_tiny", params=("tiny",), outs=(Out("data/tiny", "out", help="the scene folder"),))


def main(args, params) -> None:
    make_tiny_scene(args.out, params.tiny)


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
