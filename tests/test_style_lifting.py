"""Mask lifting (ABC-GS Eq. 2), matching groups and the stylization loop's guards, on small synthetic scenes."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch

from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.errors import InputError, NumericalError
from abcgs.features.matching import build_groups, load_style
from abcgs.features.params import ALL_PIXELS, TransferSpec
from abcgs.features.vgg import VGG16Features, random_state_dict
from abcgs.gaussians import GaussianModel
from abcgs.io.images import save_image, save_labels
from abcgs.masks.lifting import lift_labels, one_hot_labels, render_label_map
from abcgs.masks.params import LiftParams
from abcgs.render import rgb_to_sh0
from abcgs.stylize.loop import stylize
from abcgs.stylize.outputs import HISTORY_COLUMNS, write_history
from abcgs.stylize.params import StyleWeights, StylizeCompute, StylizeOptim, StylizeParams

W, H = 48, 36


def _cameras(n: int = 4) -> list[Camera]:
    K = intrinsics(40.0, W, H)
    return [Camera(f"{i:03d}.png", K, look_at(np.array([0.3 * (i - n / 2), 0.1 * i, 0.0]), np.array([0.0, 0.0, 4.0])), W, H)
            for i in range(n)]


def _two_blob_scene(seed: int = 0, separation: float = 0.8, spread: float = 0.35) -> tuple[GaussianModel, torch.Tensor]:
    """Two clusters of small opaque Gaussians, left (label 1) and right (label 2), 4 units in front, their centres
    ``separation`` either side of the axis, ``spread`` the standard deviation across it."""
    g = torch.Generator().manual_seed(seed)
    n = 300
    labels = torch.cat([torch.ones(n // 2), 2 * torch.ones(n // 2)]).long()
    centre = torch.where(labels[:, None] == 1, torch.tensor([-separation, 0.0, 4.0]),
                         torch.tensor([separation, 0.0, 4.0]))
    means = centre + spread * torch.randn(n, 3, generator=g) * torch.tensor([1.0, 1.0, 0.3])
    rgb = torch.where(labels[:, None] == 1, torch.tensor([0.9, 0.2, 0.2]), torch.tensor([0.2, 0.3, 0.9]))
    model = GaussianModel(
        means=means, quats=torch.randn(n, 4, generator=g), log_scales=torch.full((n, 3), np.log(0.08)),
        opacity_logits=torch.full((n,), 2.0), sh0=rgb_to_sh0(rgb)[:, None, :], shN=torch.zeros(n, 0, 3),
    )
    return model, labels


def test_lifting_recovers_known_labels() -> None:
    model, truth = _two_blob_scene()
    cams = _cameras()
    # ground-truth masks: the known per-Gaussian labels rendered into each view
    masks = [render_label_map(model, truth, 2, c) for c in cams]
    lifted = lift_labels(model, cams, masks, 2, LiftParams(min_weight=0.01))
    seen = lifted.weights.sum(1) > 0.01
    assert seen.float().mean() > 0.8
    agree = (lifted.labels[seen] == truth[seen]).float().mean()
    assert agree >= 0.95, f"only {agree:.3f} of the visible Gaussians got their label back"
    # re-rendered masks agree with the input masks on labelled pixels
    for c, m in zip(cams, masks):
        again = render_label_map(model, lifted.labels, 2, c)
        assert (again == m)[m > 0].mean() > 0.95


def test_lifting_from_one_view_labels_the_unmasked_views() -> None:
    model, truth = _two_blob_scene(1)
    cams = _cameras()
    masks = [render_label_map(model, truth, 2, cams[0])]
    lifted = lift_labels(model, cams[:1], masks, 2)
    other = render_label_map(model, lifted.labels, 2, cams[-1])
    expected = render_label_map(model, truth, 2, cams[-1])
    assert (other == expected)[expected > 0].mean() > 0.9


def test_lifting_rejects_bad_masks() -> None:
    model, _ = _two_blob_scene()
    cams = _cameras(1)
    with pytest.raises(InputError, match="is 10x10, the view is 48x36"):
        lift_labels(model, cams, [np.zeros((10, 10), np.int64)], 2)
    with pytest.raises(InputError, match="outside 0..2"):
        one_hot_labels(np.full((3, 3), 5), 2)
    with pytest.raises(InputError, match="no masked views"):
        lift_labels(model, [], [], 2)


@pytest.fixture(scope="module")
def vgg() -> VGG16Features:
    return VGG16Features(random_state_dict(0))


@pytest.fixture
def styles(tmp_path):
    rng = np.random.default_rng(0)
    paint = rng.random((64, 80, 3)).astype(np.float32)
    save_image(tmp_path / "paint.png", paint)
    lab = np.zeros((64, 80), np.int64)
    lab[:, :40] = 1
    lab[:, 40:] = 2
    save_labels(tmp_path / "paint_labels.png", lab)
    save_image(tmp_path / "dot.png", np.zeros((1, 1, 3), np.float32))
    (tmp_path / "broken.png").write_bytes(b"not an image")
    return {"paint": str(tmp_path / "paint.png"), "dot": str(tmp_path / "dot.png"), "broken": str(tmp_path / "broken.png"),
            "labels": str(tmp_path / "paint_labels.png")}


def test_build_groups_for_each_transfer_type(vgg, styles) -> None:
    single = build_groups(TransferSpec(scene="s", style="paint"), styles, {}, {1, 2}, vgg, style_height=64)
    assert len(single) == 1 and single[0].content_label == ALL_PIXELS and single[0].features.shape[0] == 768
    comp = build_groups(TransferSpec(scene="s", transfer="compositional", styles={1: "paint", 2: "paint"}),
                        styles, {}, {1, 2}, vgg, style_height=64)
    assert [g.content_label for g in comp] == [1, 2]
    sem = build_groups(TransferSpec(scene="s", transfer="semantic", style="paint"), styles,
                       {"paint": styles["labels"]}, {1, 2}, vgg, style_height=64)
    assert [g.content_label for g in sem] == [1, 2]
    # the region's pixels only: colour statistics come from that half of the painting
    assert len(sem[0].style_pixels) == 64 * 40


def test_build_groups_errors(vgg, styles) -> None:
    with pytest.raises(InputError, match="at least 8x8"):
        load_style(styles["dot"], 64)
    with pytest.raises(InputError, match="could not be decoded"):
        load_style(styles["broken"], 64)
    with pytest.raises(InputError, match="not in data.styles"):
        build_groups(TransferSpec(scene="s", style="nope"), styles, {}, {1}, vgg)
    with pytest.raises(InputError, match=r"content label\(s\) \[7\]"):
        build_groups(TransferSpec(scene="s", transfer="compositional", styles={7: "paint"}), styles, {}, {1, 2}, vgg)
    with pytest.raises(InputError, match="style label 5 .* has no pixels"):
        build_groups(TransferSpec(scene="s", transfer="semantic", style="paint", binding={1: 5}), styles,
                     {"paint": styles["labels"]}, {1, 2}, vgg, style_height=64)


def test_stylize_reduces_style_loss_and_stops_on_nan(vgg, styles, tmp_path) -> None:
    model, truth = _two_blob_scene(2)
    cams = _cameras(3)
    groups = build_groups(TransferSpec(scene="s", style="paint"), styles, {}, {1, 2}, vgg, style_height=64)
    labels = [np.zeros((H, W), np.int64)] * len(cams)
    params = StylizeParams(optim=StylizeOptim(iterations=12, lr_sh0=0.05, color_pass_iterations=3),
                           compute=StylizeCompute(log_every=1), downsample_render=False, weights=StyleWeights(depth=0.0))
    res = stylize(model, cams, labels, truth, groups, vgg, params, progress=False)
    style = [s.terms["style"] for s in res.history if s.pass_name == "main"]
    assert len(style) == 12 and [s.pass_name for s in res.history][-1] == "color"
    assert [s.step for s in res.history] == list(range(15))  # the colour pass counts on from the main pass
    write_history(tmp_path / "h.csv", res.history)
    rows = list(csv.DictReader((tmp_path / "h.csv").open()))
    assert tuple(rows[0]) == HISTORY_COLUMNS and [int(r["step"]) for r in rows] == list(range(15))
    assert [float(r["style"]) for r in rows[:12]] == pytest.approx(style, rel=1e-5) and rows[-1]["style"] == ""
    assert np.mean(style[-3:]) < np.mean(style[:3])
    assert res.model.num_gaussians == model.num_gaussians
    broken = model.detach()
    broken.sh0[0, 0, 0] = float("nan")
    with pytest.raises(NumericalError, match="(?i)nan"):
        stylize(broken, cams, labels, truth, groups, vgg, params, progress=False)


def test_lr_preset_fills_unset_rates_and_explicit_keys_win() -> None:
    from abcgs.stylize.params import LR_PRESETS

    authors = StylizeOptim(lr_preset="authors_code")
    assert {k: getattr(authors, k) for k in LR_PRESETS["authors_code"]} == LR_PRESETS["authors_code"]
    assert authors.lr_means == 0.0
    mixed = StylizeParams.model_validate({"optim": {"lr_preset": "authors_code", "lr_sh0": 0.02}}).optim
    assert mixed.lr_sh0 == 0.02 and mixed.lr_opacity == LR_PRESETS["authors_code"]["lr_opacity"]
    assert StylizeParams().optim.lr_sh0 == LR_PRESETS["authors_code"]["lr_sh0"] and StylizeParams().optim.lr_means == 0.0
    ours = StylizeOptim(lr_preset="ours")
    assert {k: getattr(ours, k) for k in LR_PRESETS["ours"]} == LR_PRESETS["ours"]
    with pytest.raises(ValueError):
        StylizeOptim(lr_preset="inria")


def test_authors_preset_freezes_means_and_color_pass_freezes_geometry(vgg, styles) -> None:
    """lr 0 leaves a field bit-identical; the colour pass moves colours toward the style palette only."""
    model, truth = _two_blob_scene(3)
    cams = _cameras(3)
    groups = build_groups(TransferSpec(scene="s", style="paint"), styles, {}, {1, 2}, vgg, style_height=64)
    labels = [np.zeros((H, W), np.int64)] * len(cams)
    params = StylizeParams(optim=StylizeOptim(iterations=4, lr_preset="authors_code", color_pass_iterations=0),
                           downsample_render=False, weights=StyleWeights(depth=0.0))
    main = stylize(model, cams, labels, truth, groups, vgg, params, progress=False).model
    assert torch.equal(main.means, model.means)
    assert not torch.equal(main.opacity_logits, model.opacity_logits)  # opacity does learn (lr 0.05)

    both = stylize(model, cams, labels, truth, groups, vgg, params.with_schedule(color_pass_iterations=6),
                   progress=False)
    out = both.model
    for name in ("means", "log_scales", "opacity_logits"):
        assert torch.equal(getattr(out, name), getattr(main, name)), name
    assert both.color_pass_seconds > 0 and [s.pass_name for s in both.history].count("color") >= 1
    # the style (uniform noise) has mean colour ~0.5 per channel: the pass pulls the rendered red/blue blobs toward it
    from abcgs.gaussians import render

    def covered_mean(mdl):
        pix = []
        for cam in cams:
            img, alpha, _ = render(mdl, cam)
            pix.append(img[alpha[..., 0] > 0.5])
        return torch.cat(pix).mean(0)

    target = torch.tensor(groups[0].style_pixels.mean(0), dtype=torch.float32)
    assert (covered_mean(out) - target).abs().sum() < 0.75 * (covered_mean(main) - target).abs().sum()
