"""A screenshot of the report's 3-D viewer (Spark, headless chromium) on a stylized scene whose cameras were made
around a bare splat: what a user who brought only a ``.splat`` sees at the end of the pipeline.

    python -m eval run viewer_shot --splat fern.splat --stylized stylized.ply --count 12 \\
        --out docs/img/splats/bare_splat_fern_viewer.jpg

The cameras are :func:`abcgs.splats.cameras.cameras_around` of ``--splat`` as :mod:`eval.studies.bare_splat` makes them
(a frame-filling scene: forward views frame its quantiles), so the viewer opens at the first generated view; the page
holds the stylized and the original layer.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

import cv2

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs.gaussians.ply import read_ply
from abcgs.io.atomic import write_text
from abcgs.io.images import save_image
from abcgs.splats.cameras import cameras_around
from abcgs.splats.params import SplatViewsParams
from abcgs.splats.registry import read_splat
from abcgs.view.page import prepare_experiment, viewer_page
from eval.bench.viewer import CHROMIUM_ARGS, canvas


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("--splat", type=Path, required=True, help="the bare splat the cameras were made around")
    ap.add_argument("--stylized", type=Path, required=True, help="the stylized scene (PLY)")
    ap.add_argument("--count", type=int, default=12)
    ap.add_argument("--kind", default="auto")
    ap.add_argument("--width", type=int, default=720)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--chromium", default=shutil.which("chromium") or "chromium")
    args = ap.parse_args(argv)

    original = read_splat(args.splat, "auto").model
    cams, kind = cameras_around(original, SplatViewsParams(kind=args.kind, count=args.count, width=640, height=480))
    exp = prepare_experiment("bare splat, stylized", read_ply(args.stylized), cams, original=original)
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp:
        page_file = Path(tmp) / "viewer.html"
        write_text(page_file, viewer_page([exp], title="abcgs: a bare splat, stylized", max_width=args.width))
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=args.chromium, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": args.width + 40, "height": 760})
            page.goto(page_file.resolve().as_uri())
            page.wait_for_function("window.abcgsViewer && window.abcgsViewer.ready", timeout=600_000)
            page.evaluate("window.abcgsViewer.ready.then(() => window.abcgsViewer.settle(5))")
            err = page.evaluate("window.abcgsViewer.state.error")
            img = canvas(page)
            shot = Path(tmp) / "page.png"
            page.screenshot(path=str(shot), full_page=True)
            browser.close()
        if err:
            raise SystemExit(f"the viewer reported an error: {err}")
        if (img < 0.97).any(axis=2).mean() < 0.05:
            raise SystemExit("the viewer drew (almost) nothing")
        save_image(args.out, cv2.cvtColor(cv2.imread(str(shot)), cv2.COLOR_BGR2RGB))
    print(f"{args.out}: {len(cams)} {kind} cameras, {exp.n_gaussians_full} Gaussians")


if __name__ == "__main__":
    main()
