"""Stage ``evaluate``: content preservation (SSIM, perceptual), multi-view consistency, FID/KID, ArtFID, speed.

    dvc repro evaluate@tiny_single     # its command, with every input and output path: dvc.yaml or --help

Reads the scene's evaluation reference (``out/S/reference``: the original scene's renders and the optical
flows between them, made once per scene by ``stages/reference.py``), renders the stylized scene
(``out/E/stylize``) for the same views and writes :func:`abcgs.evaluation.evaluate.write_evaluation`'s files.
Proxy metrics are named as proxies (``lpips_proxy_vgg``, ``artfid_proxy``); see docs/METRICS.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.evaluation.evaluate import evaluate_scene, load_stylize_run, write_evaluation
from abcgs.evaluation.reference import load_reference, model_digest
from abcgs.gaussians.ply import read_ply
from abcgs.io.images import load_image, load_render
from abcgs.io.metrics import info_path
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser
from abcgs.runtime import resolve_device
from abcgs.sfm.model import read_scene

_S, _E = layout.scene("{item.scene}"), layout.experiment("{key}")
SPEC = StageSpec("evaluate", foreach="experiments", params=(
    "evaluate", "experiments.{key}", "colormatches.{item.colormatch}", "data.styles", "vgg", "runtime",
), deps=(
    Dep("colmap", _S.colmap.root, "the scene's COLMAP layout (reconstruct)"),
    Dep("model", _S.fit.ply, "the fitted scene (fit)"),
    Dep("reference", _S.reference, "the scene's renders and flows (reference)"),
    Dep("stylized", _E.stylize.root, "the stylized scene and its renders (stylize)"),
    Dep("stylize-record", info_path(_E.stylize_record), "the stylization's full record (stylize)"),
    Dep("styles", layout.STYLES, "the paintings (styles)"),
), outs=(
    Out(_E.eval_record, "out", help="every metric (JSON)"),
    Out(info_path(_E.eval_record)),
    Out(_E.eval_consistency),
    Out(_E.eval_headline, "headline", kind="metric", help="the headline metrics (the DVC metric)"),
    Out(_E.eval_views, kind="plot", plot_axes=("view", "short_rmse")),
))


def main(args, params) -> None:
    ep = params.evaluate
    exp = params.experiments[args.experiment]
    spec = params.colormatches[exp.colormatch]
    scene, original = read_scene(args.colmap), read_ply(args.model)
    stems = [Path(c.name).stem for c in scene.cameras]
    ply, info, pngs = load_stylize_run(layout.StylizeDir(args.stylized), args.stylize_record, args.experiment, stems)
    n = min(len(scene.cameras), ep.max_views or len(scene.cameras))
    styles = {k: params.data.styles[k] for k in spec.style_keys()}
    reference = load_reference(args.reference, scene.cameras, ep, scene=exp.scene, model_digest=model_digest(args.model))
    device = resolve_device(params.runtime.device)
    paintings = layout.StylesDir(args.styles).paintings(styles)
    background = scene.background
    res = evaluate_scene(scene.cameras, original.to(device), read_ply(ply, device=device),
                         [load_image(paintings[k]) for k in styles], ep,
                         stylize_info=info, saved_renders=[load_render(p, background) for p in pngs[:n]],
                         vgg_params=params.vgg, reference=reference, background=background)
    record = {"experiment": args.experiment, "scene": exp.scene, "colormatch": exp.colormatch,
              "transfer": spec.transfer, "method": exp.method, "styles": styles, **res.metrics}
    write_evaluation(args.out, args.headline, record, res)


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
