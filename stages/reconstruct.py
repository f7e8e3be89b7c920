"""Stage ``reconstruct``: COLMAP through pycolmap — SIFT, matching, incremental mapping, undistortion to PINHOLE.

    python stages/reconstruct.py --scene data/tiny --out out/tiny/colmap --metrics out/tiny/reconstruct.json

Writes the undistorted model (``sparse/``), images (``images/``) and, when the scene has ``masks/``, the
undistorted label maps (``masks/``); registered/total images, points and reprojection error go to
``--metrics``. Options: the ``reconstruct`` section of params.yaml (:class:`abcgs.sfm.colmap.ReconstructParams`)
with ``data.scenes.<--scene-name>.reconstruct`` merged in.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abcgs.io.atomic import write_json  # noqa: E402
from abcgs.pipeline import run_stage, stage_parser  # noqa: E402
from abcgs.sfm.colmap import reconstruct, set_colmap_log_level  # noqa: E402

log = logging.getLogger("reconstruct")


def main(args, params) -> None:
    set_colmap_log_level(args.colmap_log)
    settings = params.scene_section(args.scene_name, "reconstruct") if args.scene_name else params.reconstruct
    report = reconstruct(args.scene / "images", args.out, settings, masks_dir=args.scene / "masks")
    write_json(args.metrics, report.metrics())
    log.info(
        "%d/%d registered, %d points, reprojection error %.3f px, %.1f s",
        report.registered, report.total, report.points, report.mean_reprojection_error_px, report.seconds,
    )


if __name__ == "__main__":
    ap = stage_parser(__doc__.strip().splitlines()[0])
    ap.add_argument("--scene", type=Path, required=True, help="scene folder containing images/ (and optionally masks/)")
    ap.add_argument("--scene-name", default=None, help="key in data.scenes whose reconstruct override applies")
    ap.add_argument("--out", type=Path, required=True, help="output folder, e.g. out/<scene>/colmap")
    ap.add_argument("--metrics", type=Path, required=True, help="metrics JSON (a DVC metric)")
    ap.add_argument("--colmap-log", choices=("info", "warning"), default="warning", help="COLMAP's own log level")
    sys.exit(run_stage("reconstruct", ap, main))
