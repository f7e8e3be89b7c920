"""Niantic's ``.spz`` compressed splat format (versions 2 and 3), written and read with numpy + gzip.

The format (nianticlabs/spz ``README.md`` "File Format"): a gzip stream holding a 16-byte little-endian
header ``magic 0x5053474e ("NGSP"), version, numPoints (uint32), shDegree, fractionalBits, flags,
reserved (uint8)`` and then, attribute by attribute for all points:

============  ===========================  =====================================================
attribute     bytes per Gaussian           encoding (decode in brackets)
============  ===========================  =====================================================
positions     9 (3 × 24-bit signed)        fixed point, ``round(x · 2^fractionalBits)``
alphas        1                            ``round(sigmoid(logit) · 255)``  [logit of byte/255]
colors        3                            ``round(f_dc · 0.15 · 255 + 127.5)``  (SH DC coefficient)
scales        3                            ``round((log σ + 10) · 16)``  [byte/16 − 10]
rotations     v2: 3, v3: 4                 v2: xyz of the unit quaternion with w ≥ 0, ``·127.5+127.5``;
                                           v3: "smallest three": index of the largest |component| in
                                           2 bits, the other three as sign + 9-bit magnitude / √½
sh            3 per coefficient            ``round(c · 128 + 128)`` snapped to 5-bit (degree 1) or
                                           4-bit (degree ≥ 2) buckets  [(byte − 128) / 128]
============  ===========================  =====================================================

Quaternions are stored ``xyzw``; :class:`~abcgs.gaussians.GaussianModel` holds ``wxyz``. Coordinates are
written as they are (the format's "unspecified" coordinate system): a reader that assumes RUB sees the
scene in the COLMAP frame, which the viewer (:mod:`abcgs.view`) accounts for by placing its cameras in that
frame. Quantisation bounds the round trip (see :data:`ROUND_TRIP_TOLERANCE`).
"""

from __future__ import annotations

import gzip
import io
import itertools
import os
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np
import torch

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.io.atomic import write_stream
from abcgs.splats.contract import SplatFormatSpec, SplatProvenance, read_bytes

MAGIC = 0x5053474E
HEADER = struct.Struct("<IIIBBBB")
COLOR_SCALE = 0.15
FRACTIONAL_BITS = 12
SQRT1_2 = float(np.sqrt(0.5))
ROUND_TRIP_TOLERANCE = {
    "position": 0.5 / (1 << FRACTIONAL_BITS),  # world units
    "log_scale": 1.0 / 32,  # half a step of 1/16
    "opacity": 0.5 / 255,  # after sigmoid
    "sh0": 0.5 / (COLOR_SCALE * 255),
    "rotation_v3": 1e-3 * 2,  # max |Δ| of a unit-quaternion component (9-bit smallest-three)
    "rotation_v2": 1.0 / 127.5,
}
"""Largest round-trip error per attribute (inside the encodable ranges), checked by the tests."""


def _sh_dim(degree: int) -> int:
    return (degree + 1) ** 2 - 1


def _u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.round(x), 0, 255).astype(np.uint8)


def _pack_positions(means: np.ndarray, bits: int) -> np.ndarray:
    fixed = np.round(means.astype(np.float64) * (1 << bits)).astype(np.int64).reshape(-1)
    limit = 1 << 23
    if fixed.size and (fixed.min() < -limit or fixed.max() >= limit):
        raise InputError(
            f"spz: positions up to {np.abs(means).max():.1f} world units do not fit 24-bit fixed point with "
            f"{bits} fractional bits (|x| < {limit / (1 << bits):.0f}); rescale the scene first"
        )
    u = fixed & 0xFFFFFF
    return np.stack([u & 0xFF, (u >> 8) & 0xFF, (u >> 16) & 0xFF], axis=1).astype(np.uint8).reshape(-1)


def _unpack_positions(raw: np.ndarray, n: int, bits: int) -> np.ndarray:
    b = raw.reshape(n * 3, 3).astype(np.int32)
    v = b[:, 0] | (b[:, 1] << 8) | (b[:, 2] << 16)
    v = np.where(v & 0x800000, v - (1 << 24), v)
    return (v.astype(np.float64) / (1 << bits)).astype(np.float32).reshape(n, 3)


def _pack_rotations_v3(q_xyzw: np.ndarray) -> np.ndarray:
    q = q_xyzw / np.linalg.norm(q_xyzw, axis=1, keepdims=True)
    largest = np.argmax(np.abs(q), axis=1)
    negate = q[np.arange(len(q)), largest] < 0
    comp = largest.astype(np.uint32)
    for i in range(4):
        keep = largest != i
        negbit = ((q[:, i] < 0) ^ negate).astype(np.uint32)
        mag = np.floor(511.0 * (np.abs(q[:, i]) / SQRT1_2) + 0.5).astype(np.uint32)
        mag = np.minimum(mag, 511)
        comp = np.where(keep, (comp << 10) | (negbit << 9) | mag, comp)
    return comp.astype("<u4").view(np.uint8)


def _unpack_rotations_v3(raw: np.ndarray, n: int) -> np.ndarray:
    comp = raw.reshape(n, 4).copy().view("<u4").reshape(n).astype(np.uint64)
    largest = (comp >> 30).astype(np.int64)
    q = np.zeros((n, 4), np.float64)
    for i in range(3, -1, -1):
        here = largest != i
        mag = (comp & 511).astype(np.float64)
        neg = ((comp >> 9) & 1).astype(bool)
        val = SQRT1_2 * mag / 511.0
        q[:, i] = np.where(here, np.where(neg, -val, val), 0.0)
        comp = np.where(here, comp >> 10, comp)
    rest = np.clip(1.0 - (q**2).sum(axis=1), 0.0, None)
    q[np.arange(n), largest] = np.sqrt(rest)
    return q.astype(np.float32)


def _pack_rotations_v2(q_xyzw: np.ndarray) -> np.ndarray:
    q = q_xyzw / np.linalg.norm(q_xyzw, axis=1, keepdims=True)
    q = np.where(q[:, 3:4] < 0, -q, q)
    return _u8(q[:, :3] * 127.5 + 127.5).reshape(-1)


def _unpack_rotations_v2(raw: np.ndarray, n: int) -> np.ndarray:
    xyz = raw.reshape(n, 3).astype(np.float32) / 127.5 - 1.0
    w = np.sqrt(np.clip(1.0 - (xyz**2).sum(axis=1), 0.0, None))
    return np.concatenate([xyz, w[:, None]], axis=1)


def _pack_sh(shN: np.ndarray) -> np.ndarray:
    """``(N, K, 3)`` (coefficient-major, channel inner, as the format wants) → uint8 with the legacy buckets."""
    n, k, _ = shN.shape
    q = np.round(shN * 128.0) + 128.0
    bucket = np.full((1, k, 1), 1 << (8 - 4), np.float64)
    bucket[:, :3] = 1 << (8 - 5)
    q = np.floor((q + bucket // 2) / bucket) * bucket
    return np.clip(q, 0, 255).astype(np.uint8).reshape(-1)


COMPRESS_LEVEL = 6
"""gzip level of the written files (any level reads back the same)."""

ENCODE_CHUNK = 1 << 18
"""Gaussians encoded at a time: the encoder's float64 temporaries stay a few tens of MB whatever the scene's size."""


def _spz_parts(model: GaussianModel, version: int, antialiased: bool) -> Iterator[bytes]:
    """The uncompressed ``.spz`` stream of ``model`` in pieces: the header, then each attribute of every Gaussian
    (positions, alphas, colours, scales, rotations, higher SH), encoded :data:`ENCODE_CHUNK` Gaussians at a time
    (elementwise, so the bytes do not depend on the chunk size)."""
    if version not in (2, 3):
        raise InputError(f"spz: version must be 2 or 3, got {version}")
    n = model.num_gaussians
    k = model.shN.shape[1]
    degree = {0: 0, 3: 1, 8: 2, 15: 3}.get(k)
    if degree is None:
        raise InputError(f"spz: {k} higher-order SH coefficients per Gaussian is not a degree 0–3 layout")
    with torch.no_grad():
        fields = {name: getattr(model, name).detach().cpu() for name in
                  ("means", "quats", "log_scales", "opacity_logits", "sh0", "shN")}
    for name in ("means", "quats", "log_scales", "sh0"):
        if not bool(torch.isfinite(fields[name]).all()):
            raise InputError(f"spz: {name} contain NaN/Inf; the scene is corrupt")
    if bool((fields["quats"].norm(dim=1) == 0).any()):
        raise InputError("spz: a Gaussian has a zero quaternion")

    def chunks(name: str, double: bool = False) -> Iterator[np.ndarray]:
        for i in range(0, n, ENCODE_CHUNK):
            t = fields[name][i:i + ENCODE_CHUNK]
            yield (t.double() if double else t).numpy()

    yield HEADER.pack(MAGIC, version, n, degree, FRACTIONAL_BITS, 1 if antialiased else 0, 0)
    for means in chunks("means"):
        yield _pack_positions(means, FRACTIONAL_BITS).tobytes()
    for logits in chunks("opacity_logits", double=True):
        yield _u8(torch.sigmoid(torch.from_numpy(logits)).numpy() * 255.0).tobytes()
    for sh0 in chunks("sh0"):
        yield _u8(sh0.reshape(-1, 3) * (COLOR_SCALE * 255.0) + 127.5).reshape(-1).tobytes()
    for log_scales in chunks("log_scales"):
        yield _u8((log_scales + 10.0) * 16.0).reshape(-1).tobytes()
    for wxyz in chunks("quats", double=True):
        xyzw = wxyz[:, [1, 2, 3, 0]]
        yield (_pack_rotations_v3(xyzw) if version == 3 else _pack_rotations_v2(xyzw)).tobytes()
    if degree:
        for shN in chunks("shN", double=True):
            yield _pack_sh(shN).tobytes()


def _gzip_parts(parts: Iterator[bytes], fh: BinaryIO) -> None:
    # no name and mtime 0 in the gzip header: the same bytes every run, whatever the (temporary) file is called.
    # zlib's default level: on degree-3 SH coefficients level 9 is 11× slower for 8 % fewer bytes.
    with gzip.GzipFile(filename="", fileobj=fh, mode="wb", compresslevel=COMPRESS_LEVEL, mtime=0) as gz:
        for part in parts:
            gz.write(part)


def encode_spz(model: GaussianModel, *, version: int = 3, antialiased: bool = False) -> bytes:
    """``model`` → ``.spz`` bytes (gzip). SH degree 0–3 (from ``model.shN``)."""
    buf = io.BytesIO()
    _gzip_parts(_spz_parts(model, version, antialiased), buf)
    return buf.getvalue()


def _inflate(data: bytes, limit: int, source: str) -> bytearray:
    """The gzip stream ``data`` inflated, at most ``limit`` bytes plus one (the caller compares the length); memory
    stays bounded by ``limit`` whatever the stream claims. Concatenated gzip members are inflated in turn."""
    out = bytearray()
    rest = data
    try:
        while rest and len(out) <= limit:
            d = zlib.decompressobj(16 + zlib.MAX_WBITS)
            chunk = rest
            while chunk and len(out) <= limit:
                out += d.decompress(chunk, limit + 1 - len(out))
                chunk = d.unconsumed_tail
            if not d.eof:
                if len(out) > limit:
                    break
                raise InputError(f"{source}: the gzip stream ends early (truncated file)")
            rest = d.unused_data
            if rest and not rest.startswith(b"\x1f\x8b"):
                break  # trailing bytes after the last member: gzip ignores zero padding
    except zlib.error as exc:
        raise InputError(f"{source} is not a gzip stream ({exc}); is it a .spz file?") from None
    return out


def _body_size(version: int, n: int, degree: int) -> int:
    """Bytes after the header of ``n`` Gaussians of SH ``degree`` in spz ``version``."""
    return n * (9 + 1 + 3 + 3 + (4 if version == 3 else 3) + 3 * _sh_dim(degree))


MAX_GAUSSIANS = 100_000_000
"""More Gaussians than any splat in use (a few million): a header stating more is refused before inflating."""
MAX_RATIO = 100
"""Most bytes a ``.spz`` may inflate to per compressed byte. A fitted scene's quantised values hardly compress (the tiny
scene's fit: 1.2×); a header whose count implies more than this is a corrupt count or a gzip bomb, refused before
inflating."""


def read_header(data: bytes, source: str = "spz data") -> tuple[int, int, int, int, int]:
    """``(version, n, degree, fractional_bits, flags)`` of ``.spz`` bytes, from the first 16 inflated bytes only;
    :class:`InputError` naming ``source`` when the header is not a supported spz header."""
    head = _inflate(data, HEADER.size, source)[: HEADER.size]
    if len(head) < HEADER.size:
        raise InputError(f"{source}: {len(head)} bytes after decompression, shorter than the 16-byte spz header")
    magic, version, n, degree, bits, flags, _ = HEADER.unpack_from(head)
    if magic != MAGIC:
        raise InputError(f"{source}: magic 0x{magic:08x} is not spz's 0x{MAGIC:08x} ('NGSP')")
    if version not in (2, 3):
        raise InputError(f"{source}: spz version {version} is not supported (2 or 3)")
    if degree > 3:
        raise InputError(f"{source}: SH degree {degree} is not supported (0–3)")
    if flags & 0x2:
        raise InputError(f"{source}: spz extensions (flag 0x2) are not supported")
    if bits > 23:
        raise InputError(f"{source}: {bits} fractional bits of a 24-bit fixed-point position; spz writes 12")
    if n > MAX_GAUSSIANS:
        raise InputError(f"{source}: its header states {n} Gaussians, more than the {MAX_GAUSSIANS} abcgs reads; the "
                         "file is corrupt")
    return version, n, degree, bits, flags


def decode_spz(data: bytes, *, source: str = "spz data") -> GaussianModel:
    """``.spz`` bytes → :class:`GaussianModel` (float32, CPU). Malformed input raises :class:`InputError`.

    The header (the first 16 inflated bytes) is read first; the stream is then inflated to at most the size the
    header's Gaussian count implies, so a stream that inflates to more (a gzip bomb) is refused with bounded
    memory."""
    version, n, degree, bits, flags = read_header(data, source)
    k = _sh_dim(degree)
    need = HEADER.size + _body_size(version, n, degree)
    if need > len(data) * MAX_RATIO:
        raise InputError(f"{source}: its header states {n} Gaussians ({need} bytes inflated) but the file has "
                         f"{len(data)} bytes, more than {MAX_RATIO}x compression (a corrupt count, a truncated file or a "
                         "gzip bomb); re-export it")
    raw = _inflate(data, need, source)
    if len(raw) != need:
        raise InputError(f"{source}: {'more than ' if len(raw) > need else ''}{len(raw)} bytes for {n} Gaussians of "
                         f"SH degree {degree}; expected {need} (truncated or corrupt file)")
    rot_bytes = 4 if version == 3 else 3
    sizes = [9 * n, n, 3 * n, 3 * n, rot_bytes * n, 3 * k * n]
    body = np.frombuffer(raw, np.uint8, offset=HEADER.size)
    offs = np.cumsum([0] + sizes)
    pos, alpha, col, sca, rot, sh = (body[offs[i]:offs[i + 1]] for i in range(6))
    means = _unpack_positions(pos, n, bits)
    a = np.clip(alpha.astype(np.float64) / 255.0, 1e-6, 1 - 1e-6)
    logits = np.log(a / (1 - a)).astype(np.float32)
    sh0 = ((col.astype(np.float32) / 255.0 - 0.5) / COLOR_SCALE).reshape(n, 1, 3)
    log_scales = (sca.astype(np.float32) / 16.0 - 10.0).reshape(n, 3)
    xyzw = _unpack_rotations_v3(rot, n) if version == 3 else _unpack_rotations_v2(rot, n)
    shN = ((sh.astype(np.float32) - 128.0) / 128.0).reshape(n, k, 3)
    t = torch.from_numpy
    return GaussianModel(
        means=t(np.ascontiguousarray(means)), quats=t(np.ascontiguousarray(xyzw[:, [3, 0, 1, 2]])),
        log_scales=t(np.ascontiguousarray(log_scales)), opacity_logits=t(logits), sh0=t(np.ascontiguousarray(sh0)),
        shN=t(np.ascontiguousarray(shN)),
    )


def write_spz(path: str | os.PathLike, model: GaussianModel, *, version: int = 3) -> int:
    """Write ``model`` to ``path`` atomically, compressing as it encodes (no copy of the whole stream in memory);
    returns the file size in bytes."""
    parts = _spz_parts(model, version, False)
    first = next(parts)  # the header: the checks run before the file is opened
    return write_stream(path, lambda fh: _gzip_parts(itertools.chain([first], parts), fh))


def read_spz(path: str | os.PathLike) -> GaussianModel:
    """Read a ``.spz`` file (missing file or malformed content: :class:`InputError`)."""
    return decode_spz(read_bytes(path, "spz file"), source=os.fspath(path))


def _read(path: Path, drop_invalid: bool) -> tuple[GaussianModel, dict]:
    """The Gaussians and the header's version (written back the same)."""
    data = read_bytes(path, "spz file")
    model = decode_spz(data, source=os.fspath(path))
    return model, {"spz_version": read_header(data, os.fspath(path))[0]}


def _write(model: GaussianModel, path: Path, like: SplatProvenance) -> None:
    write_spz(path, model, version=like.spz_version or 3)


FORMAT = SplatFormatSpec("spz", _read, _write, detect=lambda p: p.suffix.lower() == ".spz", rank=60, lossy=True,
                         suffixes=(".spz",))


def export_record(model: GaussianModel, ply: str | os.PathLike, spz: str | os.PathLike, spz_bytes: int) -> dict:
    """What an export lost: sizes, and the share of Gaussians whose values lie outside what spz encodes
    (colours beyond its ``[-0.44, 1.44]`` wide RGB, log-scales outside ``[-10, 5.94]``) and were clipped."""
    with torch.no_grad():
        sh0 = model.sh0.detach().reshape(-1, 3)
        ls = model.log_scales.detach()
    limit = 127.5 / (COLOR_SCALE * 255.0)
    n = max(1, model.num_gaussians)
    ply_bytes = os.path.getsize(ply)
    return {
        "ply": os.fspath(ply), "spz": os.fspath(spz), "n_gaussians": model.num_gaussians,
        "ply_bytes": ply_bytes, "spz_bytes": spz_bytes, "ply_over_spz": ply_bytes / max(1, spz_bytes),
        "colour_clipped_share": float((sh0.abs() > limit).any(dim=1).sum()) / n,
        "scale_clipped_share": float(((ls < -10.0) | (ls > 255 / 16 - 10.0)).any(dim=1).sum()) / n,
    }


def sidecar(spz: str | os.PathLike) -> Path:
    """Where :func:`export_spz` writes the record of ``spz``: ``point_cloud.spz`` → ``point_cloud.spz.json``."""
    return Path(f"{os.fspath(spz)}.json")


def export_spz(ply: str | os.PathLike, spz: str | os.PathLike) -> dict:
    """Convert the PLY ``ply`` to ``spz`` and write its record (:func:`export_record`) to :func:`sidecar`."""
    from abcgs.gaussians.ply import read_ply
    from abcgs.io.atomic import write_json

    model = read_ply(ply)
    record = export_record(model, ply, spz, write_spz(spz, model))
    write_json(sidecar(spz), record)
    return record
