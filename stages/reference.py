"""Stage ``reference``: the original scene's renders, the consistency pairs, the optical flows between them and the
unstylized scene's warp error over those pairs (the floor), which every experiment's evaluation of this scene
compares against, computed once per scene.

    python stages/reference.py --scene tiny --out out/tiny/reference

Tracks only the ``evaluate`` keys of :data:`abcgs.evaluation.reference.FLOW_SETTINGS` (views, pairs and flows), so
new experiments, or changed metric, ``stylize`` or ``colormatch`` settings, do not re-run it.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

from abcgs.evaluation.reference import FLOW_SETTINGS, compute_reference, model_digest, save_reference
from abcgs.layout import load_scene
from abcgs.pipeline import StageSpec, run_stage, stage_parser
from abcgs.progress import progress
from abcgs.runtime import resolve_device

log = logging.getLogger("reference")
SPEC = StageSpec("reference", foreach="data.scenes", params=(*(f"evaluate.{k}" for k in FLOW_SETTINGS), "runtime"))


def main(args, params) -> None:
    scene, model = load_scene(args.root, args.scene)
    digest = model_digest(args.root / args.scene / "gs" / "point_cloud.ply")
    ref = compute_reference(scene.cameras, model.to(resolve_device(params.runtime.device)), params.evaluate, model_digest=digest,
                            progress=lambda keys: progress(keys, "flows"))
    save_reference(args.out, ref)
    log.info("%d views, %d flows; %s", len(ref.view_names), len(ref.flows),
             ", ".join(f"{k} {v:.1f} s" for k, v in ref.timings_s.items()))


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--out", type=Path, required=True)
    sys.exit(run_stage(SPEC, ap, main))
