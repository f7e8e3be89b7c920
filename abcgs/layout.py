"""The pipeline's output layout, and reading a fitted scene back.

Per scene ``S``, colour match ``M`` (``colormatches.M``) and experiment ``E``::

    out/S/colmap/{sparse,images,masks}                                       reconstruct
    out/S/gs/point_cloud.ply                                                 fit
    out/S/masks/{gaussian_labels.npy, views/*.png, overlay.png, masks.json}  masks
    out/S/reference/                                                         reference
    out/S/colormatch/M/{point_cloud.ply, colormatch.json, recolored.png}     colormatch (shared by the E naming M)
    out/E/stylize/{point_cloud.ply, renders/, grid.png, turntable.mp4}       stylize
    out/E/{eval.json, metrics.json, eval_views.csv, eval_consistency.png}    evaluate
"""

from __future__ import annotations

from pathlib import Path

from abcgs.gaussians import GaussianModel
from abcgs.io.ply import read_ply
from abcgs.sfm.model import SceneData, read_colmap_scene


def colormatch_dir(out_root: Path, scene: str, name: str) -> Path:
    """Where stage ``colormatch@<name>`` writes: ``out/<scene>/colormatch/<name>`` (a per-scene output, shared by
    every experiment that names it)."""
    return out_root / scene / "colormatch" / name


def load_scene(out_root: Path, scene_name: str) -> tuple[SceneData, GaussianModel]:
    colmap = out_root / scene_name / "colmap"
    scene = read_colmap_scene(colmap / "sparse", colmap / "images")
    model = read_ply(out_root / scene_name / "gs" / "point_cloud.ply")
    return scene, model
