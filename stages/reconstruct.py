"""Stage ``reconstruct``: the scene's calibrated views as an undistorted COLMAP model, from its photos or its dataset.

    dvc repro reconstruct@tiny     # its command, with every input and output path: dvc.yaml or --help

Reads the scene folder ``data.scenes.<scene>.path`` in its format (``format:``, default detected:
:mod:`abcgs.sources`), by the format's reader (:mod:`abcgs.sources.registry`). A reader whose cameras are found, not
read (``photos``: ``images/``, optional ``masks/``) makes the layout itself: COLMAP via pycolmap, SIFT, matching,
incremental mapping, undistortion to PINHOLE (:mod:`abcgs.sfm.colmap`; options: the ``reconstruct`` section with the
scene's override merged in). A dataset with cameras (COLMAP model, ``transforms.json``, NeRF-synthetic,
``poses_bounds.npy``) keeps its cameras and frame: undistorted, scaled to its images, with its points or points
triangulated from its poses (:mod:`abcgs.sources.model`). Either way the output is the undistorted model
(``sparse/``), images (``images/``), label maps (``masks/``, when there are any) and ``scene.json``: the format,
frame and background resolved here and the splat the scene names, which every later stage reads back with the rest
(:func:`abcgs.sfm.model.read_scene`); the record goes to ``--metrics``.
"""

from __future__ import annotations

import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.io.atomic import write_json
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser
from abcgs.sfm.colmap import set_colmap_log_level
from abcgs.sources.reconstruct import reconstruct_scene

_S = layout.scene("{key}")
SPEC = StageSpec("reconstruct", foreach="data.scenes", params=("reconstruct", "data.scenes.{key}"), deps=(
    Dep("source", "{item.path}", "the scene's folder: photos or a dataset with its cameras"),
), outs=(
    Out(_S.colmap.root, "out", help="the undistorted COLMAP layout"),
    Out(_S.reconstruct_record, "metrics", help="the reconstruction record (JSON)"),
))


def main(args, params) -> None:
    set_colmap_log_level(args.colmap_log)
    report = reconstruct_scene(params.data.scenes[args.scene], args.out, params.scene_section(args.scene, "reconstruct"),
                               folder=args.source)
    write_json(args.metrics, report.metrics())


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--colmap-log", choices=("info", "warning"), default="warning", help="COLMAP's own log level")
    sys.exit(run_stage(SPEC, ap, main))
