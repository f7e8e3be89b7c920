"""Stage ``colormatch``: per matching group, match the colour statistics of the training images and of the
Gaussians' DC colours to the style, then re-fit briefly.

    python stages/colormatch.py --colormatch tiny_single --out out/tiny/colormatch/tiny_single

One run per ``colormatches.<name>`` (scene × transfer type × painting(s)): every experiment that names it, e.g.
FAST and NNFM of the same painting, starts from this output, so changing ``stylize.*`` or an experiment's
``method`` leaves it cached; changing the scene's fit or masks re-runs it.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abcgs.fit.trainer import torch_threads  # noqa: E402
from abcgs.io.atomic import atomic_path, write_json  # noqa: E402
from abcgs.io.images import save_image  # noqa: E402
from abcgs.io.ply import write_ply  # noqa: E402
from abcgs.pipeline import run_stage, stage_parser  # noqa: E402
from abcgs.style.colormatch import color_match_and_refit  # noqa: E402
from abcgs.style.experiment import colormatch_spec, load_groups, load_scene, load_scene_masks, load_vgg  # noqa: E402
from abcgs.viz import image_grid  # noqa: E402


def main(args, params) -> None:
    spec = colormatch_spec(params, args.colormatch)
    scene, model = load_scene(args.root, spec.scene)
    masks = load_scene_masks(args.root / spec.scene / "masks", scene, model.num_gaussians)
    vgg, info = load_vgg(params)
    groups = load_groups(params, spec, vgg, masks.gaussian_labels)
    with torch_threads(params.colormatch.threads):
        res = color_match_and_refit(model, scene, masks.gaussian_labels, masks.view_labels, groups, params.colormatch)
    with atomic_path(args.out, is_dir=True) as tmp:
        write_ply(tmp / "point_cloud.ply", res.model)
        write_json(tmp / "colormatch.json", {
            "colormatch": args.colormatch, **spec.model_dump(mode="json"), "groups": [g.style_name for g in groups],
            "transforms": {str(k): {"A": A.tolist(), "b": b.tolist()} for k, (A, b) in res.transforms.items()},
            "refit_steps": len(res.history), "refit_final_loss": res.history[-1]["loss"] if res.history else None,
            "vgg_weights": info.model_dump(),
        })
        save_image(tmp / "recolored.png", image_grid([[img.numpy() for img in res.images[:4]]]))


if __name__ == "__main__":
    ap = stage_parser(__doc__.strip().splitlines()[0])
    ap.add_argument("--colormatch", required=True, help="a key of params.yaml colormatches")
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--out", type=Path, required=True)
    sys.exit(run_stage("colormatch", ap, main))
