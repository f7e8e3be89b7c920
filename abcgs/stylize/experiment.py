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
from abcgs.features.params import ExperimentParams, IsolationParams, TransferSpec, VggWeightsParams
from abcgs.features.vgg import VGG16Features
from abcgs.features.weights import WeightsInfo, resolve_vgg16
from abcgs.gaussians import FITTED_ROW, GaussianModel, read_fitted_rows
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


def check_label_weights(name: str, exp: ExperimentParams, labels: torch.Tensor, masks_dir: Path) -> None:
    """The labels ``experiments.<name>`` gives a λ of their own are among the Gaussians' ``labels`` (cheap, before
    any work): a λ on a label no Gaussian holds would change nothing, silently."""
    present = {int(v) for v in labels.unique()} - {0}
    unknown = sorted(exp.label_weighted - present)
    if unknown:
        raise InputError(f"experiments.{name}: content_weights / structure_weights name label(s) {unknown}, which the "
                         f"Gaussians' labels ({masks_dir}) do not hold (labels present: {sorted(present)}); weight "
                         "present labels or paint those")


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


def read_colormatch(folder: Path, name: str, n_fitted: int) -> GaussianModel:
    """The colour-matched Gaussians of stage ``colormatch@<name>`` (its output ``folder``), each with its row in the
    fitted scene of ``n_fitted`` Gaussians (:data:`~abcgs.gaussians.FITTED_ROW`); a clear error when the stage has not
    run or its files do not belong together."""
    d = ColorMatchDir(folder)
    if not d.ply.is_file() or not (d.fitted_rows.exists() or d.fitted_rows.is_symlink()):
        raise InputError(f"{d.root} has no point_cloud.ply and fitted_rows.npy: run the colour match first "
                         f"(dvc repro colormatch@{name})")
    model = read_ply(d.ply)
    # the guarded reader: a FIFO, a link to /dev/zero, a pickle or a header of 10^10 rows is one line, never read
    rows = read_fitted_rows(d.fitted_rows, model.num_gaussians, n_fitted,
                            fix=f"re-run the colour match (dvc repro colormatch@{name})")
    model.attributes[FITTED_ROW] = torch.from_numpy(rows)
    return model
