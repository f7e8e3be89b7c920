"""Stage ``evaluate``: content preservation (SSIM, perceptual), multi-view consistency, FID/KID, ArtFID, speed.

    python stages/evaluate.py --experiment tiny_single --out out/tiny_single/eval.json \
        --headline out/tiny_single/metrics.json

Reads the scene's evaluation reference (``out/S/reference``: the original scene's renders and the optical
flows between them, made once per scene by ``stages/reference.py``), renders the stylized scene
(``out/E/stylize``) for the same views and writes :func:`abcgs.evaluation.evaluate.write_evaluation`'s files.
Proxy metrics are named as proxies (``lpips_proxy_vgg``, ``artfid_proxy``); see docs/METRICS.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

from abcgs.evaluation.evaluate import evaluate_scene, load_stylize_run, write_evaluation
from abcgs.evaluation.reference import load_reference, model_digest
from abcgs.io.images import load_image
from abcgs.io.ply import read_ply
from abcgs.layout import load_scene
from abcgs.pipeline import StageSpec, run_stage, stage_parser
from abcgs.runtime import resolve_device

SPEC = StageSpec("evaluate", foreach="experiments", params=(
    "evaluate", "experiments.{key}", "colormatches.{item.colormatch}", "data.styles", "vgg", "runtime",
))


def main(args, params) -> None:
    ep = params.evaluate
    exp = params.experiments[args.experiment]
    spec = params.colormatches[exp.colormatch]
    scene, original = load_scene(args.root, exp.scene)
    stems = [Path(c.name).stem for c in scene.cameras]
    ply, info, pngs = load_stylize_run(args.root, args.experiment, stems)
    n = min(len(scene.cameras), ep.max_views or len(scene.cameras))
    styles = {k: params.data.styles[k] for k in spec.style_keys()}
    reference = load_reference(args.root / exp.scene / "reference", scene.cameras, ep, scene=exp.scene,
                               model_digest=model_digest(args.root / exp.scene / "gs" / "point_cloud.ply"))
    device = resolve_device(params.runtime.device)
    res = evaluate_scene(scene.cameras, original.to(device), read_ply(ply, device=device), [load_image(p) for p in styles.values()], ep,
                         stylize_info=info, saved_renders=[load_image(p) for p in pngs[:n]], vgg_params=params.vgg,
                         reference=reference)
    record = {"experiment": args.experiment, "scene": exp.scene, "colormatch": exp.colormatch,
              "transfer": spec.transfer, "method": exp.method, "styles": styles, **res.metrics}
    write_evaluation(args.out, args.headline, record, res)


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--out", type=Path, required=True, help="full metrics record JSON (+ *_info.json)")
    ap.add_argument("--headline", type=Path, required=True, help="headline metrics JSON (the DVC metric)")
    sys.exit(run_stage(SPEC, ap, main))
