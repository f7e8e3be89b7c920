"""Benchmark a splat of real size: import, stylize and export ``--n`` Gaussians of SH degree 3 on this machine.

    python -m eval run large_splat --n 3000000 --json docs/measurements/large_splat_3m.json
    python -m eval run large_splat --table docs/measurements/large_splat_3m*.json   # the records side by side

A scene trained for 30k iterations holds 1–6 M Gaussians. This synthesizes one (deterministic: ``--n`` Gaussians of
SH degree 3 on three textured walls and a cloud in between, 0.3–3 cm across in a 2 m room), writes it as an INRIA PLY
(the input), then times each phase and reads the process's peak resident memory after it:

- ``import``: :func:`abcgs.splats.formats.read_splat`, and the import check (:func:`abcgs.splats.validate.check_splat`)
  against ``--views`` photos (the splat's own renders at the scene size);
- ``stylize``: :func:`abcgs.stylize.loop.stylize` with ``--steps`` main-pass steps and ``--color-steps`` colour-pass
  steps at ``--width`` × ``--height`` (fern's size by default), VGG-16 with random weights (the same arithmetic as the
  real ones); its preparation (content render, depth and VGG features of each view), and each step split into render
  (projection + rasterization), VGG, style loss, backward (through VGG and the rasterizer) and the optimiser step;
  the higher SH bands are zeroed first, as the pipeline's colour match leaves them (``--higher-sh``, default ``zero``:
  ``stylize.higher_sh``'s default), and the passes then render at degree 0 (the same image);
- ``export``: the stylized scene written back as the input's INRIA PLY and as ``.spz``;
- ``preview``: the same stylization steps on :func:`abcgs.splats.preview.decimate` to ``--preview`` Gaussians.

Each phase records its own peak resident memory (VmHWM, reset between phases) and the 1-minute load average
after it: run it alone, the load changes the times several-fold. The colour pass runs with its geometry frozen
(replayed blending maps, :mod:`abcgs.stylize.replay`) unless ``--color-pass-rotations``.

Prints a table and, with ``--json``, writes the raw record.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import tempfile
import time
from pathlib import Path
from typing import get_args

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs.cameras import Camera, Cameras, intrinsics, look_at
from abcgs.features.params import ALL_PIXELS
from abcgs.features.vgg import VGG16Features, extract_features, random_state_dict
from abcgs.gaussians import GaussianModel, render
from abcgs.gaussians.ply import write_ply
from abcgs.io.images import save_image
from abcgs.splats.formats.spz import write_spz
from abcgs.splats.preview import decimate
from abcgs.splats.registry import read_splat, write_splat
from abcgs.splats.validate import check_splat
from abcgs.stylize.loop import stylize
from abcgs.stylize.params import HigherSH, StylizeCompute, StylizeOptim, StylizeParams
from abcgs.types import CalibratedScene, MatchingGroup
from eval.record import bench_parser, write_record


def peak_rss_gib() -> float:
    """The process's peak resident memory since the last :func:`reset_peak_rss` (Linux: VmHWM), in GiB."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 2**20  # KiB
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # Linux: KiB, since the start


def reset_peak_rss() -> None:
    """Start a new peak (writing 5 to /proc/self/clear_refs resets VmHWM to the current resident size)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def synthesize(n: int, seed: int = 0) -> GaussianModel:
    """``n`` Gaussians of SH degree 3: 80 % on three walls (back z = 1, left x = -1, floor y = 1) with a smooth
    colour pattern, 20 % in a cloud in between."""
    g = torch.Generator().manual_seed(seed)
    n_wall = int(0.8 * n)
    uv = torch.rand(n_wall, 2, generator=g) * 2 - 1
    wall = torch.randint(0, 3, (n_wall,), generator=g)
    means = torch.empty(n, 3)
    w = means[:n_wall]
    w[:] = torch.stack([uv[:, 0], uv[:, 1], torch.ones(n_wall)], 1)
    w[wall == 1] = torch.stack([-torch.ones(n_wall), uv[:, 1], uv[:, 0]], 1)[wall == 1]
    w[wall == 2] = torch.stack([uv[:, 0], torch.ones(n_wall), uv[:, 1]], 1)[wall == 2]
    means[n_wall:] = (torch.rand(n - n_wall, 3, generator=g) * 2 - 1) * torch.tensor([0.6, 0.6, 0.5])
    rgb = 0.5 + 0.4 * torch.stack([torch.sin(6 * means[:, 0]), torch.cos(5 * means[:, 1]), torch.sin(4 * means[:, 2] + 1)], 1)
    return GaussianModel(
        means=means, quats=torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1),
        log_scales=np.log(0.003) + torch.rand(n, 3, generator=g) * np.log(10.0),
        opacity_logits=torch.randn(n, generator=g) + 1.0,
        sh0=((rgb - 0.5) / 0.28209479177387814)[:, None, :],
        shN=torch.randn(n, 15, 3, generator=g) * 0.05,
    )


def cameras(count: int, width: int, height: int) -> list[Camera]:
    K = intrinsics(0.9 * width, width, height)
    out = []
    for i in range(count):
        t = (i / max(count - 1, 1) - 0.5) * 0.6
        eye = np.array([0.5 * np.sin(t), -0.1, -2.6 + 0.2 * np.cos(t)])
        out.append(Camera(f"view_{i:02d}.png", K, look_at(eye, np.array([0.0, 0.0, 0.5])), width, height))
    return out


TABLE_ROWS = (
    ("import: read the PLY", "import: read PLY", "seconds"),
    ("import: check against the photos", "import: check vs photos", "seconds"),
    ("stylize: prepare the views", "stylize (full)", "prepare_s"),
    ("stylize: one main-pass step", "stylize (full)", "main_step_s"),
    ("  render (projection, SH, rasterization)", "stylize (full)", "step_render_s"),
    ("  VGG", "stylize (full)", "step_vgg_s"),
    ("  style loss", "stylize (full)", "step_style_loss_s"),
    ("  backward (VGG and renderer)", "stylize (full)", "step_backward_s"),
    ("  Adam", "stylize (full)", "step_step_s"),
    ("stylize: colour pass, prepare (renders, colour match)", "stylize (full)", "color_prepare_s"),
    ("stylize: one colour-pass step (records the view's map)", "stylize (full)", "color_record_step_s"),
    ("stylize: one colour-pass step (replays the map)", "stylize (full)", "color_step_s"),
    ("stylize: peak memory (GiB)", "stylize (full)", "peak_rss_gib"),
    ("export: the INRIA PLY back", "export: INRIA PLY back", "seconds"),
    ("export: `.spz`", "export: .spz", "seconds"),
    ("import / export: largest peak memory (GiB)", None, "peak_rss_gib"),
    ("preview (300 k): one main-pass step", "stylize (preview)", "main_step_s"),
)
"""The rows of :func:`markdown_table`: label, phase, key."""


def markdown_table(records: dict[str, dict]) -> str:
    """A markdown table of the :data:`TABLE_ROWS` of several records (column title → record), with each record's
    machine and load average under it."""
    def value(rec: dict, phase: str | None, key: str) -> str:
        if phase is None:  # the largest over the import and export phases
            vals = [v.get(key) for k, v in rec["phases"].items() if k.startswith(("import", "export"))]
            vals = [v for v in vals if v is not None]
            return f"{max(vals):.2f}" if vals else "–"
        v = rec["phases"].get(phase, {}).get(key)
        return "–" if v is None else f"{v:.3g}" if v < 10 else f"{v:.0f}"

    titles = list(records)
    lines = ["| 3 M Gaussians, SH 3, 504 × 378 | " + " | ".join(titles) + " |", "| --- |" + " --- |" * len(titles)]
    for label, phase, key in TABLE_ROWS:
        lines.append(f"| {label} | " + " | ".join(value(records[t], phase, key) for t in titles) + " |")
    loads = [records[t].get("load_average") or records[t].get("load_average_start") for t in titles]
    lines.append("| load average (1, 5, 15 min) at the end | "
                 + " | ".join("–" if not ld else ", ".join(f"{x:.1f}" for x in ld) for ld in loads) + " |")
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    ap = bench_parser(__doc__)
    ap.add_argument("--n", type=int, default=3_000_000)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--width", type=int, default=504)
    ap.add_argument("--height", type=int, default=378)
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--color-steps", type=int, default=8, help="colour-pass steps (more than --views, so that views are replayed)")
    ap.add_argument("--preview", type=int, default=300_000)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--color-pass-rotations", action="store_true",
                    help="re-fit rotations in the colour pass (stylize.optim.color_pass_rotations); by default its "
                    "geometry is frozen and each view's blending map is replayed")
    ap.add_argument("--higher-sh", default="zero", choices=get_args(HigherSH),
                    help="stylize.higher_sh: the SH bands above DC in the stylization (default, as the pipeline's: "
                    "zero, the colour match zeroes them)")
    ap.add_argument("--work", type=Path, default=None, help="scratch folder (default: a temporary one)")
    ap.add_argument("--table", type=Path, nargs="+", metavar="JSON",
                    help="print the markdown table of these records (one column each) and exit")
    return ap


def record_phase(phases: dict, name: str, seconds: float, **extra: float | int) -> None:
    """Store a phase under ``phases[name]``: its wall ``seconds``, the peak resident memory since the last phase (GiB;
    then reset), the 1-minute load average and ``extra`` figures; and print them on one line."""
    peak = peak_rss_gib()
    phases[name] = {"seconds": seconds, "peak_rss_gib": peak, "load_average_1min": os.getloadavg()[0], **extra}
    print(f"{name:>28}: {seconds:8.1f} s   peak RSS {peak:5.2f} GiB  load {os.getloadavg()[0]:4.1f}  "
          + " ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in extra.items()), flush=True)
    reset_peak_rss()


def render_photos(model: GaussianModel, cams: list[Camera], folder: Path) -> list[Path]:
    """The splat's own renders of ``cams``, written as ``folder/<camera name>`` (the import check's photos)."""
    paths = []
    with torch.no_grad():
        for c in cams:
            save_image(folder / c.name, render(model, c)[0].clamp(0, 1).numpy())
            paths.append(folder / c.name)
    return paths


def random_style() -> tuple[VGG16Features, list[MatchingGroup]]:
    """VGG-16 with random weights (seed 0; the real ones' arithmetic) and one matching group for all pixels: a random
    ``3 × 256 × 256`` painting (seed 1) with its relu3_1..3 features."""
    layers = ["relu3_1", "relu3_2", "relu3_3"]
    vgg = VGG16Features(random_state_dict(0), layers)
    style = torch.rand(3, 256, 256, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        feats = extract_features(vgg, style[None], layers)[0]
    pixels = style.permute(1, 2, 0).reshape(-1, 3).numpy()
    return vgg, [MatchingGroup(ALL_PIXELS, "style", pixels, feats.reshape(feats.shape[0], -1))]


def stylize_phase(phases: dict, name: str, m: GaussianModel, cams: list[Camera], vgg: VGG16Features,
                  groups: list[MatchingGroup], sp: StylizeParams) -> GaussianModel:
    """Stylize ``m`` (single-image transfer with ``groups``) and record the phase ``name``: its total, the preparation,
    one main-pass step and its split, and the colour pass's preparation and steps (seconds). Returns the stylized
    model."""
    if sp.higher_sh == "zero":  # what the colour match leaves the stylization (stylize.higher_sh: zero)
        m.shN.zero_()
    labels = torch.zeros(m.num_gaussians, dtype=torch.long)
    view_labels = [np.zeros((c.height, c.width), np.int64) for c in cams]
    t0 = time.perf_counter()
    res = stylize(m, cams, view_labels, labels, groups, vgg, sp, depth_model=m, progress=False)
    total = time.perf_counter() - t0
    n_it = max(1, int(res.timings.get("iterations", 1)))
    split = {k: v / n_it for k, v in res.timings.items() if k != "iterations"}
    main_s = sum(res.timings[k] for k in split)
    prepare = total - main_s - res.color_pass_seconds
    step = sum(split.values())
    ct = res.color_timings
    color = {"color_prepare_s": ct.get("prepare_s", 0.0),
             "color_record_step_s": ct.get("record_s", 0.0) / max(1, ct.get("record_steps", 0)),
             "color_step_s": ct.get("steps_s", 0.0) / max(1, ct.get("steps", 0))}
    record_phase(phases, name, total, main_step_s=step, prepare_s=prepare, **color,
                 **{f"step_{k}_s": v for k, v in split.items()})
    return res.model


def main(argv=None) -> dict:
    args = _parser().parse_args(argv)
    if args.table:
        print(markdown_table({p.stem: json.loads(p.read_text()) for p in args.table}))
        return {}
    torch.set_num_threads(args.threads)
    work = args.work or Path(tempfile.mkdtemp(prefix="large_splat_"))
    work.mkdir(parents=True, exist_ok=True)
    rec: dict = {"n_gaussians": args.n, "sh_degree": 3, "views": args.views, "width": args.width, "height": args.height,
                 "threads": args.threads, "color_pass_rotations": args.color_pass_rotations,
                 "higher_sh": args.higher_sh, "load_average_start": os.getloadavg(),
                 "phases": {}}
    phases = rec["phases"]

    t = time.perf_counter()
    model = synthesize(args.n)
    ply = work / "input" / "point_cloud.ply"
    write_ply(ply, model)
    record_phase(phases, "synthesize + write input PLY", time.perf_counter() - t, ply_gib=ply.stat().st_size / 2**30)
    cams = cameras(args.views, args.width, args.height)
    t = time.perf_counter()
    paths = render_photos(model, cams, work / "photos")
    record_phase(phases, "render the photos", time.perf_counter() - t, per_view_s=(time.perf_counter() - t) / len(cams))
    del model
    scene = CalibratedScene(Cameras.from_list(cams), paths, np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32))

    t = time.perf_counter()
    imported = read_splat(ply, scene=scene)
    record_phase(phases, "import: read PLY", time.perf_counter() - t)
    t = time.perf_counter()
    check = check_splat(imported.model, scene, min_psnr=18.0)
    record_phase(phases, "import: check vs photos", time.perf_counter() - t, psnr_db=check.psnr, check_width=check.width)

    vgg, groups = random_style()
    sp = StylizeParams(optim=StylizeOptim(iterations=args.steps, color_pass_iterations=args.color_steps,
                                          color_pass_rotations=args.color_pass_rotations),
                       compute=StylizeCompute(log_every=1), higher_sh=args.higher_sh)
    styled = stylize_phase(phases, "stylize (full)", imported.model, cams, vgg, groups, sp)
    t = time.perf_counter()
    out = write_splat(styled, work / "returned" / "point_cloud.ply", imported.provenance)
    record_phase(phases, "export: INRIA PLY back", time.perf_counter() - t, ply_gib=out.stat().st_size / 2**30)
    t = time.perf_counter()
    size = write_spz(work / "returned" / "point_cloud.spz", styled)
    record_phase(phases, "export: .spz", time.perf_counter() - t, spz_gib=size / 2**30)
    del styled
    t = time.perf_counter()
    small = decimate(imported.model, args.preview)
    record_phase(phases, f"preview: decimate to {args.preview}", time.perf_counter() - t)
    stylize_phase(phases, "stylize (preview)", small, cams, vgg, groups, sp)
    rec["load_average"] = os.getloadavg()
    if args.json:
        write_record(args.json, rec, argv)
    return rec

if __name__ == "__main__":
    main()
