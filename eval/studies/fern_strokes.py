"""Regions from strokes alone, on LLFF fern and Starry Night: a scripted user draws on the masks page (in chromium),
and the result is a scene folder and a painting label map that a compositional and a semantic transfer run from.

    python -m eval run fern_strokes --shared ../shared/data --work data/fern_strokes \\
        --screenshots docs/img/masks
    python -m eval run experiment run eval/params/fern_strokes.yaml --name fern-strokes --shared data/fern_strokes
    python -m eval run experiment show fern-strokes \\
        --copy out/fern_strokes_semantic/stylize/grid.png=docs/img/masks/fern_semantic_strokes.jpg \\
        --copy out/fern_strokes_compositional/stylize/grid.png=docs/img/masks/fern_compositional_strokes.jpg

What the first command does, as a person would at ``python -m abcgs.masks.page``:

1. ``<work>/fern/images/`` ← fern's photos, ``<work>/*.jpg`` ← Starry Night and the compositional transfer's other
   two paintings (copies; ``../shared`` stays as it is).
2. The scene's page: on view ``IMG_4026.jpg`` three strokes per label (:data:`SCENE_STROKES`: 1 the fern, 2 the
   concrete planter, 3 the rest), Segment, a screenshot, Save → ``<work>/fern/masks/IMG_4026.png``. No other view
   is touched: the ``masks`` stage lifts that one mask (Eq. 2) and re-cuts the other 19 views on colour and depth.
3. The painting's page: three strokes for each of three regions (:data:`PAINTING_STROKES`: 1 the sky, 2 the
   cypress, 3 the village and the hills), Segment, a screenshot, Save → ``<work>/<painting>_labels.png``.

The strokes are straight polylines in image pixels, listed below; the page gets them as mouse moves. The overlay
``eval/params/fern_strokes.yaml`` then binds them: the semantic transfer gives the fern the village and the hills,
the planter the cypress and the building the sky; the compositional one gives each region a painting of its own.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np

from abcgs.errors import InputError
from abcgs.masks.page.session import PaintSession
from abcgs.masks.strokes import Stroke

VIEW = "IMG_4026.jpg"
"""The fern view the user draws on (the first one, 504 × 378)."""

SCENE_STROKES: dict[int, list[list[tuple[float, float]]]] = {
    1: [[(266, 262), (272, 200), (300, 110), (328, 52)],  # the fern: up the trunk and the central frond
        [(240, 196), (172, 176), (112, 166)],  # a frond to the left
        [(292, 160), (362, 150), (430, 172), (468, 232)]],  # fronds to the right
    2: [[(20, 342), (160, 342)],  # the planter, left and right of the drooping frond
        [(232, 334), (330, 330)],
        [(40, 302), (150, 296)]],
    3: [[(120, 20), (330, 14)],  # the ceiling
        [(420, 262), (490, 340)],  # the floor and the wall on the right
        [(28, 60), (30, 200), (80, 250), (160, 262)]],  # the building and the plants on the left
}
"""Per content label, the strokes on :data:`VIEW` (x, y in the view's pixels)."""

PAINTING_STROKES: dict[int, list[list[tuple[float, float]]]] = {
    1: [[(300, 160), (810, 220)],  # the sky: the swirls
        [(490, 60), (900, 100)],
        [(60, 330), (80, 60)]],  # the sky left of the cypress
    2: [[(178, 140), (172, 330), (182, 540)],  # the cypress
        [(160, 420), (200, 560)],
        [(185, 90), (190, 200)]],
    3: [[(310, 580), (970, 590)],  # the village and the hills
        [(680, 460), (1000, 440)],
        [(420, 620), (700, 625)]],
}
"""Per painting region, the strokes on Starry Night (x, y in its 1024 × 640 pixels)."""

PAINTINGS = ("starry_night", "composition_vii", "woman_with_hat_matisse")
"""The paintings the overlay names (the first is the one drawn on; :data:`PAINTING_STROKES` follow its layout)."""

BRUSH_PX = 4.0
"""Brush radius in image pixels."""


def strokes(table: dict[int, list[list[tuple[float, float]]]]) -> list[Stroke]:
    return [Stroke(label, np.asarray(line, float), BRUSH_PX) for label, lines in table.items() for line in lines]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("--shared", type=Path, default=Path("../shared/data"), help="holds scenes/fern and styles/")
    ap.add_argument("--work", type=Path, default=Path("data/fern_strokes"), help="the user's folder this makes")
    ap.add_argument("--screenshots", type=Path, help="also copy the two page screenshots here (JPEG)")
    a = ap.parse_args(argv)

    fern = a.shared / "scenes" / "fern"
    paintings = [a.shared / "styles" / f"{name}.jpg" for name in PAINTINGS]
    for p in (fern / "images", *paintings):
        if not p.exists():
            raise InputError(f"{p} does not exist; --shared must hold scenes/fern/images and styles/ with "
                             f"{', '.join(PAINTINGS)} (.jpg)")
    scene = a.work / "fern"
    shutil.rmtree(scene, ignore_errors=True)
    shutil.copytree(fern / "images", scene / "images")
    for p in paintings:
        shutil.copy2(p, a.work / p.name)
    painting = a.work / paintings[0].name
    labels_out = a.work / f"{painting.stem}_labels.png"

    from eval.bench.browser import launch_chromium
    from eval.bench.paint_page import CHROMIUM_ARGS, draw_and_save, report_saved

    scene_session = PaintSession.for_scene(scene)
    width = scene_session.size(next(i for i, it in enumerate(scene_session.items) if it.name == VIEW))[1]
    painting_session = PaintSession.for_painting(painting, labels_out)
    with launch_chromium(CHROMIUM_ARGS) as browser:
        draw_and_save(browser, scene_session, strokes(SCENE_STROKES), width, a.work / "page_scene.png", VIEW)
        draw_and_save(browser, painting_session, strokes(PAINTING_STROKES), painting_session.size(0)[1],
                      a.work / "page_painting.png")

    report_saved({"view " + VIEW: scene / "masks" / f"{Path(VIEW).stem}.png", "painting": labels_out}, a.work,
                 a.screenshots, "fern_strokes")
    print(f"wrote {scene}/masks/ and {labels_out}; next: python -m eval run experiment run "
          f"eval/params/fern_strokes.yaml --name fern-strokes --shared {a.work}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
