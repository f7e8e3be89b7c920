"""Stage ``export``: a stylized scene as ``.spz`` (Niantic's compressed splat format) beside its PLY, and, for a scene
imported from a trained splat, in that splat's format, frame and layout (docs/SPLATS.md "Giving it back").

    dvc repro export@tiny_single     # its command, with every input and output path: dvc.yaml or --help

Reads no params; ``{item.scene}`` in a path argument is the experiment's scene.
"""

from __future__ import annotations

import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser
from abcgs.splats.exporting import give_back
from abcgs.splats.formats.spz import export_spz, sidecar

_S, _E = layout.scene("{item.scene}"), layout.experiment("{key}")
SPEC = StageSpec("export", foreach="experiments", deps=(
    Dep("ply", _E.stylize.ply, "the stylized scene (stylize)"),
    Dep("source", _S.fit.splat_source, "where the scene's splat came from (fit)"),
), outs=(
    Out(_E.spz, "out", help="the .spz"), Out(sidecar(_E.spz)),
    Out(_E.returned, "returned", help="the scene in its source's format, and returned.json"),
))


def main(args, params) -> None:
    export_spz(args.ply, args.out)
    give_back(args.ply, args.source, args.returned)


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
