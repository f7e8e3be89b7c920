"""Stage ``masks``: content label maps (given or automatic) lifted onto the fitted Gaussians (Eq. 2), the views
without a mask re-cut from them (cross-view refinement), re-rendered as view-consistent masks for every view.

    dvc repro masks@tiny     # its command, with every input and output path: dvc.yaml or --help
"""

from __future__ import annotations

import sys

from abcgs import layout
from abcgs.io.ply import read_ply
from abcgs.masks.content import make_content_masks
from abcgs.masks.outputs import write_content_masks
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser
from abcgs.runtime import resolve_device
from abcgs.sfm.model import read_colmap_scene

_S = layout.scene("{key}")
SPEC = StageSpec("masks", foreach="data.scenes", params=("masks", "data.scenes.{key}", "runtime"), deps=(
    Dep("colmap", _S.colmap.root, "the scene's COLMAP layout with its label maps, if any (reconstruct)"),
    Dep("model", _S.fit.ply, "the fitted scene (fit)"),
), outs=(Out(_S.masks.root, "out", help="labels per Gaussian and per view, overlay, record"),))


def main(args, params) -> None:
    colmap = layout.ColmapDir(args.colmap)
    scene = read_colmap_scene(colmap.sparse, colmap.images)
    model = read_ply(args.model, device=resolve_device(params.runtime.device))
    result = make_content_masks(model, scene.cameras, colmap.masks, params.scene_section(args.scene, "masks"),
                                scene.image_paths)
    write_content_masks(args.out, result, scene.cameras, scene.image_paths)


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
