"""Stage ``fit``: baseline 3DGS (Kerbl et al. 2023) from a COLMAP reconstruction.

    python stages/fit.py --scene tiny --colmap out/tiny/colmap --out out/tiny/gs --headline out/tiny/fit_metrics.json

Writes ``point_cloud.ply``, ``metrics.json`` (the full record: per-view scores, evaluation history),
``history.csv`` and ``heldout_grid.png`` into ``--out``, and the scene's headline numbers (the DVC metric) to
``--headline``. Options: the ``fit`` section with ``data.scenes.<scene>.fit`` merged in.
"""

from __future__ import annotations

import sys
from pathlib import Path

from abcgs.fit.trainer import fit_and_save
from abcgs.io.metrics import fit_headline, write_headline
from abcgs.pipeline import StageSpec, run_stage, stage_parser
from abcgs.runtime import resolve_device
from abcgs.sfm.model import read_colmap_scene

SPEC = StageSpec("fit", foreach="data.scenes", params=("fit", "data.scenes.{key}", "runtime"))


def main(args, params) -> None:
    scene = read_colmap_scene(args.colmap / "sparse", args.colmap / "images")
    result = fit_and_save(scene, params.scene_section(args.scene, "fit"), args.out,
                          device=resolve_device(params.runtime.device))
    write_headline(args.headline, fit_headline(result.metrics()))


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--colmap", type=Path, required=True, help="reconstruct stage output (sparse/ + images/)")
    ap.add_argument("--out", type=Path, required=True, help="output folder for point_cloud.ply, metrics, plots")
    ap.add_argument("--headline", type=Path, required=True, help="headline metrics JSON (the DVC metric)")
    sys.exit(run_stage(SPEC, ap, main))
