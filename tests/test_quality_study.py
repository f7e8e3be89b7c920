"""eval/quality_study.py end to end on the embedded tiny scene (a few steps): outputs, table, caching."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from abcgs.errors import InputError
from abcgs.io.images import load_image, save_image
from eval import quality_study


@pytest.fixture
def study_inputs(tiny_scene: Path, tiny_colmap: Path, tmp_path: Path) -> dict:
    styles = tmp_path / "styles"
    styles.mkdir()
    save_image(styles / "paint.jpg", load_image(tiny_scene / "styles" / "paint.png"))
    save_image(styles / "paint2.jpg", load_image(tiny_scene / "styles" / "paint2.png"))
    bench = tmp_path / "bench"
    shutil.copytree(tiny_colmap, bench / tiny_scene.name / "colmap")  # the reconstruction is shared, the fit is made
    return {"styles": styles, "bench": bench, "work": tmp_path / "work"}


def _argv(tiny_scene: Path, d: dict) -> list[str]:
    return ["--scene", str(tiny_scene), "--style-dir", str(d["styles"]), "--styles", "paint,paint2",
            "--ablation-style", "paint2", "--bench-root", str(d["bench"]), "--work", str(d["work"]), "--fit-iterations", "40",
            "--set", "stylize.iterations=3", "--set", "stylize.color_pass_iterations=2", "--set", "colormatch.refit_iterations=2",
            "--set", "evaluate.fid_patch_size=32", "--set", "evaluate.max_views=6", "--set", "evaluate.kid_subsets=10",
            "--set", "evaluate.fps_passes=1", "--views", "0,5", "--crop", "10,10,60,50", "--threads", "1"]


def test_quality_study_runs_every_method_and_caches(tiny_scene: Path, study_inputs: dict, capsys) -> None:
    out = quality_study.main(_argv(tiny_scene, study_inputs))
    work = study_inputs["work"]
    names = sorted(r["name"] for r in out["runs"])
    assert names == sorted(["paint__fast", "paint__nnfm", "paint2__fast", "paint2__nnfm", "paint2__fast_authors",
                            "paint2__knnfm", "paint2__gram", "paint__colormatch", "paint2__colormatch",
                            "paint2__original"])
    authors = next(r for r in out["runs"] if r["name"] == "paint2__fast_authors")
    assert authors["stylize_params"]["fast"]["cosine"] == "channel"
    assert authors["stylize_params"]["lr_preset"] == "authors_code" and authors["stylize_params"]["lr_means"] == 0.0
    by = {r["name"]: r for r in out["runs"]}
    # the reference rows stylize nothing; the unstylized scene compared with itself has SSIM 1
    assert by["paint2__original"]["metrics"]["ssim"] == pytest.approx(1.0, abs=1e-6)
    assert by["paint2__colormatch"]["stylize_seconds"] == 0.0 and by["paint2__colormatch"]["metrics"]["ssim"] < 1.0
    ref_dirs = list((work / "runs").glob("paint2__colormatch-*"))
    assert len(ref_dirs) == 1 and (ref_dirs[0] / "run.json").is_file()
    assert not (ref_dirs[0] / "point_cloud.ply").exists()  # the start already lies in the colour-match cache
    for r in out["runs"]:
        m = r["metrics"]
        assert 0.0 < m["ssim"] <= 1.0 and np.isfinite(m["gram_distance"]) and np.isfinite(m["kid_tf_inception"])
        assert r["stylize_params"]["iterations"] == 3 and r["stylize_params"]["color_pass_iterations"] == 2
    table = (work / "table.md").read_text()
    assert table.count("| paint2 |") == 7 and table.count("| paint |") == 3
    assert "FAST beats NNFM" in table and "mean SSIM" in table
    assert "measurement floor" in table and "colour match only → FAST" in table
    fig = load_image(work / "figure_paint2.png")
    fig1 = load_image(work / "figure_paint.png")
    assert fig.shape[1] > fig1.shape[1]  # 5 methods + the start vs 2 + the start, same height per row
    overview = load_image(work / "figure_overview.png")  # one row per painting: original, start, FAST, NNFM, painting
    assert overview.shape[0] >= 2 * 120 and overview.shape[1] > overview.shape[0]
    assert json.loads((work / "study.json").read_text())["acceptance"] == out["acceptance"]
    # a second call finds every run in the cache and does no stylization
    capsys.readouterr()
    again = quality_study.main(_argv(tiny_scene, study_inputs))
    assert "10 runs (10 cached)" in capsys.readouterr().out
    assert [r["metrics"]["ssim"] for r in again["runs"]] == [r["metrics"]["ssim"] for r in out["runs"]]


def test_quality_study_rejects_bad_arguments(tiny_scene: Path, study_inputs: dict) -> None:
    argv = _argv(tiny_scene, study_inputs)
    with pytest.raises(InputError, match="ablation-style"):
        quality_study.main(argv + ["--ablation-style", "nope"])
    with pytest.raises(InputError, match="does not exist"):
        quality_study.main([a if a != "paint,paint2" else "paint2,missing" for a in argv])
    with pytest.raises(Exception, match="iteratons"):
        quality_study.main(argv + ["--set", "stylize.iteratons=3"])
