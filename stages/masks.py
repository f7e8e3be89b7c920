"""Stage ``masks``: content label maps (given or automatic) and their strokes lifted onto the fitted Gaussians (Eq. 2),
the Gaussians no painted view decides labelled in 3-D as the masks page does (``masks.field``; or, with
``masks.refine.enabled``, every other view re-cut and lifted), rendered as view-consistent masks for every view.

    dvc repro masks@tiny     # its command, with every input and output path: dvc.yaml or --help

The given label maps are the ones the scene record names (:attr:`abcgs.types.CalibratedScene.label_paths`, each with
its strokes in ``strokes/`` beside it), as the ``reconstruct`` stage wrote them.

Where no colour match of the scene reads content labels (all are single-image transfer: ``--label-use``, written
by the preflight stage), nothing is lifted or re-cut: every label is 0 (:func:`abcgs.masks.outputs.write_unread_masks`).
"""

from __future__ import annotations

import json
import logging
import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.gaussians.ply import read_ply
from abcgs.masks.content import make_content_masks
from abcgs.masks.outputs import write_content_masks, write_unread_masks
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser
from abcgs.runtime import resolve_device
from abcgs.sfm.model import read_scene

_S = layout.scene("{key}")
SPEC = StageSpec("masks", foreach="data.scenes", params=("masks", "data.scenes.{key}", "runtime"), deps=(
    Dep("colmap", _S.colmap.root, "the scene's COLMAP layout with its label maps, if any (reconstruct)"),
    Dep("model", _S.fit.ply, "the fitted scene (fit)"),
    Dep("label-use", layout.label_use("{key}"), "whether a colour match reads the scene's content labels (preflight)"),
), outs=(Out(_S.masks.root, "out", help="labels per Gaussian and per view, overlay, record"),))


log = logging.getLogger("masks")


def main(args, params) -> None:
    colmap = layout.ColmapDir(args.colmap)
    scene = read_scene(colmap.root)
    if not json.loads(args.label_use.read_text())["content_labels_read"]:
        model = read_ply(args.model)
        log.info("no colour match of %s reads content labels (all are single-image): labels left at 0, nothing "
                 "lifted or re-cut", args.scene)
        write_unread_masks(args.out, model.num_gaussians, scene.cameras)
        return
    model = read_ply(args.model, device=resolve_device(params.runtime.device))
    result = make_content_masks(model, scene.cameras, scene.label_paths, params.scene_section(args.scene, "masks"),
                                scene.image_paths)
    write_content_masks(args.out, result, scene.cameras, scene.image_paths)


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
