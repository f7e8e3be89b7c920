"""Stage ``export``: a fitted or stylized scene as ``.spz`` (Niantic's compressed splat format) beside its PLY.

    python stages/export.py --ply out/tiny_single/stylize/point_cloud.ply --out out/tiny_single/point_cloud.spz
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abcgs.io.atomic import write_json  # noqa: E402
from abcgs.io.ply import read_ply  # noqa: E402
from abcgs.io.spz import export_record, write_spz  # noqa: E402
from abcgs.pipeline import run_stage, stage_parser  # noqa: E402


def main(args, params) -> None:
    model = read_ply(args.ply)
    size = write_spz(args.out, model)
    write_json(args.record or args.out.with_suffix(".spz.json"), export_record(model, args.ply, args.out, size))


if __name__ == "__main__":
    ap = stage_parser(__doc__.strip().splitlines()[0])
    ap.add_argument("--ply", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--record", type=Path, help="JSON beside the .spz (default: <out>.json)")
    sys.exit(run_stage("export", ap, main))
