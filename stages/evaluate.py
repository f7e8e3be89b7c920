"""Stage ``evaluate``: content preservation (SSIM, perceptual), multi-view consistency, FID/KID, ArtFID, speed.

    python stages/evaluate.py --experiment tiny_single --out out/tiny_single/eval.json \
        --headline out/tiny_single/metrics.json

Reads the scene's evaluation reference (``out/S/reference``: the original scene's renders and the optical
flows between them, made once per scene by ``stages/reference.py``), renders the stylized scene
(``out/E/stylize``) for the same views, writes the full numeric record ``eval.json`` (+ ``eval_info.json`` with provenance), the headline numbers
``--headline`` (the DVC metric: :data:`abcgs.io.metrics.EXPERIMENT_HEADLINE`), per-view scores
``eval_views.csv`` (a DVC plot) and
``eval_consistency.png`` (one warped pair: error map with the occlusion mask in cyan). Proxy metrics are
named as proxies (``lpips_proxy_vgg``, ``artfid_proxy``); see ``eval/metrics/__init__.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abcgs.errors import InputError  # noqa: E402
from abcgs.io.atomic import write_text  # noqa: E402
from abcgs.io.images import load_image, save_image  # noqa: E402
from abcgs.io.metrics import experiment_headline, read_record, write_headline, write_metrics  # noqa: E402
from abcgs.io.ply import read_ply  # noqa: E402
from abcgs.pipeline import run_stage, stage_parser  # noqa: E402
from abcgs.style.experiment import colormatch_spec, experiment, load_scene  # noqa: E402
from abcgs.viz import image_grid  # noqa: E402
from eval.metrics.evaluate import evaluate_scene  # noqa: E402
from eval.metrics.reference import load_reference, model_digest  # noqa: E402


def views_csv(rows: list[dict]) -> str:
    cols = list(rows[0])
    out = [",".join(cols)]
    for r in rows:
        out.append(",".join("" if r[c] is None else f"{r[c]:.6g}" if isinstance(r[c], float) else str(r[c]) for c in cols))
    return "\n".join(out) + "\n"


def load_stylize_run(root: Path, name: str, n_views: int, view_stems: list[str]) -> tuple[Path, dict, list]:
    """The stylize stage's outputs for experiment ``name``, checked against the scene's views."""
    run = root / name
    ply, metrics, renders = run / "stylize" / "point_cloud.ply", run / "stylize.json", run / "stylize" / "renders"
    for p in (ply, metrics, renders):
        if not p.exists():
            raise InputError(f"{p} is missing: run the stylize stage for experiment {name!r} first (dvc repro stylize@{name})")
    pngs = sorted(renders.glob("*.png"))
    if len(pngs) != n_views:
        raise InputError(
            f"{renders} holds {len(pngs)} renders but the scene has {n_views} views: the stylize run is stale or "
            f"incomplete; re-run dvc repro stylize@{name}"
        )
    by_stem = {p.stem: p for p in pngs}
    missing = [s for s in view_stems if s not in by_stem]
    if missing:
        raise InputError(f"{renders} has no render for views {missing[:5]}: names do not match the scene's cameras")
    return ply, read_record(metrics), [by_stem[s] for s in view_stems]


def main(args, params) -> None:
    ep = params.evaluate
    exp = experiment(params, args.experiment)
    spec = colormatch_spec(params, exp.colormatch)
    scene, original = load_scene(args.root, exp.scene)
    stems = [Path(c.name).stem for c in scene.cameras]
    ply, info, pngs = load_stylize_run(args.root, args.experiment, len(scene.cameras), stems)
    stylized = read_ply(ply)
    n = min(len(scene.cameras), ep.max_views or len(scene.cameras))
    saved = [load_image(p) for p in pngs[:n]]
    styles = [load_image(params.data.styles[k]) for k in spec.style_keys()]
    ref_dir = args.reference or args.root / exp.scene / "reference"
    reference = load_reference(ref_dir, scene.cameras, ep, scene=exp.scene,
                               model_digest=model_digest(args.root / exp.scene / "gs" / "point_cloud.ply"))
    res = evaluate_scene(scene.cameras, original, stylized, styles, ep, stylize_info=info, saved_renders=saved,
                         vgg_params=params.vgg, reference=reference)
    metrics = {"experiment": args.experiment, "scene": exp.scene, "colormatch": exp.colormatch,
               "transfer": spec.transfer, "method": exp.method,
               "styles": {k: params.data.styles[k] for k in spec.style_keys()}, **res.metrics}
    out = Path(args.out)
    views = Path(args.views) if args.views else out.with_name("eval_views.csv")
    heat = Path(args.heatmap) if args.heatmap else out.with_name("eval_consistency.png")
    save_image(heat, image_grid([res.heatmap], res.heatmap_captions, height=max(160, res.heatmap[0].shape[0])))
    write_text(views, views_csv(res.per_view))
    write_metrics(out, metrics)
    if args.headline:
        write_headline(args.headline, experiment_headline(res.metrics))


if __name__ == "__main__":
    ap = stage_parser(__doc__.strip().splitlines()[0])
    ap.add_argument("--experiment", required=True)
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--out", type=Path, required=True, help="full metrics record JSON (+ *_info.json)")
    ap.add_argument("--headline", type=Path, default=None, help="headline metrics JSON (the DVC metric)")
    ap.add_argument("--views", type=Path, default=None, help="per-view CSV (default: eval_views.csv next to --out)")
    ap.add_argument("--heatmap", type=Path, default=None, help="consistency PNG (default: eval_consistency.png next to --out)")
    ap.add_argument("--reference", type=Path, default=None, help="the scene's evaluation reference (default: ROOT/SCENE/reference)")
    sys.exit(run_stage("evaluate", ap, main))
