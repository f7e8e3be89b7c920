"""One self-contained HTML page (and a PNG summary) across stylization runs.

The table mirrors the paper's Table 1 (ArtFID, SSIM, time, FPS, short/long-range consistency) and uses
whatever names the evaluate stage wrote: official metric names only where official weights were used,
proxy names (``artfid_proxy``, ``lpips_proxy_vgg``, ``fid_tf_inception``) otherwise. Below it: per run the
content | labels | label → painting | stylized grid and the consistency heat map, and the loss-method ablation
(FAST / NNFM / KNNFM / Gram) side by side for runs that differ only in the method; and, given an
:func:`abcgs.view.viewer_fragment`, the splat viewer of every experiment.
"""

from __future__ import annotations

import base64
import html
import json
from dataclasses import dataclass, field
from pathlib import Path

from abcgs import layout
from abcgs.errors import InputError
from abcgs.io.metrics import read_record


@dataclass
class Run:
    name: str
    spec: dict
    stylize: dict
    evaluation: dict
    images: dict[str, Path] = field(default_factory=dict)


def load_runs(root: Path, experiments: dict[str, dict]) -> list[Run]:
    runs = []
    for name, spec in experiments.items():
        d = layout.experiment(name, root)
        sty, ev = d.stylize_record, d.eval_record
        if not sty.is_file():
            raise InputError(f"run {name!r} has no {sty}; run `dvc repro` first")
        images = {k: p for k, p in (("grid", d.stylize.grid), ("consistency", d.eval_consistency)) if p.is_file()}
        runs.append(Run(name, spec, read_record(sty), read_record(ev) if ev.is_file() else {}, images))
    if not runs:
        raise InputError("no experiments to report; add some under params.yaml experiments")
    return runs


def _perceptual_key(ev: dict, prefix: str) -> str | None:
    """The consistency perceptual distance's key (``short_lpips`` or ``short_lpips_proxy_vgg``, …)."""
    return next((k for k in ev if k.startswith(f"{prefix}lpips") and not k.endswith("_std")
                 and isinstance(ev[k], (int, float))), None)


def table_rows(runs: list[Run]) -> tuple[list[str], list[list[str]]]:
    """Column names (with the metric names actually used) and formatted cells; each warp RMSE is followed by the
    unstylized scene's RMSE over the same pairs (``floor``)."""
    art = next((k for r in runs for k in ("artfid", "artfid_proxy") if k in r.evaluation), "artfid_proxy")
    short_p = next((k for r in runs if (k := _perceptual_key(r.evaluation, "short_"))), "short_lpips")
    long_p = next((k for r in runs if (k := _perceptual_key(r.evaluation, "long_"))), "long_lpips")
    cols = ["run", "scene", "transfer", "method", f"{art} ↓", "fid_tf_inception ↓", "kid_tf_inception ↓", "ssim ↑",
            "stylize min ↓", "fps ↑", f"{short_p} ↓", "short_rmse ↓", "short floor", f"{long_p} ↓", "long_rmse ↓",
            "long floor"]

    def f(v, fmt="{:.3f}"):
        return "–" if v is None else fmt.format(v)

    rows = []
    for r in runs:
        ev, st = r.evaluation, r.stylize
        rows.append([
            r.name, r.spec.get("scene", ""), r.spec.get("transfer", ""), r.spec.get("method", ""),
            f(ev.get(art), "{:.2f}"), f(ev.get("fid_tf_inception"), "{:.1f}"), f(ev.get("kid_tf_inception"), "{:.4f}"),
            f(ev.get("ssim")), f(st.get("stylize_seconds", 0) / 60, "{:.2f}"),
            f((ev.get("speed") or {}).get("render_fps") or st.get("render_fps"), "{:.1f}"),
            f(ev.get(short_p)), f(ev.get("short_rmse")), f(ev.get("short_rmse_floor")),
            f(ev.get(long_p)), f(ev.get("long_rmse")), f(ev.get("long_rmse_floor")),
        ])
    return cols, rows


def _img(path: Path, width: int = 900) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img src="data:image/png;base64,{data}" style="max-width:{width}px;width:100%">'


def ablation_groups(runs: list[Run]) -> list[list[Run]]:
    """Runs that share scene, transfer and style(s) but differ in the loss method."""
    groups: dict[str, list[Run]] = {}
    for r in runs:
        key = json.dumps({k: v for k, v in r.spec.items() if k != "method"}, sort_keys=True)
        groups.setdefault(key, []).append(r)
    return [g for g in groups.values() if len({r.spec.get("method") for r in g}) > 1]


def collect_warnings(root: Path, scenes: list[str]) -> list[str]:
    """What the run left out or changed without stopping: the preflight stage's warnings and, per scene, the views
    whose content labels leave much unlabelled (``out/<scene>/masks/masks.json``) and the views that did not register
    (``out/<scene>/reconstruct.json``)."""
    preflight = root / layout.PREFLIGHT_REPORT.relative_to(layout.OUT)
    warnings = list(read_record(preflight).get("warnings", [])) if preflight.is_file() else []
    for scene in scenes:
        masks = layout.scene(scene, root).masks.record
        if masks.is_file():
            warnings += [f"scene {scene}: {w}" for w in read_record(masks).get("warnings") or []]
        rec = layout.scene(scene, root).reconstruct_record
        if rec.is_file():
            dropped = read_record(rec).get("unregistered") or []
            if dropped:
                warnings.append(f"scene {scene}: {len(dropped)} view(s) did not register and are not in the scene: "
                                f"{', '.join(dropped[:10])}{' …' if len(dropped) > 10 else ''}")
    return warnings


def render_html(runs: list[Run], title: str = "abcgs report", viewer: str | None = None,
                warnings: list[str] | None = None) -> str:
    """The report page; ``viewer``: an :func:`abcgs.view.viewer_fragment` to place under the table; ``warnings``
    (:func:`collect_warnings`) above it."""
    cols, rows = table_rows(runs)
    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows)
    parts = [
        f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;margin:24px;max-width:1200px}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}td:first-child{text-align:left}"
        "h2{margin-top:32px}.note{color:#555;font-size:90%}.warn{background:#fff4d6;border:1px solid #e0b84a;"
        "padding:4px 12px;margin:12px 0}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        "<p class='note'>Metric names say what was computed: <code>artfid</code>/<code>lpips</code> only with the "
        "official networks; offline runs report <code>artfid_proxy</code> = (1 + content distance proxy) × "
        "(1 + fid_tf_inception) and <code>lpips_proxy_vgg</code>. Paper (LLFF, RTX 4090): ABC-GS ArtFID 42.80, "
        "SSIM 0.54, short LPIPS 0.057 / RMSE 0.048, long LPIPS 0.093 / RMSE 0.077.</p>",
        f"<table><tr>{head}</tr>{body}</table>",
    ]
    if warnings:
        items = "".join(f"<li>{html.escape(w)}</li>" for w in warnings)
        parts.insert(-1, f"<div class='warn'><b>Warnings</b><ul>{items}</ul></div>")
    if viewer:
        parts += ["<h2>The scenes in 3-D</h2>", "<p class='note'>Original, stylized and content labels over the same "
                  "Gaussians; the training cameras are the viewpoints ◀ ▶ step through.</p>", viewer]
    for group in ablation_groups(runs):
        parts.append(f"<h2>Ablation: {html.escape(', '.join(r.spec.get('method', '') for r in group))}</h2>")
        parts.append("<div style='display:flex;gap:8px;flex-wrap:wrap'>")
        for r in group:
            if "grid" in r.images:
                parts.append(f"<figure style='margin:0;width:48%'>{_img(r.images['grid'], 560)}"
                             f"<figcaption>{html.escape(r.name)} ({html.escape(r.spec.get('method', ''))})</figcaption></figure>")
        parts.append("</div>")
    for r in runs:
        parts.append(f"<h2>{html.escape(r.name)}</h2>")
        for key, caption in (("grid", "content | labels | each label beside its painting (region) | stylized"),
                             ("consistency", "consistency: warped error")):
            if key in r.images:
                parts.append(f"<figure>{_img(r.images[key])}<figcaption>{caption}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts)


def summary_png(runs: list[Run], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [r.name for r in runs]
    metrics = [("ssim", "SSIM ↑"), ("short_rmse", "short RMSE ↓"), ("long_rmse", "long RMSE ↓")]
    fig, axes = plt.subplots(1, len(metrics), figsize=(4 * len(metrics), 3.2), dpi=110)
    for ax, (key, label) in zip(axes, metrics):
        vals = [r.evaluation.get(key) or 0.0 for r in runs]
        ax.barh(names, vals, color="#4c72b0")
        ax.set_title(label)
        ax.tick_params(axis="y", labelsize=8)
    fig.tight_layout()
    from abcgs.io.atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def format_table(runs: list[Run]) -> str:
    """The report's table as aligned plain text (for terminals and logs)."""
    cols, rows = table_rows(runs)
    widths = [max(len(c), *(len(r[i]) for r in rows)) for i, c in enumerate(cols)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(cols, widths))]
    lines += ["  ".join(v.ljust(w) for v, w in zip(r, widths)) for r in rows]
    return "\n".join(lines)


def format_markdown(runs: list[Run]) -> str:
    """The report's table as GitHub markdown (for README and issue notes)."""
    return _markdown(*table_rows(runs))


def _markdown(cols: list[str], rows: list[list[str]]) -> str:
    """A GitHub markdown table."""
    lines = ["| " + " | ".join(cols) + " |", "|" + " --- |" * len(cols)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def comparison_figure(runs: list[Run], root: Path, styles: dict[str, str], path: Path, *, tile_height: int = 200) -> None:
    """One row per colour match (scene × painting(s)): the photo of the first view, that view rendered by every run
    of the colour match (in the order of ``runs``) and the painting; written to ``path`` (PNG or JPEG, atomically)."""
    import numpy as np

    from abcgs.io.images import load_image, save_image
    from abcgs.viz import image_grid

    by_match: dict[str, list[Run]] = {}
    for r in runs:
        by_match.setdefault(r.spec.get("colormatch", r.name), []).append(r)
    rows, captions = [], None
    for group in by_match.values():
        scene = group[0].spec.get("scene", "")
        photos = sorted(layout.scene(scene, root).colmap.images.glob("*"))
        renders = [sorted(layout.experiment(r.name, root).stylize.renders.glob("*.png")) for r in group]
        if not photos or not all(renders):
            continue
        style_keys = [group[0].spec.get("style")] if group[0].spec.get("style") else sorted(set((group[0].spec.get("styles") or {}).values()))
        row = [load_image(photos[0])] + [load_image(r[0]) for r in renders]
        row += [load_image(styles[k]) for k in style_keys[:1] if k in styles]
        rows.append([np.asarray(t, dtype=np.float32) for t in row])
        if captions is None or len(row) > len(captions):
            captions = ["photo"] + [r.spec.get("method", r.name) for r in group] + ["painting"]
    if not rows:
        return
    width = max(len(r) for r in rows)
    rows = [r + [np.ones_like(r[0])] * (width - len(r)) for r in rows]
    save_image(path, image_grid(rows, captions[:width], height=tile_height))


METHOD_LABELS = {"fast": "FAST", "nnfm": "NNFM (ARF)", "knnfm": "KNNFM", "gram": "Gram", "none": "colour match only"}


def results_markdown(runs: list[Run]) -> str:
    """The results table as markdown, one row per run grouped by painting(s): content SSIM, short/long warp RMSE
    beside the unstylized scene's (the floor: the same pairs, flows and masks on the original renders), Gram style
    distance, KID on TF-Inception patches and stylization minutes (metric names: docs/METRICS.md)."""

    def f(v, fmt="{:.3f}"):
        return "" if v is None else fmt.format(v)

    cols = ["painting(s)", "method", "content SSIM ↑", "short / long warp RMSE ↓", "unstylized floor", "Gram distance ↓",
            "KID (TF-Inception) ↓", "stylize min"]
    rows, previous = [], None
    for r in sorted(runs, key=lambda r: (str(r.spec.get("style") or r.spec.get("styles")), r.spec.get("transfer", ""),
                                         r.spec.get("method") == "none")):
        ev, st = r.evaluation, r.stylize
        painting = r.spec.get("style") or ", ".join(sorted(set((r.spec.get("styles") or {}).values())))
        if r.spec.get("transfer", "single") != "single":
            painting = f"{painting} ({r.spec['transfer']})"
        method = r.spec.get("method", "")
        minutes = st.get("stylize_seconds") if method != "none" else None
        rows.append([
            painting if painting != previous else "", METHOD_LABELS.get(method, method), f(ev.get("ssim")),
            f"{f(ev.get('short_rmse'), '{:.4f}')} / {f(ev.get('long_rmse'), '{:.4f}')}",
            f"{f(ev.get('short_rmse_floor'), '{:.4f}')} / {f(ev.get('long_rmse_floor'), '{:.4f}')}",
            f(ev.get("gram_distance")),
            f(ev.get("kid_tf_inception")), f(None if minutes is None else minutes / 60, "{:.1f}")])
        previous = painting
    return _markdown(cols, rows)


def report_siblings(out: Path) -> tuple[Path, Path, Path]:
    """The files written beside the page ``out``: the metric bars (``<out>.png``), the results table
    (``results.md``) and the comparison figure (``comparison.jpg``)."""
    return out.with_suffix(".png"), out.with_name("results.md"), out.with_name("comparison.jpg")


def write_report(out: Path, runs: list[Run], root: Path, styles: dict[str, str], viewer: str | None = None,
                 warnings: list[str] | None = None) -> None:
    """The report's files: ``out`` (self-contained HTML), ``<out>.png`` (metric bars), ``results.md`` (the table as
    markdown, what README's results block is made from) and ``comparison.jpg`` (:func:`comparison_figure`) beside it."""
    from abcgs.io.atomic import write_text

    summary, results, comparison = report_siblings(out)
    write_text(out, render_html(runs, viewer=viewer, warnings=warnings))
    summary_png(runs, summary)
    write_text(results, results_markdown(runs) + "\n")
    comparison_figure(runs, root, styles, comparison)


if __name__ == "__main__":  # python -m abcgs.report [--markdown]: print the table of the runs in out/
    from abcgs.runtime import setup

    setup()  # the process settings (abcgs.runtime.setup): the wait policy only where torch is not loaded yet

    import argparse

    from abcgs.params import load_params

    ap = argparse.ArgumentParser(description="Print the results table of the experiments in params.yaml.")
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--markdown", action="store_true", help="GitHub markdown instead of aligned text")
    ap.add_argument("--only", help="regular expression: report only the experiments whose name matches")
    a = ap.parse_args()
    params = load_params(a.params)
    specs = params.experiment_specs()
    if a.only:
        import re

        specs = {k: v for k, v in specs.items() if re.search(a.only, k)}
    runs = load_runs(a.root, specs)
    print(format_markdown(runs) if a.markdown else format_table(runs))
