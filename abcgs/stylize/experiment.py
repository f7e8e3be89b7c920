"""What the colour-match and stylization stages load for one experiment: scene, masks, matching groups, VGG
(paths: :mod:`abcgs.layout`)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from abcgs.errors import InputError
from abcgs.features.matching import ExperimentParams, MatchingGroup, TransferSpec, build_groups
from abcgs.features.vgg import VGG16Features
from abcgs.features.weights import WeightsInfo, resolve_vgg16
from abcgs.gaussians import GaussianModel
from abcgs.io.images import load_labels
from abcgs.io.ply import read_ply
from abcgs.layout import ColorMatchDir

if TYPE_CHECKING:  # the stages hand a view of their own sections
    from abcgs.params import Params

log = logging.getLogger(__name__)


def experiment(params: Params, name: str) -> ExperimentParams:
    """``experiments.<name>`` (the schema has checked that its colour match and scene exist and agree)."""
    return params.experiments[name]


def colormatch_spec(params: Params, name: str) -> TransferSpec:
    """``colormatches.<name>``: the scene, transfer type and painting(s) of a colour-matched start."""
    return params.colormatches[name]


def load_vgg(params: Params, device: torch.device | str = "cpu") -> tuple[VGG16Features, WeightsInfo]:
    """The VGG-16 feature extractor of ``stylize.layers`` on ``device``, and its weights' provenance."""
    sd, info = resolve_vgg16(params.vgg)
    vgg = VGG16Features(sd, params.stylize.layers, feature_scale=info.feature_scale).to(device)
    log.info("VGG-16 weights: %s (%s, sha256 %s…)", info.source, info.path, info.sha256[:12])
    return vgg, info


def check_bindings(params: Params, name: str, spec: TransferSpec, labels: torch.Tensor, labels_file: Path) -> None:
    """The labels colour match ``name`` binds exist among the Gaussians' ``labels`` (the masks stage's, read from
    ``labels_file``) and in its painting's label map (:meth:`TransferSpec.check_labels`); cheap, before any work."""
    present = {int(v) for v in torch.unique(labels)} - {0}
    regions, source = None, ""
    if spec.transfer == "semantic" and spec.style in params.data.style_masks:
        source = params.data.style_masks[spec.style]
        regions = {int(v) for v in np.unique(load_labels(source))} - {0}
    spec.check_labels(name, present, f"the Gaussians' labels ({labels_file})", regions, source)


def load_groups(params: Params, spec: TransferSpec, vgg: VGG16Features, labels: torch.Tensor) -> list[MatchingGroup]:
    present = {int(v) for v in torch.unique(labels)} - {0}
    return build_groups(
        spec, params.data.styles, params.data.style_masks, present, vgg,
        style_height=params.stylize.style_height, isolation=params.isolation, layers=params.stylize.layers,
    )


def read_colormatch(folder: Path, name: str) -> GaussianModel:
    """The colour-matched Gaussians of stage ``colormatch@<name>`` (its output ``folder``), with a clear error when
    it has not run."""
    ply = ColorMatchDir(folder).ply
    if not ply.is_file():
        raise InputError(f"{ply} is missing: run the colour match first (dvc repro colormatch@{name})")
    return read_ply(ply)

