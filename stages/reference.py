"""Stage ``reference``: the original scene's renders, the consistency pairs, the optical flows between them, each
pair's occlusion/in-frame mask and the unstylized scene's warp error over those pairs (the floor), which every
experiment's evaluation of this scene reads instead of recomputing them, computed once per scene.

    dvc repro reference@tiny     # its command, with every input and output path: dvc.yaml or --help

Tracks only the ``evaluate`` keys of :data:`abcgs.evaluation.reference.FLOW_SETTINGS` (views, pairs and flows), so
new experiments, or changed metric, ``stylize`` or ``colormatch`` settings, do not re-run it.
"""

from __future__ import annotations

import logging
import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.evaluation.reference import FLOW_SETTINGS, compute_reference, model_digest, save_reference
from abcgs.gaussians.ply import read_ply
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser
from abcgs.progress import progress
from abcgs.runtime import resolve_device
from abcgs.sfm.model import read_scene

log = logging.getLogger("reference")
_S = layout.scene("{key}")
SPEC = StageSpec("reference", foreach="data.scenes", params=(*(f"evaluate.{k}" for k in FLOW_SETTINGS), "runtime"), deps=(
    Dep("colmap", _S.colmap.root, "the scene's COLMAP layout (reconstruct)"),
    Dep("model", _S.fit.ply, "the fitted scene (fit)"),
), outs=(Out(_S.reference, "out", help="renders, pairs, flows, pair masks and the scene's own warp error"),))


def main(args, params) -> None:
    scene, model = read_scene(args.colmap), read_ply(args.model)
    digest = model_digest(args.model)
    ref = compute_reference(scene.cameras, model.to(resolve_device(params.runtime.device)), params.evaluate, model_digest=digest,
                            progress=lambda keys: progress(keys, "flows"), background=scene.background)
    save_reference(args.out, ref)
    log.info("%d views, %d flows, %d pair masks; %s", len(ref.view_names), len(ref.flows), len(ref.masks),
             ", ".join(f"{k} {v:.1f} s" for k, v in ref.timings_s.items()))


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
