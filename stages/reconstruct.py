"""Stage ``reconstruct``: COLMAP through pycolmap — SIFT, matching, incremental mapping, undistortion to PINHOLE.

    python stages/reconstruct.py --scene tiny --out out/tiny/colmap --metrics out/tiny/reconstruct.json

Reads the scene folder ``data.scenes.<scene>.path`` (``images/``, optional ``masks/``). Writes the undistorted
model (``sparse/``), images (``images/``) and, when the scene has ``masks/``, the undistorted label maps
(``masks/``); registered/total images, points and reprojection error go to ``--metrics``. Options: the
``reconstruct`` section (:class:`abcgs.sfm.colmap.ReconstructParams`) with the scene's override merged in.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

from abcgs.io.atomic import write_json
from abcgs.pipeline import StageSpec, run_stage, stage_parser
from abcgs.sfm.colmap import reconstruct, set_colmap_log_level

SPEC = StageSpec("reconstruct", foreach="data.scenes", params=("reconstruct", "data.scenes.{key}"))
log = logging.getLogger("reconstruct")


def main(args, params) -> None:
    set_colmap_log_level(args.colmap_log)
    folder = Path(params.scene_path(args.scene))
    report = reconstruct(folder / "images", args.out, params.scene_section(args.scene, "reconstruct"),
                         masks_dir=folder / "masks")
    write_json(args.metrics, report.metrics())
    log.info(
        "%d/%d registered, %d points, reprojection error %.3f px, %.1f s",
        report.registered, report.total, report.points, report.mean_reprojection_error_px, report.seconds,
    )


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="output folder, e.g. out/<scene>/colmap")
    ap.add_argument("--metrics", type=Path, required=True, help="registration record JSON")
    ap.add_argument("--colmap-log", choices=("info", "warning"), default="warning", help="COLMAP's own log level")
    sys.exit(run_stage(SPEC, ap, main))
