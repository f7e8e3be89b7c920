"""The cross-run report: names metrics as written, groups the ablation, embeds its images."""

from __future__ import annotations

import numpy as np
import pytest

from abcgs.errors import InputError
from abcgs.io.images import save_image
from abcgs.io.metrics import write_metrics
from abcgs.report import ablation_groups, format_markdown, format_table, load_runs, render_html, summary_png

SPECS = {
    "a_fast": {"scene": "s", "transfer": "single", "style": "p", "method": "fast"},
    "a_nnfm": {"scene": "s", "transfer": "single", "style": "p", "method": "nnfm"},
    "b_fast": {"scene": "s", "transfer": "single", "style": "q", "method": "fast"},
}


def make_run(root, name, official: bool, ssim: float) -> None:
    d = root / name
    write_metrics(d / "stylize.json", {"experiment": name, "stylize_seconds": 90.0, "render_fps": 12.5,
                                       "vgg_weights": {"sha256": "ab"}})
    ev = {"experiment": name, "ssim": ssim, "short_rmse": 0.05, "long_rmse": 0.08, "fid_tf_inception": 300.0,
          "kid_tf_inception": 0.25, "provenance": {"seed": 0}}
    if official:
        ev |= {"artfid": 40.0, "short_lpips": 0.06, "long_lpips": 0.09}
    else:
        ev |= {"artfid_proxy": 900.0, "short_lpips_proxy_vgg": 0.3, "long_lpips_proxy_vgg": 0.7}
    write_metrics(d / "eval.json", ev)
    save_image(d / "stylize" / "grid.png", np.full((8, 12, 3), 0.5, np.float32))


def test_proxy_runs_are_reported_under_proxy_names(tmp_path) -> None:
    for name in SPECS:
        make_run(tmp_path, name, official=False, ssim=0.5)
    runs = load_runs(tmp_path, SPECS)
    md = format_markdown(runs).splitlines()
    assert len(md) == 2 + len(SPECS)
    assert "artfid_proxy ↓" in md[0] and "short_lpips_proxy_vgg ↓" in md[0]
    assert "| artfid " not in md[0] and "short_lpips ↓" not in md[0]
    assert "900.00" in md[2] and "1.50" in md[2]  # stylize minutes from the info record
    assert runs[0].stylize["vgg_weights"]["sha256"] == "ab"  # the full record, not only the numeric metric
    assert format_table(runs).splitlines()[0].startswith("run")


def test_official_names_only_with_official_values(tmp_path) -> None:
    make_run(tmp_path, "a_fast", official=True, ssim=0.6)
    cols = format_markdown(load_runs(tmp_path, {"a_fast": SPECS["a_fast"]})).splitlines()[0]
    assert "artfid ↓" in cols and "short_lpips ↓" in cols and "proxy" not in cols


def test_ablation_groups_runs_that_differ_only_in_method(tmp_path) -> None:
    for name in SPECS:
        make_run(tmp_path, name, official=False, ssim=0.5)
    groups = ablation_groups(load_runs(tmp_path, SPECS))
    assert [[r.name for r in g] for g in groups] == [["a_fast", "a_nnfm"]]


def test_html_is_self_contained_and_png_summary_written(tmp_path) -> None:
    for name in SPECS:
        make_run(tmp_path, name, official=False, ssim=0.4)
    runs = load_runs(tmp_path, SPECS)
    page = render_html(runs)
    assert page.count("data:image/png;base64,") >= len(SPECS) and "src=\"http" not in page
    assert all(name in page for name in SPECS) and "Ablation: fast, nnfm" in page
    summary_png(runs, tmp_path / "summary.png")
    assert (tmp_path / "summary.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_missing_run_is_a_clear_error(tmp_path) -> None:
    with pytest.raises(InputError, match="run `dvc repro` first"):
        load_runs(tmp_path, {"nope": SPECS["a_fast"]})
    with pytest.raises(InputError, match="no experiments"):
        load_runs(tmp_path, {})


def test_style_legend_pairs_each_label_colour_with_its_painting():
    """compositional/semantic grids show every label's painting (or painting region), not the first."""
    import numpy as np

    from abcgs.viz import style_legend

    red = np.zeros((40, 60, 3), np.uint8)
    red[..., 0] = 255
    blue = np.zeros((40, 60, 3), np.uint8)
    blue[..., 2] = 255
    region = np.zeros((40, 60), bool)
    region[:, :30] = True
    panel = style_legend([(np.array([0, 255, 0], np.uint8), red, None), (np.array([255, 255, 0], np.uint8), blue, region)],
                         height=100)
    assert panel.shape[0] == 100 and panel.dtype == np.uint8
    top, bottom = panel[:49], panel[51:]
    assert (top[5, 2] == [0, 255, 0]).all() and (bottom[5, 2] == [255, 255, 0]).all()  # swatches
    pure_red = lambda a: (a[..., 0] > 250) & (a[..., 1] < 5) & (a[..., 2] < 5)  # noqa: E731
    pure_blue = lambda a: (a[..., 2] > 250) & (a[..., 0] < 5) & (a[..., 1] < 5)  # noqa: E731
    assert pure_red(top).any() and not pure_blue(top).any()  # first painting only above
    assert pure_blue(bottom).any() and not pure_red(bottom).any()
    # the region half of the second painting is kept, the rest dimmed (greyish blue)
    row = bottom[10, 20:]
    assert pure_blue(row).sum() > 5 and ((row[:, 0] > 150) & (row[:, 0] < 250) & (row[:, 2] > 200)).sum() > 5
    no_swatch = style_legend([(None, red, None)], height=40)
    assert (no_swatch[5, 2] == [255, 0, 0]).all()


def test_tables_show_the_consistency_floor_beside_the_rmse(tmp_path) -> None:
    from abcgs.io.metrics import read_record
    from abcgs.report import results_markdown, table_rows

    make_run(tmp_path, "a_fast", official=False, ssim=0.5)
    make_run(tmp_path, "b_fast", official=False, ssim=0.5)
    rec = read_record(tmp_path / "a_fast" / "eval.json") | {"short_rmse_floor": 0.031, "long_rmse_floor": 0.047,
                                                            "short_valid_fraction": 0.9}
    write_metrics(tmp_path / "a_fast" / "eval.json", rec)
    runs = load_runs(tmp_path, {k: SPECS[k] for k in ("a_fast", "b_fast")})
    cols, rows = table_rows(runs)
    assert cols[cols.index("short_rmse ↓") + 1] == "short floor" and cols[cols.index("long_rmse ↓") + 1] == "long floor"
    assert "short_lpips_proxy_vgg ↓" in cols  # not a floor or valid-fraction key
    assert rows[0][cols.index("short floor")] == "0.031" and rows[1][cols.index("long floor")] == "–"
    md = results_markdown(runs).splitlines()
    assert "unstylized floor" in md[0] and "0.0310 / 0.0470" in md[2]
