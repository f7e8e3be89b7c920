"""Stage ``colormatch``: per matching group, match the colour statistics of the training images and of the
Gaussians' DC colours to the style, then re-fit briefly.

    dvc repro colormatch@tiny_single     # its command, with every input and output path: dvc.yaml or --help

One run per ``colormatches.<name>`` (scene × transfer type × painting(s)): every experiment that names it, e.g.
FAST and NNFM of the same painting, starts from this output, so changing ``stylize.*`` (but the style features'
``layers`` and ``style_height``) or an experiment's ``method`` leaves it cached; changing the scene's fit or
masks re-runs it.
"""

from __future__ import annotations

import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.gaussians.ply import read_ply
from abcgs.masks.outputs import load_scene_masks
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser
from abcgs.runtime import resolve_device, torch_threads
from abcgs.sfm.model import read_scene
from abcgs.stylize.colormatch import color_match_and_refit, write_colormatch
from abcgs.stylize.experiment import check_bindings, load_groups, load_vgg

_S = layout.scene("{item.scene}")
SPEC = StageSpec("colormatch", foreach="colormatches", params=(
    "colormatches.{key}", "data.styles", "data.style_masks", "colormatch", "isolation", "vgg",
    "stylize.layers", "stylize.style_height",  # the style features of the matching groups
    "stylize.color_only",  # the re-fit changes only the colours
    "runtime",
), deps=(
    Dep("colmap", _S.colmap.root, "the scene's COLMAP layout (reconstruct)"),
    Dep("model", _S.fit.ply, "the fitted scene (fit)"),
    Dep("masks", _S.masks.root, "the scene's content labels (masks)"),
    Dep("styles", layout.STYLES, "the paintings and their region maps (styles, style_masks)"),
), outs=(Out(_S.colormatch("{key}").root, "out", help="the colour-matched Gaussians and their record"),))


def main(args, params) -> None:
    spec = params.colormatches[args.colormatch]
    device = resolve_device(params.runtime.device)
    scene, model = read_scene(args.colmap), read_ply(args.model)
    masks = load_scene_masks(args.masks, scene, model.num_gaussians)
    styles = layout.StylesDir(args.styles)
    region_maps = styles.label_maps(params.data.style_masks)
    check_bindings(args.colormatch, spec, masks.gaussian_labels, layout.MasksDir(args.masks).gaussian_labels,
                   region_maps)
    vgg, info = load_vgg(params.vgg, params.stylize.layers, device)
    groups = load_groups(spec, vgg, masks.gaussian_labels, styles.paintings(params.data.styles), region_maps,
                         params.isolation, params.stylize)
    with torch_threads(params.colormatch.threads):
        res = color_match_and_refit(model.to(device), scene, masks.gaussian_labels.to(device), masks.view_labels,
                                    groups, params.colormatch, background=scene.background,
                                    color_only=params.stylize.color_only)
    write_colormatch(args.out, args.colormatch, spec, res, groups, info.model_dump())


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
