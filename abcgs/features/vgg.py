"""VGG-16 feature extractor in plain torch (no torchvision), torchvision-compatible layout.

The network is ``features`` of torchvision's ``vgg16`` truncated after the deepest requested layer,
with the same module indices (conv layers at 0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28; ReLUs one
after each; max-pools at 4, 9, 16, 23, 30), so a torchvision state dict (``features.<i>.weight``)
loads unchanged.

Input convention: RGB in ``[0, 1]``, ``(B, 3, H, W)`` float32. The module applies torchvision's
ImageNet normalisation (mean ``[0.485, 0.456, 0.406]``, std ``[0.229, 0.224, 0.225]``) itself. Weights
trained on another convention (the Oxford/Keras caffe-style BGR 0–255 input) are converted to this one
by :mod:`abcgs.features.weights`, which folds the difference into ``conv1_1``.

Output features are multiplied by ``feature_scale`` (from :class:`abcgs.features.weights.WeightsInfo`), so
activations of different weight sources have comparable magnitudes (1.0 for torchvision's weights).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from abcgs.errors import InputError

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

# torchvision "D" configuration: channel counts, "M" = 2x2 max-pool.
_CFG: tuple[int | str, ...] = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M")


def _layer_table() -> tuple[dict[str, int], dict[str, int]]:
    """``conv{b}_{i}`` / ``relu{b}_{i}`` / ``pool{b}`` → (torchvision ``features`` index, channels)."""
    index: dict[str, int] = {}
    channels: dict[str, int] = {}
    idx, block, conv, ch = 0, 1, 1, 3
    for v in _CFG:
        if v == "M":
            index[f"pool{block}"], channels[f"pool{block}"] = idx, ch
            idx += 1
            block, conv = block + 1, 1
        else:
            ch = int(v)
            index[f"conv{block}_{conv}"], channels[f"conv{block}_{conv}"] = idx, ch
            index[f"relu{block}_{conv}"], channels[f"relu{block}_{conv}"] = idx + 1, ch
            idx += 2
            conv += 1
    return index, channels


LAYER_INDEX, LAYER_CHANNELS = _layer_table()
"""Layer name → index in ``features`` (e.g. ``relu3_1`` → 11, ``relu3_3`` → 15) and → channel count."""
CONV_INDICES: tuple[int, ...] = tuple(i for n, i in LAYER_INDEX.items() if n.startswith("conv"))
"""The 13 conv indices: 0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28."""
DEFAULT_LAYERS: tuple[str, ...] = ("relu3_1", "relu3_2", "relu3_3")
"""The authors' choice: conv3 block, concatenated → 768 channels."""


def feature_channels(layers: Sequence[str]) -> int:
    """Total channels of the concatenation of ``layers`` (768 for :data:`DEFAULT_LAYERS`)."""
    _check_layers(layers)
    return sum(LAYER_CHANNELS[n] for n in layers)


def _check_layers(layers: Sequence[str]) -> None:
    if len(layers) == 0:
        raise InputError("VGG layer list is empty; use e.g. ['relu3_1', 'relu3_2', 'relu3_3']")
    bad = [n for n in layers if n not in LAYER_INDEX]
    if bad:
        raise InputError(f"unknown VGG-16 layer(s) {bad}; valid names: {', '.join(LAYER_INDEX)}")


def _build_features(last_index: int) -> nn.Sequential:
    mods: list[nn.Module] = []
    in_ch = 3
    for v in _CFG:
        if v == "M":
            mods.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            mods.append(nn.Conv2d(in_ch, int(v), kernel_size=3, padding=1))
            mods.append(nn.ReLU(inplace=False))
            in_ch = int(v)
        if len(mods) > last_index:
            break
    return nn.Sequential(*mods[: last_index + 1])


class VGG16Features(nn.Module):
    """Frozen VGG-16 ``features`` truncated after the deepest of ``layers``.

    ``forward(img)`` takes RGB ``(B, 3, H, W)`` in ``[0, 1]`` and returns ``{layer: (B, C_l, h_l, w_l)}``
    for every requested layer, each multiplied by ``feature_scale``. Parameters do not require grad, but
    gradients flow to the input.

    The convolutions run in channels-last memory layout unless ``channels_last=False`` (oneDNN's faster
    path on CPU; ``eval/bench/vgg.py`` times both); the returned maps are in the usual contiguous layout.
    """

    def __init__(
        self,
        state_dict: Mapping[str, torch.Tensor],
        layers: Sequence[str] = DEFAULT_LAYERS,
        *,
        feature_scale: float = 1.0,
        channels_last: bool = True,
    ) -> None:
        super().__init__()
        _check_layers(layers)
        self.memory_format = torch.channels_last if channels_last else torch.contiguous_format
        self.layers = tuple(layers)
        self.feature_scale = float(feature_scale)
        last = max(LAYER_INDEX[n] for n in self.layers)
        self.features = _build_features(last)
        own = self.features.state_dict()
        wanted = {f"features.{k}": v for k, v in own.items()}
        missing = [k for k in wanted if k not in state_dict]
        if missing:
            raise InputError(f"VGG-16 state dict lacks {missing[:4]}{'…' if len(missing) > 4 else ''}")
        for key, ref in wanted.items():
            src = state_dict[key]
            if tuple(src.shape) != tuple(ref.shape):
                raise InputError(f"VGG-16 state dict entry {key} has shape {tuple(src.shape)}, expected {tuple(ref.shape)}")
        self.features.load_state_dict({k[len("features."):]: state_dict[k].float() for k in wanted})
        for p in self.parameters():
            p.requires_grad_(False)
        self.features.to(memory_format=self.memory_format)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)
        self._take = {LAYER_INDEX[n]: n for n in self.layers}
        self.eval()

    @property
    def device(self) -> torch.device:
        """Where the weights are (inputs must be there too)."""
        return self.mean.device

    def train(self, mode: bool = True) -> VGG16Features:  # always eval: no dropout/BN anyway
        return super().train(False)

    def forward(self, img: torch.Tensor) -> dict[str, torch.Tensor]:
        if img.ndim != 4 or img.shape[1] != 3:
            raise InputError(f"VGG input must be (B, 3, H, W) RGB in [0, 1]; got shape {tuple(img.shape)}")
        if img.shape[2] < 4 or img.shape[3] < 4:
            raise InputError(f"VGG input {img.shape[3]}x{img.shape[2]} is too small (need at least 4x4)")
        x = ((img.to(self.mean.dtype) - self.mean) / self.std).contiguous(memory_format=self.memory_format)
        out: dict[str, torch.Tensor] = {}
        for i, mod in enumerate(self.features):
            x = mod(x)
            if i in self._take:
                f = x.contiguous()
                out[self._take[i]] = f * self.feature_scale if self.feature_scale != 1.0 else f
        return out


def extract_features(vgg: VGG16Features, img: torch.Tensor, layers: Sequence[str] | None = None) -> torch.Tensor:
    """Concatenate the requested layers' features along channels → ``(B, ΣC_l, h, w)``.

    ``h, w`` is the spatial size of the first listed layer; other layers are bilinearly resized to it
    when their size differs (never within one conv block, e.g. relu3_1..3 at ``H/4, W/4``). ``layers``
    defaults to the layers ``vgg`` was built for and must be a subset of them.
    """
    layers = tuple(layers) if layers is not None else vgg.layers
    _check_layers(layers)
    absent = [n for n in layers if n not in vgg.layers]
    if absent:
        raise InputError(f"layers {absent} were not requested when the VGG extractor was built ({vgg.layers})")
    feats = vgg(img)
    hw = feats[layers[0]].shape[-2:]
    maps = [
        f if f.shape[-2:] == hw else F.interpolate(f, size=tuple(hw), mode="bilinear", align_corners=False)
        for f in (feats[n] for n in layers)
    ]
    return torch.cat(maps, dim=1)


def downsample_half(img: torch.Tensor) -> torch.Tensor:
    """Bilinear ×0.5 resize of ``(B, C, H, W)`` (the authors' pre-VGG downsampling of renders).

    For even sizes this equals 2×2 box averaging; gradients flow through it.
    """
    if img.ndim != 4:
        raise InputError(f"downsample_half expects (B, C, H, W); got shape {tuple(img.shape)}")
    return F.interpolate(img, scale_factor=0.5, mode="bilinear", align_corners=False, antialias=False)


def random_state_dict(seed: int = 0, last_layer: str = "relu3_3") -> dict[str, torch.Tensor]:
    """Kaiming-initialised random VGG-16 weights up to ``last_layer`` (for tests and benchmarks only).

    The activation scale is roughly that of torchvision's weights on normalised input (units).
    """
    _check_layers([last_layer])
    gen = torch.Generator().manual_seed(seed)
    seq = _build_features(LAYER_INDEX[last_layer])
    sd: dict[str, torch.Tensor] = {}
    for i, mod in enumerate(seq):
        if isinstance(mod, nn.Conv2d):
            fan_in = mod.in_channels * 9
            sd[f"features.{i}.weight"] = torch.randn(mod.weight.shape, generator=gen) * (2.0 / fan_in) ** 0.5
            sd[f"features.{i}.bias"] = torch.randn(mod.bias.shape, generator=gen) * 0.01
    return sd
