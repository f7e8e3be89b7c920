"""Stage ``export_scene``: a fitted (or imported) scene as ``.spz`` (Niantic's compressed splat format) beside its PLY.

    python stages/export_scene.py --ply out/tiny/gs/point_cloud.ply --out out/tiny/point_cloud.spz

Reads no params.
"""

from __future__ import annotations

import sys
from pathlib import Path

from abcgs.io.spz import export_spz
from abcgs.pipeline import StageSpec, run_stage, stage_parser

SPEC = StageSpec("export_scene", foreach="data.scenes")


def main(args, params) -> None:
    export_spz(args.ply, args.out)


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--ply", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True, help="the .spz; its record goes to <out>.json")
    sys.exit(run_stage(SPEC, ap, main))
