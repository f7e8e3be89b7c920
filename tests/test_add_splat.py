"""``python -m abcgs add-scene NAME FOLDER --splat PATH``: every kind of trained splat the README names goes through
the command itself, which renders it against the scene's photos and writes the entry; the fit stage's import of that
entry renders them as the command said, and the export stage gives the scene back under the source's name and format.

The scene is a COLMAP folder whose photos are the renders of a generated degree-3 model (tests/test_splats.py's), its
sparse points every 10th mean; each splat is that model as its tool writes it (test_splats' ``_write``).
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT
from test_add_scene import _run
from test_splats import _write, make_model, render_all, ring_cameras

from abcgs.cameras import Cameras, Distortion
from abcgs.fit.params import FitParams
from abcgs.gaussians.ply import write_ply
from abcgs.io.colmap import write_model
from abcgs.io.images import save_image
from abcgs.params import load_params
from abcgs.sources.read import read_source
from abcgs.splats.exporting import give_back
from abcgs.splats.importing import import_and_save
from abcgs.splats.registry import detect_splat_format, read_splat
from abcgs.splats.validate import check_splat
from abcgs.types import CalibratedScene

REPORTED = re.compile(r"its renders match the photos at ([\d.]+) dB over (\d+) views")

# Route → (the format add-scene detects, the least PSNR of its renders against the photos, dB). The photos are 8-bit
# PNGs of the model's renders, so a lossless route renders them at ~61 dB; the lossy ones at their codec's bound
# (docs/SPLATS.md: supersplat 48, spz 38); .splat has no SH bands, so the view-dependent part is missing (21.5 dB).
ROUTES = {"inria_folder": ("inria", 55.0), "gsplat_ckpt": ("gsplat_ckpt", 55.0),
          "splatfacto_ply": ("splatfacto", 55.0), "splatfacto_folder": ("splatfacto", 55.0), "ply": ("ply", 55.0),
          "supersplat": ("supersplat", 45.0), "splat": ("splat", 20.0), "spz": ("spz", 35.0)}


@pytest.fixture
def params_file(tmp_path: Path) -> Path:
    """A copy of the repository's params file (and dvc.yaml, which the tiny scene's entry needs), as add-scene edits."""
    for name in ("params.yaml", "dvc.yaml"):
        shutil.copy(REPO_ROOT / name, tmp_path / name)
    return tmp_path / "params.yaml"


@pytest.fixture(scope="module")
def colmap_scene(tmp_path_factory) -> tuple[Path, CalibratedScene, object]:
    """``(folder, scene, model)``: a COLMAP folder (``images/``, ``sparse/0`` with PINHOLE cameras and points) whose
    photos are ``model``'s renders, and the same scene as test_splats' ``_write`` takes it."""
    model, cams = make_model(), ring_cameras()
    folder = tmp_path_factory.mktemp("splat_routes") / "garden"
    paths = []
    for cam, img in zip(cams, render_all(model, cams)):
        save_image(folder / "images" / cam.name, img.numpy())
        paths.append(folder / "images" / cam.name)
    pts = model.means[::10].numpy().astype(np.float32)
    write_model(folder / "sparse" / "0", Cameras.from_list(cams), pts)
    return folder, CalibratedScene(Cameras.from_list(cams), paths, pts, np.full_like(pts, 0.5)), model


def _splat(route: str, scene: CalibratedScene, model, root: Path) -> Path:
    """The splat of ``route`` as its tool leaves it (a folder for INRIA's output and splatfacto's exports)."""
    if route == "ply":
        write_ply(root / "point_cloud.ply", model)
        return root / "point_cloud.ply"
    written = _write(route.removesuffix("_ply").removesuffix("_folder"), model, scene, root)
    return written.parent if route == "splatfacto_folder" else written


@pytest.mark.parametrize("route", list(ROUTES))
def test_add_scene_takes_each_splat_route_and_the_import_renders_the_photos(route, colmap_scene, params_file,
                                                                           tmp_path, capsys):
    folder, scene, model = colmap_scene
    fmt, least_db = ROUTES[route]
    splat = _splat(route, scene, model, tmp_path / "trained")
    rc, out, err = _run(capsys, "add-scene", "garden2", str(folder), "--splat", str(splat), "--params", str(params_file))
    assert rc == 0, err
    named = splat / "splat.ply" if route == "splatfacto_folder" else splat  # the entry names the exported PLY
    assert f"splat {named} ({fmt}): its renders match the photos" in out, out
    reported = REPORTED.search(out)
    assert reported and int(reported.group(2)) == 8
    assert least_db <= float(reported.group(1)) < 70.0, out  # 8-bit photos: no route renders them exactly
    spec = load_params(params_file).data.scenes["garden2"]
    assert (spec.path, spec.format, spec.splat_path()) == (str(folder), "colmap", named)
    # the fit stage's import of the written entry: the same frame, the same check, the same number
    source = read_source(spec.path, spec.format)
    record = import_and_save(source, spec.splat_path(), spec.splat_format, FitParams(), tmp_path / "gs")
    assert record["imported"]["format"] == fmt
    assert record["imported"]["check"]["psnr"] == pytest.approx(float(reported.group(1)), abs=0.05)
    # the export stage gives it back under the source's name, in its format, rendering the photos again
    back = give_back(tmp_path / "gs" / "point_cloud.ply", tmp_path / "gs" / "splat_source.json", tmp_path / "back")
    returned = tmp_path / "back" / named.name
    assert back["file"] == named.name and detect_splat_format(returned) == fmt
    again = check_splat(read_splat(returned, scene=source).model, source, min_psnr=16.0)
    assert again.psnr == pytest.approx(float(reported.group(1)), abs=0.5)  # a lossy codec re-encodes its own values


def test_a_trainers_frame_comes_from_every_camera_while_the_check_skips_distorted_views(colmap_scene, params_file,
                                                                                        tmp_path, capsys):
    """gsplat's world is computed from all of the model's cameras and its points; the check renders only the views
    without a lens model (here two of the eight views get a SIMPLE_RADIAL lens)."""
    folder, scene, model = colmap_scene
    mixed = tmp_path / "mixed"
    shutil.copytree(folder / "images", mixed / "images")
    cams = list(scene.cameras)
    lenses = [Distortion("SIMPLE_RADIAL", (c.K[0, 0], c.K[0, 2], c.K[1, 2], 0.02)) if i < 2 else None
              for i, c in enumerate(cams)]
    write_model(mixed / "sparse" / "0", Cameras.from_list(cams, lenses), scene.points)
    ckpt = _splat("gsplat_ckpt", scene, model, tmp_path / "trained")
    rc, out, err = _run(capsys, "add-scene", "mixed", str(mixed), "--splat", str(ckpt), "--params", str(params_file),
                        "--dry-run")
    assert rc == 0, err
    assert "lens: SIMPLE_RADIAL (2), pinhole (6)" in out and REPORTED.search(out).group(2) == "6", out
    assert float(REPORTED.search(out).group(1)) > 55.0, out


def test_photos_without_cameras_defer_the_check_and_a_folder_without_a_splat_is_refused(colmap_scene, params_file,
                                                                                        tmp_path, capsys):
    """The README's row: photos that structure from motion will pose, and an INRIA output folder. The folder is
    recognised now and checked in the fit stage; a folder holding no splat is refused in one line."""
    folder, scene, model = colmap_scene
    photos = tmp_path / "photos"
    shutil.copytree(folder / "images", photos / "images")
    inria = _splat("inria_folder", scene, model, tmp_path / "gs_out" / "garden")
    rc, out, err = _run(capsys, "add-scene", "garden3", str(photos), "--splat", str(inria), "--params",
                        str(params_file), "--dry-run")
    assert rc == 0, err
    assert f"splat {inria} (inria): checked against the photos in the fit stage" in out, out
    (tmp_path / "empty_run").mkdir()
    rc, _, err = _run(capsys, "add-scene", "garden3", str(photos), "--splat", str(tmp_path / "empty_run"),
                      "--params", str(params_file), "--dry-run")
    assert rc == 2 and err.count("\n") == 1
    assert "empty_run is a folder but neither an INRIA output folder" in err, err
