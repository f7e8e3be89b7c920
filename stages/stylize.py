"""Stage ``stylize``: optimise the colour-matched Gaussians with FAST (or a baseline) + content, TV, depth,
scale and opacity terms; write the stylized PLY, renders, a grid, a turntable video (the camera path of
``viewer.camera_path``: an orbit for object-centred captures, else a spiral) and the loss curves.

    python stages/stylize.py --experiment tiny_single --out out/tiny_single/stylize
"""

from __future__ import annotations

import sys
from pathlib import Path

from abcgs.io.metrics import write_metrics
from abcgs.layout import colormatch_dir, load_scene
from abcgs.masks.outputs import load_scene_masks
from abcgs.pipeline import StageSpec, run_stage, stage_parser
from abcgs.runtime import resolve_device, torch_threads
from abcgs.stylize.experiment import load_groups, load_vgg, read_colormatch
from abcgs.stylize.loop import stylize_scene
from abcgs.stylize.outputs import write_history, write_stylized_scene

SPEC = StageSpec("stylize", foreach="experiments", params=(
    "experiments.{key}", "colormatches.{item.colormatch}", "data.styles", "data.style_masks", "stylize",
    "isolation", "vgg", "viewer.camera_path", "viewer.path_frames", "runtime",
))


def main(args, params) -> None:
    exp = params.experiments[args.experiment]
    spec = params.colormatches[exp.colormatch]
    sp = params.stylize
    device = resolve_device(params.runtime.device)
    scene, original = load_scene(args.root, exp.scene)
    matched = read_colormatch(colormatch_dir(args.root, exp.scene, exp.colormatch), exp.colormatch)
    masks = load_scene_masks(args.root / exp.scene / "masks", scene, original.num_gaussians, device=device)
    original, matched = original.to(device), matched.to(device)
    vgg, info = load_vgg(params.vgg, sp.layers, device)
    groups = load_groups(spec, vgg, masks.gaussian_labels, params.data.styles, params.data.style_masks,
                         params.isolation, sp)
    with torch_threads(sp.threads):
        res = stylize_scene(matched, original, scene.cameras, masks, groups, vgg, sp, method=exp.method)
        written = write_stylized_scene(
            args.out, res.model, original, scene.cameras, masks.view_labels, groups, backend=sp.backend,
            path_kind=params.viewer.camera_path, path_frames=params.viewer.path_frames)
    write_history(args.history, res.history)
    write_metrics(args.metrics, {
        "experiment": args.experiment, "method": exp.method, "colormatch": exp.colormatch, "transfer": spec.transfer,
        **res.record(), **written, "vgg_weights": info.model_dump(), "seed": sp.seed,
    })


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--metrics", type=Path, required=True, help="the run's record JSON (+ *_info.json)")
    ap.add_argument("--history", type=Path, required=True, help="per-iteration loss terms CSV (a DVC plot)")
    sys.exit(run_stage(SPEC, ap, main))
