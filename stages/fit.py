"""Stage ``fit``: baseline 3DGS (Kerbl et al. 2023) from a COLMAP reconstruction.

    python stages/fit.py --colmap out/<scene>/colmap --out out/<scene>/gs --headline out/<scene>/fit_metrics.json

Writes ``point_cloud.ply``, ``metrics.json`` (the full record: per-view scores, evaluation history),
``history.csv`` and ``heldout_grid.png`` into ``--out``, and the scene's headline numbers (the DVC metric) to
``--headline``. Options: the ``fit`` section with ``data.scenes.<--scene-name>.fit`` merged in.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abcgs.fit.trainer import fit_and_save  # noqa: E402
from abcgs.io.metrics import fit_headline, write_headline  # noqa: E402
from abcgs.pipeline import run_stage, stage_parser  # noqa: E402
from abcgs.sfm.colmap import read_colmap_scene  # noqa: E402


def main(args, params) -> None:
    scene = read_colmap_scene(args.colmap / "sparse", args.colmap / "images")
    settings = params.scene_section(args.scene_name, "fit") if args.scene_name else params.fit
    result = fit_and_save(scene, settings, args.out)
    if args.headline:
        write_headline(args.headline, fit_headline(result.metrics()))


if __name__ == "__main__":
    ap = stage_parser(__doc__.strip().splitlines()[0])
    ap.add_argument("--scene-name", default=None, help="key in data.scenes whose fit override applies")
    ap.add_argument("--colmap", type=Path, required=True, help="reconstruct stage output (sparse/ + images/)")
    ap.add_argument("--out", type=Path, required=True, help="output folder for point_cloud.ply, metrics, plots")
    ap.add_argument("--headline", type=Path, default=None, help="headline metrics JSON (the DVC metric)")
    sys.exit(run_stage("fit", ap, main))
