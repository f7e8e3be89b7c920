"""Render several scenes (PLYs) from the same views side by side, with a 2× crop row: a before/after figure.

    python -m eval run figure_runs --colmap out/bench/fern/colmap --ply original=out/bench/fern/gs/point_cloud.ply \
        --ply "FAST exact=out/quality/fern_exact/runs/<run>/point_cloud.ply" \
        --ply "FAST projected=out/quality/fern_proj/runs/<run>/point_cloud.ply" \
        --views 2,13 --crop 240,180,480,360 --out docs/img/scaling/fern_starry_projected.jpg

Columns: the given scenes in order (captions from NAME); rows: the views, then a 2× crop of the first view
(``--crop x0,y0,x1,y1`` in pixels of that view). ``--style`` adds the painting as a last column.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import cv2
import numpy as np
import torch

from abcgs.errors import InputError
from abcgs.features.matching import load_style
from abcgs.gaussians import render
from abcgs.gaussians.ply import read_ply
from abcgs.io.images import save_image
from abcgs.sfm.model import read_scene
from abcgs.viz import image_grid


def main(argv=None) -> np.ndarray:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--colmap", type=Path, required=True, help="reconstruct output (sparse/, images/, scene.json)")
    ap.add_argument("--ply", action="append", required=True, help="NAME=PATH (repeatable; one column each)")
    ap.add_argument("--views", default="0", help="comma-separated view indices (rows)")
    ap.add_argument("--crop", default=None, help="x0,y0,x1,y1: a 2x crop row of the first view")
    ap.add_argument("--style", type=Path, default=None, help="painting shown as the last column")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    scene = read_scene(args.colmap)
    views = [int(v) for v in args.views.split(",")]
    bad = [v for v in views if not 0 <= v < len(scene.cameras)]
    if bad:
        raise InputError(f"--views {bad} out of range: the scene has {len(scene.cameras)} views")
    names, models = [], []
    for item in args.ply:
        name, sep, path = item.partition("=")
        if not sep:
            raise InputError(f"--ply expects NAME=PATH, got {item!r}")
        names.append(name)
        models.append(read_ply(path))
    rows = []
    with torch.no_grad():
        for v in views:
            rows.append([render(m, scene.cameras[v])[0].clamp(0, 1).numpy() for m in models])
    captions = list(names)
    if args.crop:
        x0, y0, x1, y1 = (int(c) for c in args.crop.split(","))
        rows.append([cv2.resize(img[y0:y1, x0:x1], (2 * (x1 - x0), 2 * (y1 - y0)), interpolation=cv2.INTER_CUBIC)
                     for img in rows[0]])
    if args.style is not None:
        painting = load_style(str(args.style), 0)
        for row in rows[: len(views)]:
            row.append(painting)
        captions.append("painting")
    grid = image_grid(rows, captions, height=rows[0][0].shape[0])
    save_image(args.out, grid)
    print(f"wrote {args.out} ({grid.shape[1]}x{grid.shape[0]})")
    return grid


if __name__ == "__main__":
    main()
