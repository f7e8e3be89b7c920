"""Stage ``reference``: the original scene's renders and optical flows that every experiment's evaluation
of this scene compares against, computed once per scene.

    python stages/reference.py --scene-name tiny --out out/tiny/reference

Depends on the fitted scene and the ``evaluate`` flow/view settings only (``eval.metrics.reference.FLOW_SETTINGS``),
so new experiments, or changed ``stylize``/``colormatch`` settings, do not re-run it.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abcgs.pipeline import run_stage, stage_parser  # noqa: E402
from abcgs.progress import progress  # noqa: E402
from abcgs.style.experiment import load_scene  # noqa: E402
from eval.metrics.reference import compute_reference, model_digest, save_reference  # noqa: E402


def main(args, params) -> None:
    scene, model = load_scene(args.root, args.scene_name)
    digest = model_digest(args.root / args.scene_name / "gs" / "point_cloud.ply")
    ref = compute_reference(scene.cameras, model, params.evaluate, model_digest=digest,
                            progress=lambda keys: progress(keys, "flows"))
    save_reference(args.out, ref)


if __name__ == "__main__":
    ap = stage_parser(__doc__.strip().splitlines()[0])
    ap.add_argument("--scene-name", required=True)
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--out", type=Path, required=True)
    sys.exit(run_stage("reference", ap, main))
