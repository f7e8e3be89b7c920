"""The .spz codec: round trip within the format's quantisation, a hand-decoded header, malformed input."""

from __future__ import annotations

import gzip
import struct

import numpy as np
import pytest
import torch

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.splats.formats.spz import ROUND_TRIP_TOLERANCE, decode_spz, encode_spz, export_record, read_spz, write_spz


def _model(n: int = 500, sh_degree: int = 0, seed: int = 0) -> GaussianModel:
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g)
    k = (sh_degree + 1) ** 2 - 1
    return GaussianModel(
        means=(torch.rand(n, 3, generator=g) - 0.5) * 20,
        quats=q / q.norm(dim=1, keepdim=True),
        log_scales=torch.rand(n, 3, generator=g) * 8 - 9,  # inside [-10, 5.9]
        opacity_logits=torch.randn(n, generator=g) * 2,
        sh0=(torch.rand(n, 1, 3, generator=g) - 0.5) * 6,  # inside ±3.33
        shN=(torch.rand(n, k, 3, generator=g) - 0.5) * 1.6,
    )


def _same_rotation_err(a: torch.Tensor, b: torch.Tensor) -> float:
    a = a / a.norm(dim=1, keepdim=True)
    sign = torch.sign((a * b).sum(dim=1, keepdim=True))
    return float((a - sign * b).abs().max())


@pytest.mark.parametrize("version", [3, 2])
def test_round_trip_within_quantisation(version):
    m = _model()
    if version == 2:  # v2 derives w from xyz: accurate only away from w ≈ 0
        m.quats[:, 0] = m.quats[:, 0].abs() + 0.8
        m.quats = m.quats / m.quats.norm(dim=1, keepdim=True)
    d = decode_spz(encode_spz(m, version=version))
    assert d.num_gaussians == m.num_gaussians
    tol = ROUND_TRIP_TOLERANCE
    assert float((d.means - m.means).abs().max()) <= tol["position"] + 1e-6
    assert float((d.log_scales - m.log_scales).abs().max()) <= tol["log_scale"] + 1e-6
    assert float((torch.sigmoid(d.opacity_logits) - torch.sigmoid(m.opacity_logits)).abs().max()) <= tol["opacity"] + 1e-6
    assert float((d.sh0 - m.sh0).abs().max()) <= tol["sh0"] + 1e-6
    assert _same_rotation_err(m.quats, d.quats) <= tol[f"rotation_v{version}"]


def test_sh_coefficients_round_trip_to_their_buckets():
    m = _model(200, sh_degree=2)
    d = decode_spz(encode_spz(m))
    err = (d.shN - m.shN).abs()
    assert d.shN.shape == m.shN.shape
    assert float(err[:, :3].max()) <= 8 / 128 + 1e-6  # degree 1: 5 bits → buckets of 8
    assert float(err[:, 3:].max()) <= 16 / 128 + 1e-6  # degree 2: 4 bits → buckets of 16


def test_header_and_layout_by_hand():
    """Decode the first Gaussian straight from the byte layout of the format's README."""
    m = _model(3)
    raw = gzip.decompress(encode_spz(m))
    magic, version, n, degree, bits, flags, reserved = struct.unpack_from("<IIIBBBB", raw)
    assert (magic, version, n, degree, bits, flags, reserved) == (0x5053474E, 3, 3, 0, 12, 0, 0)
    body = raw[16:]
    x = int.from_bytes(body[0:3], "little", signed=True) / 4096
    assert abs(x - float(m.means[0, 0])) <= 0.5 / 4096 + 1e-7
    alpha0 = body[9 * 3]
    assert alpha0 == round(float(torch.sigmoid(m.opacity_logits[0])) * 255)
    red0 = body[9 * 3 + 3]
    assert red0 == int(np.clip(round(float(m.sh0[0, 0, 0]) * 0.15 * 255 + 127.5), 0, 255))
    assert len(raw) == 16 + 3 * (9 + 1 + 3 + 3 + 4)


def test_deterministic_bytes():
    m = _model(50)
    assert encode_spz(m) == encode_spz(m)


@pytest.mark.parametrize("version", [3, 2])
def test_the_file_is_encoded_in_chunks_to_the_same_bytes(tmp_path, monkeypatch, version):
    from abcgs.splats.formats import spz

    m = _model(1000, sh_degree=3, seed=4)
    whole = encode_spz(m, version=version)
    monkeypatch.setattr(spz, "ENCODE_CHUNK", 64)  # 16 chunks, the last one short
    assert encode_spz(m, version=version) == whole
    # streamed to disk through a temporary file: its name must not reach the gzip header
    for name in ("a.spz", "another_name.spz"):
        write_spz(tmp_path / name, m, version=version)
        assert (tmp_path / name).read_bytes() == whole


def test_file_round_trip_and_record(tmp_path):
    m = _model(300)
    path = tmp_path / "scene.spz"
    size = write_spz(path, m)
    assert path.stat().st_size == size
    assert not list(tmp_path.glob("*.tmp*"))
    d = read_spz(path)
    assert float((d.means - m.means).abs().max()) <= ROUND_TRIP_TOLERANCE["position"] + 1e-6
    from abcgs.gaussians.ply import write_ply

    write_ply(tmp_path / "scene.ply", m)
    rec = export_record(m, tmp_path / "scene.ply", path, size)
    assert rec["ply_over_spz"] > 3  # the format's point: ~10x smaller than the PLY
    assert rec["colour_clipped_share"] == 0.0


def test_out_of_range_colours_are_clipped_and_counted(tmp_path):
    m = _model(100)
    m.sh0[:10] = 12.0  # far beyond spz's wide-RGB range
    d = decode_spz(encode_spz(m))
    assert float(d.sh0[:10].max()) == pytest.approx(127.5 / (0.15 * 255), abs=1e-3)
    write_spz(tmp_path / "a.spz", m)
    from abcgs.gaussians.ply import write_ply

    write_ply(tmp_path / "a.ply", m)
    rec = export_record(m, tmp_path / "a.ply", tmp_path / "a.spz", 1)
    assert rec["colour_clipped_share"] == pytest.approx(0.10)


@pytest.mark.parametrize(
    "data, message",
    [
        (b"not gzip at all", "not a gzip stream"),
        (gzip.compress(b"short"), "shorter than the 16-byte"),
        (gzip.compress(struct.pack("<IIIBBBB", 0x12345678, 3, 0, 0, 12, 0, 0)), "magic"),
        (gzip.compress(struct.pack("<IIIBBBB", 0x5053474E, 9, 0, 0, 12, 0, 0)), "version 9"),
        (gzip.compress(struct.pack("<IIIBBBB", 0x5053474E, 3, 10, 0, 12, 0, 0) + b"\0" * 5), "truncated"),
    ],
    ids=["not gzip", "short", "magic", "version 9", "truncated"],  # the bytes hold gzip's time: not an id
)
def test_malformed_input_is_a_clear_error(data, message):
    with pytest.raises(InputError, match=message):
        decode_spz(data)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        read_spz(tmp_path / "nope.spz")


def test_positions_beyond_24_bits_are_refused():
    m = _model(4)
    m.means[0, 0] = 5000.0  # 5000 · 4096 ≥ 2^23
    with pytest.raises(InputError, match="24-bit"):
        encode_spz(m)
