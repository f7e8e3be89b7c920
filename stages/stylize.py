"""Stage ``stylize``: optimise the colour-matched Gaussians with FAST (or a baseline) + content, TV, depth,
scale and opacity terms; write the stylized PLY, renders, a grid, a turntable video (the camera path of
``viewer.camera_path``: an orbit for object-centred captures, else a spiral) and the loss curves.

    dvc repro stylize@tiny_single     # its command, with every input and output path: dvc.yaml or --help
"""

from __future__ import annotations

import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.gaussians import fitted_rows
from abcgs.gaussians.ply import read_ply
from abcgs.io.metrics import info_path, write_metrics
from abcgs.masks.outputs import load_scene_masks
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser
from abcgs.runtime import resolve_device, torch_threads
from abcgs.sfm.model import read_scene
from abcgs.stylize.experiment import check_label_weights, load_groups, load_vgg, read_colormatch
from abcgs.stylize.loop import stylize_scene
from abcgs.stylize.outputs import grid_indices, write_history, write_stylized_scene
from abcgs.stylize.targets import LabelWeights

_S, _E = layout.scene("{item.scene}"), layout.experiment("{key}")
SPEC = StageSpec("stylize", foreach="experiments", params=(
    "experiments.{key}", "colormatches.{item.colormatch}", "data.styles", "data.style_masks", "stylize",
    "isolation", "vgg", "viewer.camera_path", "viewer.path_frames", "runtime",
), deps=(
    Dep("colmap", _S.colmap.root, "the scene's COLMAP layout (reconstruct)"),
    Dep("model", _S.fit.ply, "the fitted scene (fit)"),
    Dep("masks", _S.masks.root, "the scene's content labels (masks)"),
    Dep("styles", layout.STYLES, "the paintings and their region maps (styles, style_masks)"),
    Dep("colormatch", _S.colormatch("{item.colormatch}").root, "the colour-matched start (colormatch)"),
), outs=(
    Out(_E.stylize.root, "out", help="the stylized PLY, renders, grid, turntable"),
    Out(_E.stylize_record, "metrics", help="the run's record JSON"),
    Out(info_path(_E.stylize_record)),
    Out(_E.stylize_history, "history", kind="plot", plot_axes=("step", "loss"), help="per-step loss terms CSV"),
))


def main(args, params) -> None:
    exp = params.experiments[args.experiment]
    spec = params.colormatches[exp.colormatch]
    sp = params.stylize
    device = resolve_device(params.runtime.device)
    scene, original = read_scene(args.colmap), read_ply(args.model)
    background = scene.background
    matched = read_colormatch(args.colormatch, exp.colormatch, original.num_gaussians)
    masks = load_scene_masks(args.masks, scene, original.num_gaussians, device=device)
    masks = masks.at_rows(fitted_rows(matched))  # the fitted Gaussians' labels on the re-fitted ones
    check_label_weights(args.experiment, exp, masks.gaussian_labels, args.masks)
    original, matched = original.to(device), matched.to(device)
    vgg, info = load_vgg(params.vgg, sp.layers, device)
    styles = layout.StylesDir(args.styles)
    groups = load_groups(spec, vgg, masks.gaussian_labels, styles.paintings(params.data.styles),
                         styles.label_maps(params.data.style_masks), params.isolation, sp)
    grid_indices(scene.cameras, sp.grid_views)  # a grid_views list that names none of the views fails before work
    with torch_threads(sp.compute.threads):
        res = stylize_scene(matched, original, scene.cameras, masks, groups, vgg, sp, method=exp.method,
                            background=background,
                            label_weights=LabelWeights(exp.content_weights, exp.structure_weights))
        written = write_stylized_scene(
            args.out, res.model, original, scene.cameras, masks.view_labels, groups, backend=sp.compute.backend,
            path_kind=params.viewer.camera_path, path_frames=params.viewer.path_frames, background=background,
            grid_views=sp.grid_views)
    write_history(args.history, res.history)
    write_metrics(args.metrics, {
        "experiment": args.experiment, "method": exp.method, "colormatch": exp.colormatch, "transfer": spec.transfer,
        **res.record(), **written, "vgg_weights": info.model_dump(), "seed": sp.seed,
        "background": background.to_json(),
    })


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
