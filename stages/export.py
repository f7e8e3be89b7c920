"""Stage ``export``: a stylized scene as ``.spz`` (Niantic's compressed splat format) beside its PLY, and, for a scene
imported from a trained splat, in that splat's format, frame and layout (docs/SPLATS.md "Giving it back").

    python stages/export.py --ply out/tiny_single/stylize/point_cloud.ply --out out/tiny_single/point_cloud.spz \\
        --source out/tiny/gs/splat_source.json --returned out/tiny_single/returned

Reads no params; ``{item.scene}`` in a path argument is the experiment's scene.
"""

from __future__ import annotations

import sys
from pathlib import Path

from abcgs.io.spz import export_spz
from abcgs.pipeline import StageSpec, run_stage, stage_parser
from abcgs.splats.exporting import give_back

SPEC = StageSpec("export", foreach="experiments")


def main(args, params) -> None:
    export_spz(args.ply, args.out)
    if args.returned is not None:
        give_back(args.ply, args.source, args.returned)


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--ply", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True, help="the .spz; its record goes to <out>.json")
    ap.add_argument("--source", type=Path, help="the scene's splat_source.json (fit stage)")
    ap.add_argument("--returned", type=Path, help="folder for the scene in its source's format, and returned.json")
    sys.exit(run_stage(SPEC, ap, main))
