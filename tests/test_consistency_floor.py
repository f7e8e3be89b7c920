"""eval/studies/consistency_floor.py on the tiny scene: the flow vs depth-correspondence warp error table."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.gaussians.ply import write_ply
from abcgs.sfm.model import read_scene
from eval.studies import consistency_floor


def test_floor_rows_and_a_view_inconsistent_scene_scores_higher(tiny_colmap: Path, tmp_path: Path) -> None:
    scene = read_scene(tiny_colmap)
    model = GaussianModel.from_points(scene.points, scene.colors, init_opacity=0.95)
    model.log_scales = model.log_scales + math.log(3.0)  # cover the surfaces so that alpha > 0.95 somewhere
    write_ply(tmp_path / "scene.ply", model)
    noisy = model.detach()
    gen = torch.Generator().manual_seed(0)
    noisy.sh0 = torch.randn(noisy.sh0.shape, generator=gen) * 2.0  # per-Gaussian colours: texture, blended per view
    write_ply(tmp_path / "noisy.ply", noisy)
    out = consistency_floor.main(["--colmap", str(tiny_colmap), "--scene-ply", str(tmp_path / "scene.ply"),
                                  "--ply", f"same={tmp_path / 'scene.ply'}", "--ply", f"noisy={tmp_path / 'noisy.ply'}",
                                  "--json", str(tmp_path / "floor.json")])
    floor, same, nz = out["rows"]
    for key in ("short_rmse_flow", "long_rmse_flow", "short_rmse_depth", "long_rmse_depth"):
        assert np.isfinite(floor[key]) and floor[key] == same[key]
    assert nz["short_rmse_depth"] > floor["short_rmse_depth"] and nz["short_rmse_flow"] > floor["short_rmse_flow"]
    assert 0.05 < out["depth_valid_fraction"]["short"] <= 1.0
    assert json.loads((tmp_path / "floor.json").read_text())["rows"][2]["name"] == "noisy"


def test_bad_ply_argument_is_an_error(tiny_colmap: Path, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="name=path"):
        consistency_floor.main(["--colmap", str(tiny_colmap), "--scene-ply", "x.ply", "--ply", "nope"])
