"""The fit's densification schedule follows the run's length, a schedule that ends on a reset is refused before
any work, and a fit that is broken is refused by the fit stage's check before anything paints it."""

from __future__ import annotations

import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_fit_trainer import make_scene

from abcgs.cameras import Camera, Cameras
from abcgs.fit.outputs import fit_and_save
from abcgs.fit.params import MIN_RECOVERY, MIN_RESET_EVERY, FitParams, StrategyParams
from abcgs.fit.plausibility import FitCheck, FitError, problems, train_sample
from abcgs.fit.strategy import DefaultStrategy
from abcgs.fit.training import fit, make_strategy
from abcgs.scene.params import TinySceneParams
from abcgs.scene.synthetic import ring_cameras
from abcgs.sfm.model import read_scene

REPO = Path(__file__).resolve().parents[1]


def test_the_default_schedule_is_3dgs_at_30000_steps_and_follows_any_length():
    p = FitParams(iterations=30000).strategy_params()
    assert (p.refine_start, p.refine_every, p.refine_stop, p.reset_every) == (500, 100, 15000, 3000)
    for n in (6200, 7000, 9000, 12345, 20000):
        s = FitParams(iterations=n).strategy_params()
        assert s.refine_stop == n // 2  # densify until half the run
        last = s.last_reset(n)
        assert last is not None and last < s.refine_stop  # resets only while densifying
        assert n - last >= MIN_RECOVERY * n and s.reset_every >= MIN_RESET_EVERY
        assert 0 < s.refine_start < s.refine_stop and 10 <= s.refine_every <= 100
    for n in (30, 60, 200, 300, 1000, 1500, 2000, 3000, 6000):  # densifying for under 3DGS's reset interval: none
        s = FitParams(iterations=n).strategy_params()
        assert s.last_reset(n) is None and s.refine_start == min(500, n // 10) and s.refine_stop == n // 2


def test_set_step_fields_are_kept_and_unset_ones_follow_the_length():
    s = FitParams(iterations=3000, strategy={"refine_every": 40}).strategy_params()
    assert s.refine_every == 40 and s.refine_stop == 1500 and s.reset_every == 3000 and s.refine_start == 300
    s = StrategyParams(refine_stop=2000, reset_every=1000).resolved(3000)
    assert (s.refine_stop, s.reset_every, s.last_reset(3000)) == (2000, 1000, 1000)
    # the strategy used directly, without a run length, is 3DGS's reference schedule
    d = DefaultStrategy(StrategyParams(refine_every=7))
    assert (d.params.refine_every, d.params.refine_stop, d.params.reset_every) == (7, 15000, 3000)


@pytest.mark.parametrize("iterations,strategy", [
    (3000, {"reset_every": 3000, "refine_stop": 15000}),  # 3DGS's fixed steps: a reset on the last step
    (3000, {"reset_every": 2800, "refine_stop": 3000}),  # in the last 10 %
    (12000, {"reset_every": 3000, "refine_stop": 15000}),  # 3DGS's steps on a shorter run: a reset at 12000 of 12000
])
def test_a_schedule_that_resets_near_the_end_is_refused(iterations, strategy):
    with pytest.raises(ValueError, match=r"last opacity reset falls on step \d+ of \d+.*set strategy.refine_stop"):
        FitParams(iterations=iterations, strategy=strategy)
    # unless nothing densifies: then no reset happens
    FitParams(iterations=iterations, strategy=strategy, densify=False)


def test_preflight_refuses_a_late_reset_in_one_line_naming_the_fields_and_the_fix(tmp_path):
    params = yaml.safe_load((REPO / "params.yaml").read_text())
    params["data"]["scenes"]["tiny"]["fit"] = {"iterations": 3000, "strategy": {"reset_every": 2900,
                                                                             "refine_stop": 3000}}
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params))
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "abcgs.preflight", str(path)], capture_output=True, text=True,
                          timeout=60, cwd=REPO)
    assert time.perf_counter() - t0 < 10
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    err = proc.stderr.strip()
    assert "data.scenes.tiny.fit: the last opacity reset" in err and "step 2900 of 3000" in err
    assert "strategy.reset_every 2900" in err and "set strategy.refine_stop to at most 2400" in err
    # the same run with the schedule left to follow it passes the check
    params["data"]["scenes"]["tiny"]["fit"] = {"iterations": 3000}
    path.write_text(yaml.safe_dump(params))
    assert FitParams.model_validate({**params["fit"], "iterations": 3000}).strategy_params().last_reset(3000) is None
    # and so does a schedule that keeps its resets and takes the fix the message names
    fixed = FitParams.model_validate({**params["fit"], "iterations": 3000,
                                      "strategy": {"reset_every": 1000, "refine_stop": 2400}})
    assert fixed.strategy_params().last_reset(3000) == 2000


def _check(**kw) -> FitCheck:
    base = dict(heldout_psnr=25.0, train_psnr=28.0, heldout_views=["000.png"], train_views=["001.png"],
                min_psnr=15.0, max_psnr_gap=12.0, reset_share=0.01, problems=[])
    return FitCheck(**{**base, **kw})


def test_the_verdict_names_the_floor_the_gap_and_the_likely_cause():
    assert problems(_check()) == []
    low = problems(_check(heldout_psnr=7.0, train_psnr=8.0, reset_share=0.97))
    assert len(low) == 2 and "97% of its Gaussians still have the reset opacity" in low[0]
    assert "under the floor fit.min_psnr = 15 dB; likely causes: the opacity reset above" in low[1]
    cams = problems(_check(heldout_psnr=9.0, train_psnr=30.0))
    assert len(cams) == 2 and "cameras that do not" in cams[0] and "more than fit.max_psnr_gap" in cams[1]
    assert problems(_check(heldout_psnr=None, train_psnr=12.0))[0].startswith("its training views score 12.0 dB")
    assert problems(_check(heldout_psnr=14.0, train_psnr=15.0, min_psnr=0.0)) == []  # the floor turned off
    assert train_sample(list(range(100)), 8) == [0, 14, 28, 42, 57, 71, 85, 99]


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory):
    return make_scene(tmp_path_factory.mktemp("scene"), n_views=9)[0]


def _params(**kw) -> FitParams:
    return FitParams(iterations=300, test_every=4, threads=1, **kw)


def test_a_healthy_fit_passes_and_its_record_says_both_psnrs_and_the_views(small_scene, tmp_path):
    result = fit_and_save(small_scene, _params(), tmp_path / "gs", progress=False)
    record = yaml.safe_load((tmp_path / "gs" / "metrics.json").read_text())
    check = record["check"]
    assert check["problems"] == [] and check["heldout_views"] == ["000.png", "004.png", "008.png"]
    assert check["heldout_psnr"] == pytest.approx(result.heldout.psnr) and check["heldout_psnr"] > 20
    assert check["train_psnr"] > check["heldout_psnr"] - 12 and len(check["train_views"]) == 6


def test_a_fit_whose_opacities_were_reset_after_the_last_step_fails_before_writing(small_scene, tmp_path):
    # the schedule preflight refuses, forced past it: the last reset on the last step, as the old defaults did
    p = _params()
    p = p.model_copy(update={"strategy": p.strategy.model_copy(update={"reset_every": 300, "refine_stop": 1000})})
    with pytest.raises(FitError, match=r"still have the reset opacity: the opacities were reset too near the end"):
        fit_and_save(small_scene, p, tmp_path / "gs", progress=False)
    assert not (tmp_path / "gs" / "point_cloud.ply").exists() and not (tmp_path / "gs" / "metrics.json").exists()


def test_a_fit_on_the_cameras_of_another_scene_fails(tiny_colmap, tmp_path):
    # the tiny scene's photos and points, each view with the pose of the orbit scene's view of that name (its
    # cameras go round the objects, in that scene's frame): a dataset read with another scene's poses
    scene = read_scene(tiny_colmap)
    orbit = ring_cameras(TinySceneParams(layout="orbit"), np.random.default_rng(0))
    cams = [Camera(c.name, c.K, o.viewmat, c.width, c.height) for c, o in zip(scene.cameras, orbit)]
    wrong = replace(scene, cameras=Cameras.from_list(cams))
    with pytest.raises(FitError, match="under the floor fit.min_psnr.*cameras that do not belong"):
        fit_and_save(wrong, _params(), tmp_path / "gs", progress=False)
    assert not (tmp_path / "gs" / "point_cloud.ply").exists()


def test_a_strategy_resolved_for_the_run_never_resets_in_its_last_part(small_scene):
    p = FitParams(iterations=2200, test_every=0, threads=1, strategy={"reset_every": 400})
    resets = [r.step for r in fit(small_scene, p, progress=False, strategy=make_strategy(p, 1.0)).refinements
              if r.opacity_reset]
    assert resets == [400, 800]  # every 400 steps while densifying (until step 1100, half the run)
