"""abcgs.io.colmap: the writer's models read back the same (binary and text, distorted lenses too), pycolmap reads
them, points come by id whatever order the file lists them in, and damaged files are refused with InputError."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from abcgs.cameras import Camera, Cameras, Distortion, intrinsics, look_at
from abcgs.errors import InputError
from abcgs.io.colmap import read_model, write_model


def _cameras() -> Cameras:
    rng = np.random.default_rng(0)
    cams = [Camera(f"{i:03d}.png", intrinsics(90.0 + i, 64, 48), look_at(rng.normal(size=3) * 3, np.zeros(3)), 64, 48)
            for i in range(4)]
    lenses = [None, Distortion("OPENCV", (90.0, 91.0, 32.0, 24.0, 0.1, -0.01, 0.001, 0.002)),
              Distortion("SIMPLE_RADIAL", (92.0, 32.0, 24.0, 0.05)), None]
    return Cameras.from_list(cams, lenses)


@pytest.mark.parametrize("text", [False, True])
def test_a_written_model_reads_back_the_same(tmp_path: Path, text: bool) -> None:
    import pycolmap

    cams, xyz = _cameras(), np.random.default_rng(1).normal(size=(30, 3))
    rgb = np.random.default_rng(2).uniform(size=(30, 3))
    write_model(tmp_path, cams, xyz, rgb, text=text)
    model = read_model(tmp_path)
    back = model.cameras()
    assert back.names == cams.names
    np.testing.assert_allclose(back.viewmats, cams.viewmats, atol=1e-12)
    assert np.array_equal(back.intrinsics, cams.intrinsics) and np.array_equal(back.camera_models, cams.camera_models)
    assert np.array_equal(back.distortion_params, cams.distortion_params)
    assert back.distortion(1) == cams.distortion(1) and back.distortion(0) is None
    np.testing.assert_allclose(model.points, xyz, atol=1e-12)
    assert np.array_equal(model.colors, np.round(rgb * 255).astype(np.uint8))
    rec = pycolmap.Reconstruction(str(tmp_path))
    assert rec.num_images() == 4 and rec.num_points3D() == 30
    assert sorted(c.model.name for c in rec.cameras.values()) == ["OPENCV", "PINHOLE", "PINHOLE", "SIMPLE_RADIAL"]


def test_points_come_by_id_whatever_the_files_order(tmp_path: Path) -> None:
    xyz = np.arange(15, dtype=np.float64).reshape(5, 3)
    write_model(tmp_path, _cameras(), xyz, text=True)
    path = tmp_path / "points3D.txt"
    head = [ln for ln in path.read_text().splitlines() if ln.startswith("#")]
    rows = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    path.write_text("\n".join(head + rows[::-1]) + "\n")
    model = read_model(tmp_path)
    assert model.point_ids.tolist() == [1, 2, 3, 4, 5]
    np.testing.assert_array_equal(model.points, xyz)


@pytest.mark.parametrize("name", ["cameras.bin", "images.bin", "points3D.bin"])
def test_a_truncated_binary_file_is_refused_at_every_length(tmp_path: Path, name: str) -> None:
    write_model(tmp_path, _cameras(), np.zeros((3, 3)))
    data = (tmp_path / name).read_bytes()
    for n in range(len(data)):
        (tmp_path / name).write_bytes(data[:n])
        with pytest.raises(InputError, match=name):
            read_model(tmp_path)


def test_garbled_text_is_refused(tmp_path: Path) -> None:
    write_model(tmp_path, _cameras(), np.zeros((3, 3)), text=True)
    cams = (tmp_path / "cameras.txt").read_text()
    for bad in (cams.replace("PINHOLE", "PINHOL", 1), cams.replace(" 64 48 ", " 64 nan ", 1),
                cams.replace(" 64 48 ", " 64 ", 1)):
        (tmp_path / "cameras.txt").write_text(bad)
        with pytest.raises(InputError):
            read_model(tmp_path)
