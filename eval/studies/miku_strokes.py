"""Regions from strokes alone, on the miku capture and Matisse's Woman with a Hat: a scripted user draws on the masks
page (in chromium), and the result is a scene folder and a painting label map that a compositional and a semantic
transfer run from.

    python -m eval run fit --scene ../shared/data/scenes/miku --format colmap --work W --iterations 3000 \\
        --test-every 0 --threads 1                                  # the fitted splat, as eval.bench.strokes uses it
    python -m eval run miku_strokes --shared ../shared/data --splat W/miku-colmap/gs/point_cloud.ply \\
        --work data/miku_strokes
    python -m eval run experiment run eval/params/miku_strokes.yaml --name miku-strokes --shared data/miku_strokes
    python -m eval run experiment show miku-strokes \\
        --copy out/miku_strokes_semantic/stylize/grid.png=docs/img/masks/miku_semantic_strokes.jpg \\
        --copy out/miku_strokes_compositional/stylize/grid.png=docs/img/masks/miku_compositional_strokes.jpg

What the second command does, as a person would at ``python -m abcgs.masks.page``:

1. ``<work>/miku/``: the capture's COLMAP model (``sparse/0/``, copied), a subset of its photos in ``images/``
   (:func:`subset`: every :data:`STEP`-th photo in name order counted from the stroked view, and the arc's two far
   ends, :data:`EXTREMES`; the model's other images are left out by the reader) and the fitted splat
   (``point_cloud.ply``, copied from ``--splat``: the ``fit`` stage imports it instead of fitting). ``<work>/*.jpg``
   ← the paintings the overlay names (copies; ``../shared`` stays as it is).
2. The scene's page: on the front view the test strokes of the miku strokes benchmark (``eval/data/miku/
   strokes.json``, ``test``: 15 strokes, labels 1 hair, 2 face, 3 hood, 4 dress, 5 the bed, 6 the room; drawn in
   the pixels of the undistorted views, scaled here to the photo's size), Segment, a screenshot, Save →
   ``<work>/miku/masks/<view>.png``. No other view is touched: the ``masks`` stage lifts that one mask and re-cuts
   the other views on colour and depth.
3. The painting's page: strokes for six regions numbered like the doll's labels (:data:`PAINTING_STROKES`: 1 the
   hair, 2 the face, 3 the hat, 4 the dress, 5 the background left of the figure, 6 the background right of it),
   Segment, a screenshot, Save → ``<work>/woman_with_hat_matisse_labels.png``.

The overlay ``eval/params/miku_strokes.yaml`` then binds them: the semantic transfer gives each part of the doll the
same part of the portrait (the hood the hat, the bed the left background, the room the right one); the compositional
one gives each label a painting of its own.
"""

from __future__ import annotations

import argparse
import json
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
from abcgs.sources.detect import image_files
from abcgs.sources.lens import image_size
from eval.bench.strokes import DATA

STROKES = DATA / "miku" / "strokes.json"
"""The miku strokes benchmark's annotation: its ``test`` view and strokes are the user's strokes here."""

STEP = 4
"""Every STEP-th photo (in name order, counted from the stroked view) goes into the scene."""

EXTREMES = ("20240212_003945", "20240212_004018")
"""The far ends of the arc round the doll (about 100° to its left and 107° to its right of the front view), kept
whatever STEP gives."""

PAINTING_STROKES: dict[int, list[list[tuple[float, float]]]] = {
    1: [[(152, 318), (205, 334)],  # the hair: the red-orange lock left of the face
        [(180, 350), (200, 372)],
        [(346, 318), (362, 340)]],  # and the dark lock on the right
    2: [[(248, 372), (322, 378)],  # the face
        [(292, 396), (300, 432)],
        [(236, 338), (262, 344)]],
    3: [[(70, 175), (250, 255), (430, 200)],  # the hat: the blue brim
        [(190, 55), (330, 75)],  # the flowers on top
        [(380, 100), (430, 150)],
        [(100, 150), (160, 120)],
        [(352, 20), (368, 90)]],  # the dark feathers at the top
    4: [[(150, 520), (380, 505)],  # the dress: the light-blue bodice
        [(210, 600), (400, 585)],
        [(120, 720), (400, 725)],
        [(240, 460), (330, 470)],  # the collar
        [(198, 418), (214, 456)],  # the shoulder below the hair
        [(430, 640), (520, 700)],  # the dark dress and the red patch at the bottom right
        [(460, 762), (560, 780)]],
    5: [[(20, 60), (30, 300)],  # the background left of the figure: green, yellow, orange
        [(55, 240), (95, 320)],
        [(15, 650), (20, 790)],
        [(30, 420), (50, 540)],
        [(110, 20), (160, 40)]],  # the teal above the hat's left
    6: [[(480, 50), (560, 440)],  # the background right of the figure: pink, violet, teal
        [(455, 330), (470, 470)],
        [(570, 520), (575, 600)],
        [(384, 330), (424, 430)],  # the teal patch right of the face
        [(440, 440), (470, 500)]],
}
"""Per painting region, the strokes on Woman with a Hat (x, y in its 591 × 800 pixels)."""

PAINTINGS = ("woman_with_hat_matisse", "starry_night", "composition_vii", "udnie", "van_doesburg_composition_xiii",
             "shipwreck")
"""The paintings the overlay names (the first is the one drawn on; :data:`PAINTING_STROKES` follow its layout)."""

BRUSH_PX = 4.0
"""Brush radius of the painting's strokes, in image pixels."""


def front_strokes(spec: dict, size: tuple[int, int]) -> tuple[str, list[Stroke]]:
    """The benchmark's test view and its strokes at a photo ``size`` (w, h): ``strokes.json`` holds them in the pixels
    of ``image_size`` (the undistorted views), the page shows the photos."""
    w0, h0 = spec["image_size"]
    scale = np.array([size[0] / w0, size[1] / h0])
    strokes = [Stroke.from_json(d) for d in spec["test"]["strokes"]]
    return spec["test"]["view"], [Stroke(s.label, s.points * scale, s.radius) for s in strokes]


def subset(names: list[str], front: str, step: int = STEP, extremes: tuple[str, ...] = EXTREMES) -> list[str]:
    """The photos the scene keeps of ``names`` (sorted file names): every ``step``-th counted from the one of stem
    ``front``, and those of stems ``extremes``."""
    stems = [Path(n).stem for n in names]
    missing = [s for s in (front, *extremes) if s not in stems]
    if missing:
        raise InputError(f"the capture has no photo {', '.join(missing)}")
    i0 = stems.index(front)
    return [n for i, (n, s) in enumerate(zip(names, stems)) if (i - i0) % step == 0 or s in extremes]


def painting_strokes() -> list[Stroke]:
    return [Stroke(label, np.asarray(line, float), BRUSH_PX) for label, lines in PAINTING_STROKES.items()
            for line in lines]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("--shared", type=Path, default=Path("../shared/data"), help="holds scenes/miku and styles/")
    ap.add_argument("--splat", type=Path, required=True,
                    help="a splat fitted to the whole capture (eval.bench.fit's <work>/miku-colmap/gs/point_cloud.ply)")
    ap.add_argument("--work", type=Path, default=Path("data/miku_strokes"), help="the user's folder this makes")
    ap.add_argument("--screenshots", type=Path, help="also copy the two page screenshots here (JPEG)")
    a = ap.parse_args(argv)

    miku = a.shared / "scenes" / "miku"
    paintings = [a.shared / "styles" / f"{name}.jpg" for name in PAINTINGS]
    for p in (miku / "images", miku / "sparse" / "0", a.splat, *paintings):
        if not p.exists():
            raise InputError(f"{p} does not exist; --shared must hold scenes/miku (images/, sparse/0/) and styles/ with "
                             f"{', '.join(PAINTINGS)} (.jpg), --splat a fitted PLY")
    spec = json.loads(STROKES.read_text())
    photos = image_files(miku / "images")
    front = spec["test"]["view"]
    keep = subset([p.name for p in photos], front)

    scene = a.work / "miku"
    shutil.rmtree(scene, ignore_errors=True)
    (scene / "images").mkdir(parents=True)
    for name in keep:
        shutil.copy2(miku / "images" / name, scene / "images" / name)
    shutil.copytree(miku / "sparse" / "0", scene / "sparse" / "0")
    shutil.copy2(a.splat, scene / "point_cloud.ply")
    for p in paintings:
        shutil.copy2(p, a.work / p.name)
    painting = a.work / paintings[0].name
    labels_out = a.work / f"{painting.stem}_labels.png"

    from eval.bench.browser import launch_chromium
    from eval.bench.paint_page import CHROMIUM_ARGS, draw_and_save, report_saved

    scene_session = PaintSession.for_scene(scene, fmt="colmap", first=[front])
    view = next(it.name for it in scene_session.items if Path(it.name).stem == front)
    view_name, strokes = front_strokes(spec, image_size(scene / "images" / view))
    painting_session = PaintSession.for_painting(painting, labels_out)
    with launch_chromium(CHROMIUM_ARGS) as browser:
        draw_and_save(browser, scene_session, strokes, image_size(scene / "images" / view)[0],
                      a.work / "page_scene.png", view)
        draw_and_save(browser, painting_session, painting_strokes(), painting_session.size(0)[1],
                      a.work / "page_painting.png")

    report_saved({"view " + view: scene / "masks" / f"{view_name}.png", "painting": labels_out}, a.work,
                 a.screenshots, "miku_strokes")
    print(f"wrote {scene} ({len(keep)} of {len(photos)} photos), its masks/ and {labels_out}; next: python -m "
          f"eval.bench.experiment run eval/params/miku_strokes.yaml --name miku-strokes --shared {a.work}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
