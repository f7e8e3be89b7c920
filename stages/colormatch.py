"""Stage ``colormatch``: per matching group, match the colour statistics of the training images and of the
Gaussians' DC colours to the style, then re-fit briefly.

    python stages/colormatch.py --colormatch tiny_single --out out/tiny/colormatch/tiny_single

One run per ``colormatches.<name>`` (scene × transfer type × painting(s)): every experiment that names it, e.g.
FAST and NNFM of the same painting, starts from this output, so changing ``stylize.*`` (but the style features'
``layers`` and ``style_height``) or an experiment's ``method`` leaves it cached; changing the scene's fit or
masks re-runs it.
"""

from __future__ import annotations

import sys
from pathlib import Path

from abcgs.layout import load_scene
from abcgs.masks.outputs import load_scene_masks
from abcgs.pipeline import StageSpec, run_stage, stage_parser
from abcgs.runtime import resolve_device, torch_threads
from abcgs.stylize.colormatch import color_match_and_refit, write_colormatch
from abcgs.stylize.experiment import check_bindings, load_groups, load_vgg

SPEC = StageSpec("colormatch", foreach="colormatches", params=(
    "colormatches.{key}", "data.styles", "data.style_masks", "colormatch", "isolation", "vgg",
    "stylize.layers", "stylize.style_height",  # the style features of the matching groups
    "runtime",
))


def main(args, params) -> None:
    spec = params.colormatches[args.colormatch]
    device = resolve_device(params.runtime.device)
    scene, model = load_scene(args.root, spec.scene)
    masks = load_scene_masks(args.root / spec.scene / "masks", scene, model.num_gaussians)
    check_bindings(args.colormatch, spec, masks.gaussian_labels, args.root / spec.scene / "masks",
                   params.data.style_masks)
    vgg, info = load_vgg(params.vgg, params.stylize.layers, device)
    groups = load_groups(spec, vgg, masks.gaussian_labels, params.data.styles, params.data.style_masks,
                         params.isolation, params.stylize)
    with torch_threads(params.colormatch.threads):
        res = color_match_and_refit(model.to(device), scene, masks.gaussian_labels.to(device), masks.view_labels,
                                    groups, params.colormatch)
    write_colormatch(args.out, args.colormatch, spec, res, groups, info.model_dump())


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--out", type=Path, required=True)
    sys.exit(run_stage(SPEC, ap, main))
