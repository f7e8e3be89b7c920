"""Stage ``masks``: content label maps (given or automatic) lifted onto the fitted Gaussians (Eq. 2),
re-rendered as view-consistent masks for every view.

    python stages/masks.py --scene-name tiny --out out/tiny/masks
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from abcgs.io.atomic import atomic_path, write_json  # noqa: E402
from abcgs.io.images import load_image, save_image, save_labels  # noqa: E402
from abcgs.pipeline import run_stage, stage_parser  # noqa: E402
from abcgs.style.content_masks import colorize_labels, make_content_masks  # noqa: E402
from abcgs.style.experiment import load_scene  # noqa: E402
from abcgs.viz import image_grid  # noqa: E402


def main(args, params) -> None:
    scene, model = load_scene(args.root, args.scene_name)
    masks_dir = args.root / args.scene_name / "colmap" / "masks"
    result = make_content_masks(model, scene.cameras, masks_dir, params.scene_section(args.scene_name, "masks"))
    with atomic_path(args.out, is_dir=True) as tmp:
        np.save(tmp / "gaussian_labels.npy", result.gaussian_labels.numpy().astype(np.int64))
        (tmp / "views").mkdir()
        rows = []
        for cam, path, lab in zip(scene.cameras, scene.image_paths, result.view_labels):
            save_labels(tmp / "views" / f"{Path(cam.name).stem}.png", lab)
            if len(rows) < 4:
                img = load_image(path)
                over = (0.5 * img + 0.5 * colorize_labels(lab) / 255.0).astype(np.float32)
                rows.append([img, colorize_labels(lab), over])
        save_image(tmp / "overlay.png", image_grid(rows, ["view", "lifted labels", "overlay"]))
        counts = {str(k): v for k, v in sorted(
            zip(*np.unique(result.gaussian_labels.numpy(), return_counts=True)))}
        write_json(tmp / "masks.json", {
            "source": result.source, "input_views": result.input_views, "n_labels": result.n_labels,
            "gaussians_per_label": {k: int(v) for k, v in counts.items()},
            "agreement_with_input_masks": result.agreement,
            "heldout_views": result.heldout_views,
            "heldout_iou_per_label": {str(k): v for k, v in result.heldout_iou.items()},
            "heldout_agreement": result.heldout_agreement,
            "colour_palette": {str(k): list(v) for k, v in result.palette.items()},
            "gaussians_propagated": result.propagated,
        })


if __name__ == "__main__":
    ap = stage_parser(__doc__.strip().splitlines()[0])
    ap.add_argument("--scene-name", required=True)
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--out", type=Path, required=True)
    sys.exit(run_stage("masks", ap, main))
