"""Stage ``export``: a fitted or stylized scene as ``.spz`` (Niantic's compressed splat format) beside its PLY.

    python stages/export.py --ply out/tiny_single/stylize/point_cloud.ply --out out/tiny_single/point_cloud.spz

Reads no params (``export_scene`` and ``export`` run this one script).
"""

from __future__ import annotations

import sys
from pathlib import Path

from abcgs.io.spz import export_spz
from abcgs.pipeline import StageSpec, run_stage, stage_parser

SPEC = StageSpec("export")


def main(args, params) -> None:
    export_spz(args.ply, args.out)


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--ply", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True, help="the .spz; its record goes to <out>.json")
    sys.exit(run_stage(SPEC, ap, main))
