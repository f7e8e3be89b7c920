"""What the colour-match and stylization stages load for one experiment: scene, masks, matching groups, VGG
(paths: :mod:`abcgs.layout`)."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch

from abcgs.errors import InputError
from abcgs.features.matching import build_groups
from abcgs.features.params import IsolationParams, TransferSpec, VggWeightsParams
from abcgs.features.vgg import VGG16Features
from abcgs.features.weights import WeightsInfo, resolve_vgg16
from abcgs.gaussians import GaussianModel
from abcgs.gaussians.ply import read_ply
from abcgs.io.images import load_labels
from abcgs.layout import ColorMatchDir
from abcgs.stylize.params import StylizeParams
from abcgs.types import MatchingGroup

log = logging.getLogger(__name__)


def load_vgg(weights: VggWeightsParams, layers: Sequence[str],
             device: torch.device | str = "cpu") -> tuple[VGG16Features, WeightsInfo]:
    """The VGG-16 feature extractor of ``layers`` (``stylize.layers``) with the weights that ``weights`` (``vgg``)
    names, on ``device``, and the weights' provenance."""
    sd, info = resolve_vgg16(weights)
    vgg = VGG16Features(sd, layers, feature_scale=info.feature_scale).to(device)
    log.info("VGG-16 weights: %s (%s, sha256 %s…)", info.source, info.path, info.sha256[:12])
    return vgg, info


def check_bindings(name: str, spec: TransferSpec, labels: torch.Tensor, labels_file: Path,
                   style_masks: Mapping[str, str]) -> None:
    """The labels colour match ``name`` binds exist among the Gaussians' ``labels`` (the masks stage's, read from
    ``labels_file``) and in its painting's label map (``style_masks``: ``data.style_masks``;
    :meth:`TransferSpec.check_labels`); cheap, before any work."""
    present = {int(v) for v in torch.unique(labels)} - {0}
    regions, source = None, ""
    if spec.transfer == "semantic" and spec.style in style_masks:
        source = style_masks[spec.style]
        regions = {int(v) for v in np.unique(load_labels(source))} - {0}
    spec.check_labels(name, present, f"the Gaussians' labels ({labels_file})", regions, source)


def load_groups(spec: TransferSpec, vgg: VGG16Features, labels: torch.Tensor, styles: Mapping[str, str],
                style_masks: Mapping[str, str], isolation: IsolationParams,
                stylize: StylizeParams) -> list[MatchingGroup]:
    """The matching groups of colour match ``spec`` over the content labels present in ``labels``: the paintings of
    ``styles`` / ``style_masks`` (``data.*``), isolated (``isolation``), at ``stylize.style_height`` and
    ``stylize.layers``."""
    present = {int(v) for v in torch.unique(labels)} - {0}
    return build_groups(
        spec, styles, style_masks, present, vgg,
        style_height=stylize.style_height, isolation=isolation, layers=stylize.layers,
    )


def read_colormatch(folder: Path, name: str) -> GaussianModel:
    """The colour-matched Gaussians of stage ``colormatch@<name>`` (its output ``folder``), with a clear error when
    it has not run."""
    ply = ColorMatchDir(folder).ply
    if not ply.is_file():
        raise InputError(f"{ply} is missing: run the colour match first (dvc repro colormatch@{name})")
    return read_ply(ply)
