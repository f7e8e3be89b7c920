"""Does structure from motion hold on an object-centred capture? Registered views, azimuth round the object, time.

    python -m eval run sfm_orbit --scene ../shared/data/scenes/bonsai --work /tmp/sfm \\
        --reconstruct '{"matcher": "exhaustive"}' --json docs/measurements/bonsai_sfm.json

Runs :func:`abcgs.sources.reconstruct.reconstruct_scene` on the folder as ``photos`` (the reconstruct stage's route) with the given
``reconstruct`` params (JSON, as ``params.yaml`` would set them) into ``--work/colmap`` (replaced) and reads the scene
back. Printed: registered / total views and which did not
register, 3-D points, mean reprojection error, and :func:`abcgs.camera_paths.capture_layout` of the registered
cameras: its kind, the azimuth span the camera centres cover round the point the optical axes meet at (360° minus
the largest gap), the largest gap, the share of cameras that have that point in front, and each view's azimuth. A
capture that goes all the way round should register every view with a span near 360°. ``--json`` appends the record,
with its provenance (:func:`eval.record.provenance`), to a JSON list.
"""

from __future__ import annotations

import logging
import shutil
import time
from pathlib import Path

import numpy as np

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs.camera_paths import _plane_basis, capture_layout
from abcgs.io.atomic import write_json
from abcgs.sfm.colmap import set_colmap_log_level
from abcgs.sfm.model import read_scene
from abcgs.sfm.params import ReconstructParams
from abcgs.sources.params import SceneParams
from abcgs.sources.reconstruct import reconstruct_scene
from eval.record import bench_parser, provenance


def main(argv: list[str] | None = None) -> dict:
    ap = bench_parser(__doc__, json_help="append the record to this JSON list")
    ap.add_argument("--scene", type=Path, required=True, help="folder with images/")
    ap.add_argument("--work", type=Path, required=True, help="the model is written to WORK/colmap (replaced)")
    ap.add_argument("--reconstruct", default="{}", help="reconstruct params as JSON (ReconstructParams)")
    args = ap.parse_args(argv)
    params = ReconstructParams.model_validate_json(args.reconstruct)
    logging.basicConfig(level=logging.WARNING)
    set_colmap_log_level("error")

    out = args.work / "colmap"
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    report = reconstruct_scene(SceneParams.at(args.scene, "photos"), out, params)
    seconds = time.perf_counter() - t0
    cams = read_scene(out).cameras
    lay = capture_layout(cams)
    centers = np.stack([c.center for c in cams])
    dirs = np.stack([c.viewmat[2, :3] for c in cams])
    off = centers - lay.center
    e1, e2 = _plane_basis(lay.down)
    az = np.degrees(np.arctan2(off @ e2, off @ e1))
    order = np.sort(np.mod(az, 360.0))
    gap = float(np.diff(np.concatenate([order, order[:1] + 360.0])).max())
    record = {
        "scene": str(args.scene), "reconstruct": params.model_dump(), "registered": report.registered,
        "total": report.total, "unregistered": report.unregistered, "points": report.points,
        "mean_reprojection_error_px": report.mean_reprojection_error_px, "layout": lay.kind,
        "azimuth_span_deg": lay.span_deg, "largest_azimuth_gap_deg": gap,
        "look_at_in_front": float(np.mean((-(off) * dirs).sum(1) > 0)),
        "azimuth_deg": {Path(c.name).stem: round(float(a), 1) for c, a in zip(cams, az)},
        "seconds": round(seconds, 1),
    }
    print(f"{args.scene.name}: {report.registered}/{report.total} views registered"
          + (f" (not: {', '.join(report.unregistered)})" if report.unregistered else "")
          + f", {report.points} points, reprojection {report.mean_reprojection_error_px:.2f} px; layout {lay.kind}, "
          f"azimuth span {lay.span_deg:.0f}° (largest gap {gap:.0f}°), look-at point in front of "
          f"{record['look_at_in_front']:.0%} of the cameras; {seconds:.0f} s")
    if args.json:
        import json

        runs = json.loads(args.json.read_text()) if args.json.is_file() else []
        write_json(args.json, [*runs, {**record, "provenance": provenance(argv)}])
    return record


if __name__ == "__main__":
    main()
