"""Real VGG features for the style-loss benchmarks: a painting's and the renders' of fitted scenes.

Shared by ``eval/bench/knn_recall.py`` and ``eval/bench/fast_precision.py``. The features are the stylization's:
relu3_1..3 (``params.stylize.layers``) of the render ×0.5 and of the painting at ``stylize.style_height``.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import torch

from abcgs.cameras import Camera
from abcgs.features import knn
from abcgs.features.matching import load_style
from abcgs.features.vgg import VGG16Features, downsample_half, extract_features
from abcgs.features.weights import resolve_vgg16
from abcgs.gaussians import render
from abcgs.gaussians.ply import read_ply
from abcgs.params import Params, load_params
from abcgs.sfm.model import read_scene


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


def add_feature_arguments(ap: argparse.ArgumentParser) -> None:
    """The benchmarks' shared inputs: ``--colmap``, ``--ply NAME=PATH`` (repeatable), ``--style``, ``--params``,
    ``--views``."""
    ap.add_argument("--colmap", type=Path, required=True, help="reconstruct output (sparse/, images/, scene.json)")
    ap.add_argument("--ply", action="append", required=True, help="NAME=PATH of a scene to render (repeatable)")
    ap.add_argument("--style", type=Path, required=True)
    ap.add_argument("--params", type=Path, default=Path("params.yaml"),
                    help="the VGG weights, the layers and the stylization's params")
    ap.add_argument("--views", type=int, default=0, help="first N views (0 = all)")


@dataclass
class BenchFeatures:
    """What :func:`load_bench_features` gives: the params, the painting's features, the cameras used and every
    (scene name, rendered features) pair, scene by scene and view by view."""

    params: Params
    style: knn.StyleFeatures
    cameras: list[Camera]
    rendered: list[tuple[str, torch.Tensor]]


def load_bench_features(args: argparse.Namespace) -> BenchFeatures:
    """Load the inputs of :func:`add_feature_arguments`: VGG, the painting's features and each scene's renders."""
    params = load_params(args.params)
    vgg = stylization_vgg(params)
    style = style_features(vgg, params, args.style)
    scene = read_scene(args.colmap)
    cameras = list(scene.cameras[: args.views] if args.views else scene.cameras)
    rendered: list[tuple[str, torch.Tensor]] = []
    for item in args.ply:
        name, _, path = item.partition("=")
        rendered += [(name, f) for f in rendered_features(vgg, params, path, cameras)]
    return BenchFeatures(params, style, cameras, rendered)
