"""Benchmark: the splat viewer page for the fern quality-study scenes, opened in chromium.

    python -m eval run viewer                         # out/quality/fern runs (make quality first)
    python -m eval run viewer --max-gaussians 30000 --json out/bench/viewer.json

Builds one page (``out/bench/viewer_fern.html``) holding, per stylized run of the study (FAST and NNFM on
each painting), the original and the stylized scene over the same subsampled Gaussians, opens it from
``file://`` in Debian's chromium (playwright, SwiftShader software WebGL, headless), and prints:

- the page size, and the .spz bytes per layer;
- time to first frame: from navigation until the first experiment's splats are decoded and its first frame
  is drawn (``abcgs.viewer`` resolved ``ready`` with at least one frame), and the same for switching to each
  other experiment;
- per experiment, the share of non-background pixels and the correlation of the canvas with our own
  rasterizer's render of the same training camera (so neither a blank nor a wrong picture can pass).

Software rendering on this 2-core VM is far slower than any GPU: the figures are an upper bound.
"""

from __future__ import annotations

import base64
import io
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs.gaussians.ply import read_ply
from abcgs.io.atomic import write_text
from abcgs.sfm.model import read_scene
from abcgs.view.page import prepare_experiment, viewer_page
from eval.record import bench_parser, write_record

CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox", "--disable-gpu-sandbox"]


def study_runs(study: Path, methods: tuple[str, ...]) -> list[Path]:
    """Finished stylized runs of the quality study (``runs/<painting>__<method>-<hash>/point_cloud.ply``)."""
    runs = sorted(p.parent for p in (study / "runs").glob("*/point_cloud.ply"))
    return [r for r in runs if r.name.split("__")[1].rsplit("-", 1)[0] in methods]


def canvas(page) -> np.ndarray:
    from PIL import Image

    url = page.evaluate("document.getElementById('abcgs-canvas').toDataURL('image/png')")
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGB")) / 255.0


def agreement(shot: np.ndarray, model, camera) -> float:
    """Pearson correlation of the viewer's canvas with our rasterizer's render of the same camera (white
    background, rendered at the canvas size)."""
    import torch

    from abcgs.gaussians import render

    with torch.no_grad():
        img, alpha, _ = render(model, camera.scaled(shot.shape[1] / camera.width))
    ours = (img + (1 - alpha)).clamp(0, 1).numpy()
    h, w = min(ours.shape[0], shot.shape[0]), min(ours.shape[1], shot.shape[1])
    return float(np.corrcoef(shot[:h, :w].reshape(-1), ours[:h, :w].reshape(-1))[0, 1])


def main(argv=None) -> dict:
    ap = bench_parser(__doc__, json_help="write the record here (default: out/bench/viewer.json)")
    ap.set_defaults(json=Path("out/bench/viewer.json"))
    ap.add_argument("--study", type=Path, default=Path("out/quality/fern"))
    ap.add_argument("--bench-root", type=Path, default=Path("out/bench/fern"), help="fitted scene + COLMAP")
    ap.add_argument("--methods", default="fast,nnfm")
    ap.add_argument("--max-gaussians", type=int, default=100_000)
    ap.add_argument("--width", type=int, default=640, help="canvas width (CSS px)")
    ap.add_argument("--page", type=Path, default=Path("out/bench/viewer_fern.html"))
    ap.add_argument("--chromium", default=shutil.which("chromium") or "chromium")
    args = ap.parse_args(argv)

    runs = study_runs(args.study, tuple(args.methods.split(",")))
    if not runs:
        sys.exit(f"no stylized runs under {args.study}/runs; run `make quality` first")
    colmap = args.bench_root / "colmap"
    cams = read_scene(colmap).cameras
    original = read_ply(args.bench_root / "gs" / "point_cloud.ply")
    t0 = time.perf_counter()
    exps = [prepare_experiment(r.name.rsplit("-", 1)[0], read_ply(r / "point_cloud.ply"), cams, original=original,
                               max_gaussians=args.max_gaussians, full_artifact=str(r / "point_cloud.ply"))
            for r in runs]
    write_text(args.page, viewer_page(exps, title="abcgs: fern quality study", max_width=args.width))
    build_s = time.perf_counter() - t0
    size = args.page.stat().st_size

    from playwright.sync_api import sync_playwright

    per_exp = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=args.chromium, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": args.width + 40, "height": 900})
        remote = []
        page.on("request", lambda r: remote.append(r.url) if not r.url.startswith(("file:", "data:", "blob:")) else None)
        t = time.perf_counter()
        page.goto(args.page.resolve().as_uri())
        page.wait_for_function("window.abcgsViewer && window.abcgsViewer.ready", timeout=600_000)
        page.evaluate("window.abcgsViewer.ready.then(() => window.abcgsViewer.settle(1))")
        first_frame_s = time.perf_counter() - t
        err = page.evaluate("window.abcgsViewer.state.error")
        for i, exp in enumerate(exps):
            t = time.perf_counter()
            if i:
                page.evaluate(f"window.abcgsViewer.setExperiment({i}).then(() => window.abcgsViewer.settle(1))")
            switch_s = time.perf_counter() - t
            page.evaluate("window.abcgsViewer.settle(5)")
            img = canvas(page)
            r = agreement(img, exp.layers["stylized"], exp.cameras[0])
            per_exp.append({"name": exp.name, "switch_s": switch_s if i else first_frame_s, "corr_with_ours": r,
                            "non_background": float((img < 0.97).any(axis=2).mean()), "spz_bytes": exp.spz_bytes})
        browser.close()

    out = {
        "page": str(args.page), "page_bytes": size, "experiments": len(exps), "max_gaussians": args.max_gaussians,
        "gaussians_full": original.num_gaussians, "build_seconds": build_s, "first_frame_seconds": first_frame_s,
        "per_experiment": per_exp, "error": err, "remote_requests": remote,
        "how": "chromium headless, SwiftShader software WebGL, file:// page, time from navigation to the first drawn "
               "frame after the splats decoded",
    }
    write_record(args.json, out, argv)
    print(f"page {args.page}: {size / 1e6:.1f} MB, {len(exps)} experiments × 2 layers × "
          f"{min(args.max_gaussians, original.num_gaussians):,} of {original.num_gaussians:,} Gaussians; built in {build_s:.1f} s")
    print(f"time to first frame (navigation → first experiment drawn): {first_frame_s:.1f} s")
    for e in per_exp:
        print(f"  {e['name']:<32} {'first' if e is per_exp[0] else 'switch'} {e['switch_s']:6.1f} s   "
              f"non-background {e['non_background']:.2f}   r(viewer, ours) {e['corr_with_ours']:.3f}   spz {sum(e['spz_bytes'].values()) / 1e6:.2f} MB")
    print(f"network requests: {len(remote)}; viewer error: {err}")
    if err or remote or any(e["non_background"] < 0.05 or e["corr_with_ours"] < 0.9 for e in per_exp):
        sys.exit("FAILED: the page did not render every experiment offline (see above)")
    return out


if __name__ == "__main__":
    main()
