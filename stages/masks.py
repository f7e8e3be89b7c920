"""Stage ``masks``: content label maps (given or automatic) lifted onto the fitted Gaussians (Eq. 2), the views
without a mask re-cut from them (cross-view refinement), re-rendered as view-consistent masks for every view.

    python stages/masks.py --scene tiny --out out/tiny/masks
"""

from __future__ import annotations

import sys
from pathlib import Path

from abcgs.layout import load_scene
from abcgs.masks.content import make_content_masks
from abcgs.masks.outputs import write_content_masks
from abcgs.pipeline import StageSpec, run_stage, stage_parser
from abcgs.runtime import resolve_device

SPEC = StageSpec("masks", foreach="data.scenes", params=("masks", "data.scenes.{key}", "runtime"))


def main(args, params) -> None:
    scene, model = load_scene(args.root, args.scene)
    model = model.to(resolve_device(params.runtime.device))
    masks_dir = args.root / args.scene / "colmap" / "masks"
    result = make_content_masks(model, scene.cameras, masks_dir, params.scene_section(args.scene, "masks"),
                                scene.image_paths)
    write_content_masks(args.out, result, scene.cameras, scene.image_paths)


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--out", type=Path, required=True)
    sys.exit(run_stage(SPEC, ap, main))
