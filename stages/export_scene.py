"""Stage ``export_scene``: a fitted (or imported) scene as ``.spz`` (Niantic's compressed splat format) beside its PLY.

    dvc repro export_scene@tiny     # its command, with every input and output path: dvc.yaml or --help

Reads no params.
"""

from __future__ import annotations

import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser
from abcgs.splats.formats.spz import export_spz, sidecar

_S = layout.scene("{key}")
SPEC = StageSpec("export_scene", foreach="data.scenes", deps=(Dep("ply", _S.fit.ply, "the fitted scene (fit)"),), outs=(
    Out(_S.spz, "out", help="the .spz"), Out(sidecar(_S.spz)),
))


def main(args, params) -> None:
    export_spz(args.ply, args.out)


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
