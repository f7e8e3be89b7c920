"""End-to-end fit on a tiny synthetic scene: loss falls, held-out PSNR rises, artefacts are written."""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from abcgs.cameras import Camera, Cameras, intrinsics, look_at
from abcgs.errors import InputError, NumericalError
from abcgs.fit.data import load_views
from abcgs.fit.evaluation import evaluate
from abcgs.fit.outputs import fit_and_save
from abcgs.fit.params import FitParams, StrategyParams
from abcgs.fit.training import fit, view_order
from abcgs.gaussians import GaussianModel, render
from abcgs.gaussians.ply import read_ply
from abcgs.io.images import load_image, save_image
from abcgs.types import CalibratedScene

W, H = 48, 36


def make_scene(folder: Path, n: int = 200, n_views: int = 6, seed: int = 0) -> tuple[CalibratedScene, GaussianModel]:
    """``n`` random Gaussians in front of a small arc of cameras, rendered as the ground-truth images.

    The SfM points are the true means with 0.08 noise (scene size ≈ 2) and the colours with 0.1 noise.
    """
    g = torch.Generator().manual_seed(seed)
    means = torch.rand(n, 3, generator=g) * torch.tensor([2.4, 1.8, 1.0]) + torch.tensor([-1.2, -0.9, 3.5])
    gt = GaussianModel(
        means=means,
        quats=torch.randn(n, 4, generator=g),
        log_scales=torch.log(0.04 + 0.1 * torch.rand(n, 3, generator=g)),
        opacity_logits=torch.logit(0.6 + 0.35 * torch.rand(n, generator=g)),
        sh0=(torch.rand(n, 1, 3, generator=g) - 0.5) / 0.28209479177387814,
        shN=torch.zeros(n, 0, 3),
    )
    cams, paths = [], []
    for i in range(n_views):
        a = (i / (n_views - 1) - 0.5) * 0.5
        eye = np.array([3.5 * np.sin(a), 0.1 * np.cos(3 * a), 4.0 - 3.5 * np.cos(a)])
        cam = Camera(f"{i:03d}.png", intrinsics(40.0, W, H), look_at(eye, np.array([0.0, 0.0, 4.0])), W, H)
        with torch.no_grad():
            img, _, _ = render(gt, cam, backend="cpu")
        save_image(folder / cam.name, img.clamp(0, 1).numpy())
        cams.append(cam)
        paths.append(folder / cam.name)
    rng = np.random.default_rng(seed)
    pts = (means.numpy() + rng.normal(0, 0.08, (n, 3))).astype(np.float32)
    rgb = gt.sh0[:, 0].numpy() * 0.28209479177387814 + 0.5
    cols = np.clip(rgb + rng.normal(0, 0.1, (n, 3)), 0, 1).astype(np.float32)
    return CalibratedScene(Cameras.from_list(cams), paths, pts, cols), gt


def small_params(**kw) -> FitParams:
    base = dict(
        iterations=150, backend="cpu", test_every=3, threads=1, lr_means=1.6e-3, lr_means_final=1.6e-5, max_gaussians=400,
        strategy=StrategyParams(refine_start=30, refine_every=30, refine_stop=120, reset_every=10_000),
    )
    base.update(kw)
    return FitParams(**base)


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> CalibratedScene:
    return make_scene(tmp_path_factory.mktemp("scene"))[0]


@pytest.fixture(scope="module")
def fitted(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("fit")
    result = fit_and_save(scene, small_params(eval_every=50), out, progress=False)
    return result, out


def test_fit_reduces_loss_and_improves_heldout(scene, fitted):
    result, _ = fitted
    views = load_views(scene, 1.0, 3)
    assert views.test == [0, 3] and views.train == [1, 2, 4, 5]
    init = GaussianModel.from_points(scene.points, scene.colors)
    before = evaluate(init, [views.cameras[i] for i in views.test], [views.images[i] for i in views.test], "cpu")
    after = result.heldout
    assert [v.name for v in after.views] == ["000.png", "003.png"]
    assert after.psnr > before.psnr + 4.0, (before.psnr, after.psnr)
    assert after.ssim > before.ssim + 0.2, (before.ssim, after.ssim)
    losses = [h["loss"] for h in result.history]
    assert np.mean(losses[-20:]) < 0.5 * np.mean(losses[:20])
    assert len(result.history) == 150 and result.history[-1]["step"] == 150
    assert all(np.diff([h["seconds"] for h in result.history]) >= 0)
    # densification happened and respected the cap
    assert any(r.n_split + r.n_duplicated > 0 for r in result.refinements)
    assert result.model.num_gaussians <= 400
    assert [e["step"] for e in result.eval_history] == [50, 100, 150]


def test_fit_and_save_artefacts(fitted):
    result, out = fitted
    assert sorted(p.name for p in out.iterdir()) == ["heldout_grid.png", "history.csv", "metrics.json", "point_cloud.ply"]
    model = read_ply(out / "point_cloud.ply")
    assert model.num_gaussians == result.model.num_gaussians
    assert torch.equal(model.means, result.model.means)
    m = json.loads((out / "metrics.json").read_text())
    assert m["psnr"] == pytest.approx(result.heldout.psnr)
    assert set(m["per_view"]) == {"000.png", "003.png"} and "ssim" in m["per_view"]["003.png"]
    assert m["n_gaussians"] == model.num_gaussians and m["backend"] == "cpu" and m["seconds"] > 0
    rows = list(csv.DictReader((out / "history.csv").open()))
    assert list(rows[0]) == ["step", "seconds", "loss", "psnr", "n_gaussians"] and len(rows) == 150
    grid = load_image(out / "heldout_grid.png")
    assert grid.shape == (2 * H + 4, 2 * W + 4, 3)  # rows: held-out views; columns: truth | render


def test_fit_is_deterministic(scene):
    params = small_params(iterations=25, strategy=StrategyParams(refine_start=5, refine_every=10, refine_stop=20, reset_every=1000))
    a = fit(scene, params, progress=False)
    b = fit(scene, params, progress=False)
    assert [h["loss"] for h in a.history] == [h["loss"] for h in b.history]
    assert torch.equal(a.model.means, b.model.means)


def test_no_densify_sh_degree_and_no_holdout(scene, tmp_path):
    params = small_params(iterations=12, densify=False, sh_degree=1, sh_degree_interval=5, test_every=0, random_background=True)
    result = fit_and_save(scene, params, tmp_path, progress=False)
    assert result.model.num_gaussians == len(scene.points)
    assert result.model.sh_degree == 1 and result.model.shN.abs().sum() > 0  # band 1 trained after step 5
    assert result.heldout is None and json.loads((tmp_path / "metrics.json").read_text())["psnr"] is None
    assert (tmp_path / "heldout_grid.png").is_file()


def test_view_order_visits_every_training_view_once_per_epoch():
    order = view_order([1, 2, 3, 5, 6], np.random.default_rng(0))
    epochs = [[next(order) for _ in range(5)] for _ in range(4)]
    assert all(sorted(e) == [1, 2, 3, 5, 6] for e in epochs)
    assert len({tuple(e) for e in epochs}) > 1  # a fresh order each epoch
    with pytest.raises(InputError, match="no training views"):
        next(view_order([], np.random.default_rng(0)))


def test_nan_loss_names_step_and_term(scene):
    params = small_params(iterations=5)
    views = load_views(scene, 1.0, params.test_every)
    for i in views.train:
        views.images[i] = views.images[i].clone()
        views.images[i][3, 3, 0] = math.nan
    with pytest.raises(NumericalError, match=r"l1 loss term is nan at step 1"):
        fit(scene, params, progress=False, views=views)


def test_resolution_scale_and_input_errors(scene, tmp_path):
    views = load_views(scene, 0.5, 8)
    assert views.cameras[0].width == 24 and tuple(views.images[0].shape) == (18, 24, 3)
    assert views.test == [0]
    small = tmp_path / "small.png"
    save_image(small, np.zeros((10, 12, 3), np.float32))
    bad = replace(scene, image_paths=scene.image_paths[:2] + (small,) + scene.image_paths[3:])
    with pytest.raises(InputError, match="12x10 but its camera 002.png is 48x36"):
        load_views(bad)
    with pytest.raises(ValueError):
        FitParams(iterations=10, bogus=1)
    with pytest.raises(ValueError):
        FitParams(test_every=1)
    with pytest.raises(InputError):
        GaussianModel.from_points(np.zeros((0, 3)), np.zeros((0, 3)))


def test_from_points_knn_scale():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3], [10, 10, 10]], np.float32)
    model = GaussianModel.from_points(pts, np.full((5, 3), 0.5, np.float32), sh_degree=2)
    # point 0: neighbours at distances 1, 2, 3 → sqrt(mean(1, 4, 9))
    assert model.scales[0, 0].item() == pytest.approx(math.sqrt(14 / 3), rel=1e-5)
    assert torch.allclose(model.opacities, torch.full((5,), 0.1))
    assert model.shN.shape == (5, 8, 3) and model.sh_degree == 2
    colors, degree = model.colors_or_sh(0)
    assert degree is None and torch.allclose(colors, torch.full((5, 3), 0.5), atol=1e-6)
    assert model.colors_or_sh()[1] == 2
