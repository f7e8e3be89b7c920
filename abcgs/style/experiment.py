"""Glue for the stylization stages: load what an experiment needs and write what it produces.

Layout (per scene ``S``, colour match ``M`` = ``colormatches.M`` and experiment ``E``):

    out/S/colmap/{sparse,images,masks}        reconstruct
    out/S/gs/point_cloud.ply                   fit
    out/S/masks/{gaussian_labels.npy, views/*.png, overlay.png, masks.json}   masks
    out/S/colormatch/M/{point_cloud.ply, colormatch.json, recolored.png}     colormatch (shared by E's naming M)
    out/E/stylize/{point_cloud.ply, renders/, grid.png, turntable.mp4, ...}   stylize
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.io.images import load_labels
from abcgs.io.ply import read_ply
from abcgs.params import Params
from abcgs.sfm.colmap import SceneData, read_colmap_scene
from abcgs.style.matching import ExperimentParams, MatchingGroup, TransferSpec, build_groups
from abcgs.style.vgg import VGG16Features
from abcgs.style.weights import WeightsInfo, resolve_vgg16

log = logging.getLogger(__name__)


def experiment(params: Params, name: str) -> ExperimentParams:
    if name not in params.experiments:
        raise InputError(f"experiment {name!r} is not in params.yaml experiments (known: {', '.join(params.experiments)})")
    exp = params.experiments[name]
    if exp.scene not in params.data.scenes:
        raise InputError(f"experiment {name!r} names scene {exp.scene!r}, not in data.scenes ({', '.join(params.data.scenes)})")
    return exp


def colormatch_spec(params: Params, name: str) -> TransferSpec:
    """``colormatches.<name>``: the scene, transfer type and painting(s) of a colour-matched start."""
    if name not in params.colormatches:
        raise InputError(f"colour match {name!r} is not in params.yaml colormatches "
                         f"(known: {', '.join(params.colormatches) or 'none'})")
    return params.colormatches[name]


def colormatch_dir(out_root: Path, scene: str, name: str) -> Path:
    """Where stage ``colormatch@<name>`` writes: ``out/<scene>/colormatch/<name>`` (a per-scene output, shared by
    every experiment that names it)."""
    return out_root / scene / "colormatch" / name


def load_vgg(params: Params) -> tuple[VGG16Features, WeightsInfo]:
    sd, info = resolve_vgg16(params.vgg)
    vgg = VGG16Features(sd, params.stylize.layers, feature_scale=info.feature_scale)
    log.info("VGG-16 weights: %s (%s, sha256 %s…)", info.source, info.path, info.sha256[:12])
    return vgg, info


@dataclass
class SceneMasks:
    gaussian_labels: torch.Tensor  # (N,)
    view_labels: list[np.ndarray]  # per camera


def load_scene_masks(masks_dir: Path, scene: SceneData, n_gaussians: int) -> SceneMasks:
    labels = torch.from_numpy(np.load(masks_dir / "gaussian_labels.npy")).long()
    if labels.shape[0] != n_gaussians:
        raise InputError(
            f"{masks_dir}/gaussian_labels.npy has {labels.shape[0]} labels but the scene has {n_gaussians} Gaussians; "
            "re-run the masks stage (dvc repro)"
        )
    views = [load_labels(masks_dir / "views" / f"{Path(c.name).stem}.png", expect_hw=(c.height, c.width)) for c in scene.cameras]
    return SceneMasks(labels, views)


def load_groups(params: Params, spec: TransferSpec, vgg: VGG16Features, labels: torch.Tensor) -> list[MatchingGroup]:
    present = {int(v) for v in torch.unique(labels)} - {0}
    return build_groups(
        spec, params.data.styles, params.data.style_masks, present, vgg,
        style_height=params.stylize.style_height, isolation=params.isolation, layers=params.stylize.layers,
    )


def load_scene(out_root: Path, scene_name: str) -> tuple[SceneData, GaussianModel]:
    colmap = out_root / scene_name / "colmap"
    scene = read_colmap_scene(colmap / "sparse", colmap / "images")
    model = read_ply(out_root / scene_name / "gs" / "point_cloud.ply")
    return scene, model
