"""Stage ``stylize``: optimise the colour-matched Gaussians with FAST (or a baseline) + content, TV, depth,
scale and opacity terms; write the stylized PLY, renders, a grid, a turntable video (the camera path of
``viewer.camera_path``: an orbit for object-centred captures, else a spiral) and the loss curves.

    python stages/stylize.py --experiment tiny_single --out out/tiny_single/stylize
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import abcgs  # noqa: E402,F401  (before torch: abcgs sets OpenMP's wait policy, see abcgs/__init__.py)

# isort: split
import numpy as np  # noqa: E402
import torch  # noqa: E402

from abcgs.camera_paths import camera_path  # noqa: E402
from abcgs.errors import InputError  # noqa: E402
from abcgs.fit.trainer import torch_threads  # noqa: E402
from abcgs.gaussians import render  # noqa: E402
from abcgs.io.atomic import atomic_path, write_text  # noqa: E402
from abcgs.io.images import save_image  # noqa: E402
from abcgs.io.metrics import write_metrics  # noqa: E402
from abcgs.io.ply import read_ply, write_ply  # noqa: E402
from abcgs.pipeline import run_stage, stage_parser  # noqa: E402
from abcgs.style.content_masks import colorize_labels  # noqa: E402
from abcgs.style.experiment import (  # noqa: E402
    colormatch_dir,
    colormatch_spec,
    experiment,
    load_groups,
    load_scene,
    load_scene_masks,
    load_vgg,
)
from abcgs.style.matching import ALL_PIXELS  # noqa: E402
from abcgs.style.stylize import stylize  # noqa: E402
from abcgs.viz import image_grid, style_legend, write_video  # noqa: E402


def history_csv(rows: list[dict]) -> str:
    cols = ["step", "seconds", "loss", "style", "content", "tv", "depth", "scale", "opacity"]
    lines = [",".join(cols)]
    for r in rows:
        lines.append(",".join("" if r.get(c) is None else f"{r[c]:.6g}" if isinstance(r.get(c), float) else str(r[c]) for c in cols))
    return "\n".join(lines) + "\n"


def read_colormatch(folder: Path, name: str):
    """The colour-matched Gaussians of stage ``colormatch@<name>``, with a clear error when it has not run."""
    ply = folder / "point_cloud.ply"
    if not ply.is_file():
        raise InputError(f"{ply} is missing: run the colour match first (dvc repro colormatch@{name})")
    return read_ply(ply)


def main(args, params) -> None:
    with torch_threads(params.stylize.threads):
        _main(args, params)


def _main(args, params) -> None:
    exp = experiment(params, args.experiment)
    sp = params.stylize
    spec = colormatch_spec(params, exp.colormatch)
    scene, original = load_scene(args.root, exp.scene)
    matched = read_colormatch(colormatch_dir(args.root, exp.scene, exp.colormatch), exp.colormatch)
    masks = load_scene_masks(args.root / exp.scene / "masks", scene, original.num_gaussians)
    vgg, info = load_vgg(params)
    groups = load_groups(params, spec, vgg, masks.gaussian_labels)
    cams = [c.scaled(sp.resolution_scale) if sp.resolution_scale != 1.0 else c for c in scene.cameras]
    labels = masks.view_labels
    if sp.resolution_scale != 1.0:
        import cv2

        labels = [cv2.resize(v.astype(np.int32), (c.width, c.height), interpolation=cv2.INTER_NEAREST).astype(np.int64)
                  for v, c in zip(labels, cams)]
    res = stylize(matched, cams, labels, masks.gaussian_labels, groups, vgg, sp, method=exp.method, depth_model=original)

    with atomic_path(args.out, is_dir=True) as tmp:
        write_ply(tmp / "point_cloud.ply", res.model)
        (tmp / "renders").mkdir()
        rows = []
        with torch.no_grad():
            t0 = time.perf_counter()
            renders = [render(res.model, c, backend=sp.backend)[0].clamp(0, 1).numpy() for c in scene.cameras]
            fps = len(renders) / (time.perf_counter() - t0)
            for cam, img in zip(scene.cameras, renders):
                save_image(tmp / "renders" / f"{Path(cam.name).stem}.png", img)
            legend = style_legend(
                [(None if g.content_label == ALL_PIXELS else colorize_labels(np.array([g.content_label]))[0],
                  g.style_image, g.style_region) for g in groups],
                height=scene.cameras[0].height)
            for i in range(min(3, len(renders))):
                content = render(original, scene.cameras[i], backend=sp.backend)[0].clamp(0, 1).numpy()
                rows.append([content, colorize_labels(masks.view_labels[i]), legend, renders[i]])
            path, path_kind = camera_path(scene.cameras, params.viewer.camera_path, params.viewer.path_frames)
            frames = [render(res.model, c, backend=sp.backend)[0].clamp(0, 1).numpy() for c in path]
        save_image(tmp / "grid.png", image_grid(rows, ["content", "labels", "label: painting", "stylized"]))
        write_video(tmp / "turntable.mp4", frames, fps=24)
    write_text(args.history, history_csv(res.history))
    n_it = max(1, res.timings.get("iterations", 1))
    write_metrics(args.metrics, {
        "experiment": args.experiment, "method": exp.method, "colormatch": exp.colormatch, "transfer": spec.transfer,
        "stylize_seconds": res.seconds, "iterations": int(res.timings.get("iterations", 0)),
        "seconds_per_iteration": {k: v / n_it for k, v in res.timings.items() if k != "iterations"},
        "render_fps": fps, "fast": res.fast_stats, "n_gaussians": res.model.num_gaussians,
        "vgg_weights": info.model_dump(), "seed": sp.seed, "camera_path": path_kind,
        "projected_search": _projected_search_record(sp.fast),
    })


def _projected_search_record(fast_params) -> dict | None:
    """The approximate neighbour search as it ran here (``projection_products: auto`` resolved on this CPU), or None
    when it is off; it applies to CPU searches of at least ``min_similarities`` only."""
    proj = fast_params.projection()
    if proj is None:
        return None
    return {"rank": proj.rank, "candidates": proj.candidates, "min_similarities": proj.min_similarities,
            "products": "bfloat16" if proj.bf16_products() else "float32"}


if __name__ == "__main__":
    ap = stage_parser(__doc__.strip().splitlines()[0])
    ap.add_argument("--experiment", required=True)
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--metrics", type=Path, required=True, help="metrics JSON (a DVC metric)")
    ap.add_argument("--history", type=Path, required=True, help="per-iteration loss terms CSV (a DVC plot)")
    sys.exit(run_stage("stylize", ap, main))
