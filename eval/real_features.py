"""Real VGG features for the style-loss benchmarks: a painting's and the renders' of fitted scenes.

Shared by ``eval/bench_knn_recall.py`` and ``eval/bench_fast_precision.py``. The features are the stylization's:
relu3_1..3 (``params.stylize.layers``) of the render ×0.5 and of the painting at ``stylize.style_height``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch

from abcgs.cameras import Camera
from abcgs.gaussians import render
from abcgs.io.ply import read_ply
from abcgs.params import Params
from abcgs.style import knn
from abcgs.style.matching import load_style
from abcgs.style.vgg import VGG16Features, downsample_half, extract_features
from abcgs.style.weights import resolve_vgg16


def stylization_vgg(params: Params) -> VGG16Features:
    """The VGG-16 extractor of ``params``'s stylization (weights as ``params.vgg`` resolves them)."""
    sd, info = resolve_vgg16(params.vgg)
    return VGG16Features(sd, params.stylize.layers, feature_scale=info.feature_scale)


@torch.no_grad()
def style_features(vgg: VGG16Features, params: Params, style_path: Path) -> knn.StyleFeatures:
    """The painting's features ``(C, N_s)``, prepared once as a stylization run does."""
    sp = params.stylize
    img = load_style(str(style_path), sp.style_height)
    f_s = extract_features(vgg, torch.from_numpy(img).permute(2, 0, 1)[None], sp.layers)[0]
    return knn.StyleFeatures.of(f_s.reshape(f_s.shape[0], -1))


@torch.no_grad()
def rendered_features(
    vgg: VGG16Features, params: Params, ply: str | Path, cameras: Sequence[Camera]
) -> list[torch.Tensor]:
    """The features ``(C, N_r)`` float32 (contiguous) of the scene in ``ply`` seen from each of ``cameras``."""
    model = read_ply(ply)
    out = []
    for cam in cameras:
        img = render(model, cam)[0].clamp(0, 1).permute(2, 0, 1)[None]
        f = extract_features(vgg, downsample_half(img), params.stylize.layers)[0]
        out.append(f.reshape(f.shape[0], -1).contiguous())
    return out
