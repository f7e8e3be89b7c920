"""INRIA-layout 3DGS PLY: bit-exact round trip, layout, and clear errors for malformed files."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.gaussians.ply import gaussians_to_array, ply_property_names, read_ply, write_ply


def random_model(n: int, degree: int, seed: int = 0) -> GaussianModel:
    g = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    return GaussianModel(
        means=torch.randn(n, 3, generator=g) * 10,
        quats=torch.randn(n, 4, generator=g),
        log_scales=torch.randn(n, 3, generator=g) - 3,
        opacity_logits=torch.randn(n, generator=g) * 4,
        sh0=torch.randn(n, 1, 3, generator=g),
        shN=torch.randn(n, k - 1, 3, generator=g),
    )


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_round_trip_bit_exact(tmp_path, degree):
    model = random_model(257, degree)
    # values whose decimal printing would lose bits, plus extremes
    model.means[0] = torch.tensor([1.0 / 3.0, -0.0, 3.4028235e38])
    model.log_scales[1] = torch.tensor([1e-45, -1e-38, 7.0])
    path = tmp_path / "pc.ply"
    write_ply(path, model)
    back = read_ply(path)
    assert back.sh_degree == degree
    for (name, a), (_, b) in zip(model.items(), back.items()):
        assert a.dtype == b.dtype == torch.float32, name
        assert a.shape == b.shape, name
        assert np.array_equal(a.numpy().view(np.uint32), b.numpy().view(np.uint32)), name
    assert not list(tmp_path.glob(".*tmp*")), "temporary file left behind"


def test_the_body_written_in_blocks_is_plyfiles_whole_array_byte_for_byte(tmp_path, monkeypatch):
    from abcgs.gaussians import ply
    from abcgs.gaussians.ply import PlyLayout

    model = random_model(1000, 3, seed=5)
    monkeypatch.setattr(ply, "PLY_CHUNK", 96)  # 11 blocks, the last one short
    custom = PlyLayout(tuple([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("red", "|u1")]
                             + [(n, "<f4") for n in ply_property_names(3) if n not in ("x", "y", "z", "nx", "ny", "nz")]))
    extras = {"red": np.arange(1000) % 256}
    for layout in (None, custom):
        write_ply(tmp_path / "blocks.ply", model, layout, extras)
        element = PlyElement.describe(gaussians_to_array(model, layout, extras), "vertex")
        PlyData([element], text=False, byte_order="<").write(str(tmp_path / "whole.ply"))
        assert (tmp_path / "blocks.ply").read_bytes() == (tmp_path / "whole.ply").read_bytes()


def test_layout_matches_inria(tmp_path):
    model = random_model(5, 3)
    path = tmp_path / "pc.ply"
    write_ply(path, model)
    header = path.read_bytes().split(b"end_header\n")[0].decode()
    assert "format binary_little_endian 1.0" in header
    assert "element vertex 5" in header
    props = [line.split()[-1] for line in header.splitlines() if line.startswith("property")]
    assert props == ply_property_names(3)
    assert all(line.split()[1] == "float" for line in header.splitlines() if line.startswith("property"))
    assert len([p for p in props if p.startswith("f_rest_")]) == 45
    arr = gaussians_to_array(model)
    # channel-major f_rest: R coefficients 0..14, then G, then B
    assert arr["f_rest_0"][2] == model.shN[2, 0, 0]
    assert arr["f_rest_1"][2] == model.shN[2, 1, 0]
    assert arr["f_rest_15"][2] == model.shN[2, 0, 1]
    assert arr["f_rest_30"][2] == model.shN[2, 0, 2]
    assert arr["opacity"][3] == model.opacity_logits[3]
    assert arr["rot_0"][4] == model.quats[4, 0]  # w first, unnormalised
    assert np.all(arr["nx"] == 0)


def _write_vertex(path, fields: dict[str, np.ndarray]):
    arr = np.empty(len(next(iter(fields.values()))), dtype=[(k, "<f4") for k in fields])
    for k, v in fields.items():
        arr[k] = v
    PlyData([PlyElement.describe(arr, "vertex")], byte_order="<").write(str(path))


def test_missing_property(tmp_path):
    arr = gaussians_to_array(random_model(4, 0))
    fields = {k: arr[k] for k in arr.dtype.names if k != "scale_1"}
    _write_vertex(tmp_path / "a.ply", fields)
    with pytest.raises(InputError, match="scale_1"):
        read_ply(tmp_path / "a.ply")


def test_wrong_sh_count(tmp_path):
    arr = gaussians_to_array(random_model(4, 0))
    fields = {k: arr[k] for k in arr.dtype.names}
    fields.update({f"f_rest_{i}": np.zeros(4, np.float32) for i in range(5)})
    _write_vertex(tmp_path / "a.ply", fields)
    with pytest.raises(InputError, match="5 f_rest"):
        read_ply(tmp_path / "a.ply")


def test_no_vertex_element(tmp_path):
    arr = np.zeros(3, dtype=[("x", "<f4")])
    PlyData([PlyElement.describe(arr, "face_data")]).write(str(tmp_path / "a.ply"))
    with pytest.raises(InputError, match="vertex"):
        read_ply(tmp_path / "a.ply")


def test_ascii_ply_is_read(tmp_path):
    model = random_model(3, 0)
    PlyData([PlyElement.describe(gaussians_to_array(model), "vertex")], text=True).write(str(tmp_path / "a.ply"))
    back = read_ply(tmp_path / "a.ply")
    assert torch.allclose(back.means, model.means, rtol=1e-6)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda b: b[:-7], "truncated"),
        (lambda b: b[:40], "truncated"),
        (lambda b: b.replace(b"element vertex 10", b"element vertex 11"), "truncated"),
        (lambda b: b.replace(b"element vertex 10", b"element vertex 9 "), "header is wrong"),
        (lambda b: b"hello, not a ply at all", "not a PLY"),
        (lambda b: b"", "not a PLY"),
    ],
    ids=["truncated-body", "truncated-header", "count-too-high", "count-too-low", "not-ply", "empty"],
)
def test_malformed(tmp_path, mutate, message):
    good = tmp_path / "good.ply"
    write_ply(good, random_model(10, 1))
    bad = tmp_path / "bad.ply"
    bad.write_bytes(mutate(good.read_bytes()))
    with pytest.raises(InputError, match=message):
        read_ply(bad)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        read_ply(tmp_path / "nope.ply")
