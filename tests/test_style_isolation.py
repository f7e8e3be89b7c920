"""Style isolation: zero leak from other regions, the three completions, erosion, region features."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from abcgs.errors import InputError
from abcgs.features import isolation as iso
from abcgs.features.vgg import VGG16Features, random_state_dict

METHODS = ("mirror", "translate", "fill")


@pytest.fixture(scope="module")
def vgg():
    return VGG16Features(random_state_dict(seed=0))


def _scene(seed=0, h=64, w=80):
    rng = np.random.default_rng(seed)
    img = rng.random((h, w, 3)).astype(np.float32)
    labels = np.zeros((h, w), np.int64)
    yy, xx = np.mgrid[0:h, 0:w]
    labels[(yy - 30) ** 2 + (xx - 35) ** 2 < 15**2] = 1  # a disc
    labels[5:12, 50:75] = 2  # a thin bar
    labels[40:60, 60:62] = 3  # 2 px wide strip
    return img, labels


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("label", [1, 2, 3])
def test_zero_leak_image_and_features(vgg, method, label):
    img, labels = _scene()
    mask = labels == label
    out, region = iso.isolate_region(img, mask, method, label=label)
    assert out.shape == img.shape and out.dtype == img.dtype
    assert np.array_equal(out[region], img[region])
    other = img.copy()
    other[~mask] = np.random.default_rng(99).random(((~mask).sum(), 3)).astype(np.float32)
    out2, _ = iso.isolate_region(other, mask, method, label=label)
    assert np.abs(out2 - out).max() == 0.0
    # every output colour is a colour of the region (mirror/translate) or its mean (fill)
    region_colours = {tuple(c) for c in img[mask].tolist()}
    if method == "fill":
        assert np.allclose(out[~mask], img[mask].mean(0), atol=1e-6)
    else:
        assert all(tuple(c) in region_colours for c in out.reshape(-1, 3)[:: 7].tolist())
    f1 = iso.region_features(vgg, img, mask, method, label=label)
    f2 = iso.region_features(vgg, other, mask, method, label=label)
    assert f1.shape[0] == 768 and f1.shape[1] >= 1
    assert torch.equal(f1, f2)


def test_mirror_reflects_across_boundary():
    img = np.zeros((1, 10, 3), np.float32)
    img[0, :5, 0] = np.arange(5)
    mask = np.zeros((1, 10), bool)
    mask[0, :5] = True
    out, _ = iso.isolate_region(img, mask, "mirror")
    # x=5..9 reflect about x=4: 3, 2, 1, 0, then 4 − 5 = −1 is outside → nearest (x=4)
    assert out[0, :, 0].tolist() == [0, 1, 2, 3, 4, 3, 2, 1, 0, 4]


def test_translate_tiles_bounding_box():
    rng = np.random.default_rng(1)
    img = rng.random((30, 40, 3)).astype(np.float32)
    mask = np.zeros((30, 40), bool)
    mask[10:16, 5:13] = True  # full rectangle → tile is exactly the crop
    out, _ = iso.isolate_region(img, mask, "translate")
    crop = img[10:16, 5:13]
    assert np.array_equal(out[16:22, 13:21], crop)
    assert np.array_equal(out[4:10, 5:13], crop)
    assert np.array_equal(out[0:4, 0:5], crop[2:6, 3:8])


def test_erosion_and_errors():
    img, labels = _scene()
    mask = labels == 1
    _, region = iso.isolate_region(img, mask, erode_px=3, label=1)
    assert region.sum() < mask.sum() and not (region & ~mask).any()
    with pytest.raises(InputError, match="label 7.*empty"):
        iso.isolate_region(img, labels == 7, label=7)
    with pytest.raises(InputError, match="label 3.*vanishes"):
        iso.isolate_region(img, labels == 3, erode_px=2, label=3)
    with pytest.raises(InputError, match="unknown style isolation"):
        iso.isolate_region(img, mask, "black")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="must match"):
        iso.isolate_region(img, mask[:10], label=1)
    with pytest.raises(InputError, match="boolean"):
        iso.isolate_region(img, labels, label=1)
    with pytest.raises(InputError, match="RGB"):
        iso.isolate_region(img[..., 0], mask)


def test_downsample_mask_thresholds():
    m = np.zeros((16, 16), bool)
    m[0:4, 0:4] = True  # exactly one 4x4 cell
    m[8, 8] = True  # 1/16 of a cell
    sel = iso.downsample_mask(m, (4, 4))
    assert sel.sum() == 1 and bool(sel[0, 0])
    thin = np.zeros((16, 16), bool)
    thin[5, :] = True  # thinner than a cell: falls back to any coverage
    assert iso.downsample_mask(thin, (4, 4))[1].all()
    feats = torch.arange(2 * 4 * 4, dtype=torch.float32).view(1, 2, 4, 4)
    assert iso.masked_features(feats, sel).tolist() == [[0.0], [16.0]]
