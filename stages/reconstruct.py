"""Stage ``reconstruct``: COLMAP structure from motion + undistortion for one scene.

Usage: ``python stages/reconstruct.py --scene data/tiny --out out/tiny/colmap [--params params.yaml]
[--metrics out/tiny/reconstruct.json]``

Reads ``<scene>/images/`` (and undistorts ``<scene>/masks/`` alongside when present); options come
from the ``reconstruct:`` section of ``--params`` (:class:`abcgs.sfm.colmap.ReconstructParams`; the
whole file is validated first). The output folder is written atomically.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make the repository importable without installing it
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abcgs.errors import AbcgsError
from abcgs.io.atomic import write_json
from abcgs.sfm.colmap import ReconstructParams, reconstruct, set_colmap_log_level

log = logging.getLogger("reconstruct")


def load_reconstruct_params(path: Path | None) -> ReconstructParams:
    """The ``reconstruct:`` section of ``path`` after validating the whole file (defaults without a file)."""
    if path is None:
        return ReconstructParams()
    from abcgs.params import load_params  # imports every stage's schema; only needed with --params

    return load_params(path).reconstruct


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, required=True, help="scene folder containing images/ (and optionally masks/)")
    ap.add_argument("--out", type=Path, required=True, help="output folder, e.g. out/<scene>/colmap")
    ap.add_argument("--params", type=Path, default=None, help="params.yaml with a reconstruct: section")
    ap.add_argument("--metrics", type=Path, default=None, help="also write metrics.json's content here (DVC metrics)")
    ap.add_argument("--colmap-log", choices=("info", "warning"), default="warning", help="COLMAP's own log level")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    set_colmap_log_level(args.colmap_log)
    try:
        params = load_reconstruct_params(args.params)
        report = reconstruct(args.scene / "images", args.out, params, masks_dir=args.scene / "masks")
    except AbcgsError as e:
        log.error("%s", e)
        return 1
    if args.metrics is not None:
        write_json(args.metrics, report.metrics())
    log.info(
        "%d/%d registered, %d points, reprojection error %.3f px, %.1f s",
        report.registered, report.total, report.points, report.mean_reprojection_error_px, report.seconds,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
