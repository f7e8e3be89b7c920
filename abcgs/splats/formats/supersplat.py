"""SuperSplat's (PlayCanvas) compressed PLY: 16 bytes per Gaussian plus 256-Gaussian chunk bounds.

Elements (binary little endian): ``chunk`` (one per 256 Gaussians, ``float32``: ``min_x min_y min_z max_x max_y
max_z min_scale_x … max_scale_z`` and optionally ``min_r min_g min_b max_r max_g max_b``), ``vertex`` (``uint32``
``packed_position packed_rotation packed_scale packed_color``) and, for SH degree ≥ 1, ``sh`` (``uint8``
``f_rest_0 …``, INRIA's channel-major order). Packing (as PlayCanvas' ``splat-transform`` decodes it):

- position and log-scale: 11/10/11 bits (x high, z low), each the fraction between the chunk's min and max;
- colour: 8 bits each of ``C0·f_dc + 0.5`` between the chunk's colour min/max, and 8 bits of ``sigmoid(opacity)``;
- rotation: 2 bits for the index of the largest |component| of the unit quaternion (wxyz; made positive), the other
  three as 10 bits of ``v/√2 + 0.5``;
- SH: ``byte = clamp(floor((v/8 + 0.5)·256), 0, 255)``, decoded at the bucket centre ``(byte + 0.5)/256`` (0 and
  255 at the ends).

Gaussians are written in Morton order of their positions (what SuperSplat does), so each chunk's bounds are tight.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.io.atomic import write_stream
from abcgs.render.sh import C0
from abcgs.splats.contract import SplatFormatSpec, SplatProvenance
from abcgs.splats.formats.ply import is_compressed_ply, is_ply

CHUNK = 256
_CHUNK_FIELDS = [f"{m}_{a}" for m in ("min", "max") for a in "xyz"] + [
    f"{m}_scale_{a}" for m in ("min", "max") for a in "xyz"] + [f"{m}_{c}" for m in ("min", "max") for c in "rgb"]
_PACKED = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
SQRT2 = float(np.sqrt(2.0))


def _morton(means: np.ndarray) -> np.ndarray:
    lo, hi = means.min(0), means.max(0)
    q = ((means - lo) / np.maximum(hi - lo, 1e-12) * 1023).astype(np.uint64)
    code = np.zeros(len(means), np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


def _chunk_minmax(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per chunk min and max of ``values (N, C)`` (the last chunk padded with its own first row)."""
    n = len(values)
    pad = (-n) % CHUNK
    v = np.concatenate([values, np.repeat(values[-1:], pad, axis=0)]) if pad else values
    v = v.reshape(-1, CHUNK, values.shape[1])
    return v.min(1), v.max(1)


def _unorm(values: np.ndarray, lo: np.ndarray, hi: np.ndarray, bits: int) -> np.ndarray:
    """Quantise ``values (N, C)`` into ``bits`` between the per-Gaussian bounds ``lo``/``hi``."""
    top = (1 << bits) - 1
    t = np.where(hi > lo, (values - lo) / np.where(hi > lo, hi - lo, 1.0), 0.0)
    return np.clip(np.floor(t * top + 0.5), 0, top).astype(np.uint32)


def encode_compressed_ply(model: GaussianModel) -> tuple[PlyData, np.ndarray]:
    """``model`` → the compressed PLY and the order its Gaussians were written in (indices into ``model``)."""
    n = model.num_gaussians
    if n == 0:
        raise InputError("compressed PLY: the scene has no Gaussians")
    with torch.no_grad():
        means = model.means.double().cpu().numpy()
        order = _morton(means)
        means = means[order]
        ls = np.clip(model.log_scales.double().cpu().numpy()[order], -20, 20)
        rgb = (model.sh0[:, 0, :].double().cpu().numpy() * C0 + 0.5)[order]
        alpha = model.opacities.double().cpu().numpy()[order]
        q = torch.nn.functional.normalize(model.quats.double(), dim=-1).cpu().numpy()[order]
        rest = model.shN.transpose(1, 2).reshape(n, -1).double().cpu().numpy()[order]
    chunk_idx = np.arange(n) // CHUNK
    pmin, pmax = _chunk_minmax(means)
    smin, smax = _chunk_minmax(ls)
    cmin, cmax = _chunk_minmax(rgb)
    p = _unorm(means, pmin[chunk_idx], pmax[chunk_idx], 11)
    p[:, 1] = _unorm(means[:, 1:2], pmin[chunk_idx, 1:2], pmax[chunk_idx, 1:2], 10)[:, 0]
    s = _unorm(ls, smin[chunk_idx], smax[chunk_idx], 11)
    s[:, 1] = _unorm(ls[:, 1:2], smin[chunk_idx, 1:2], smax[chunk_idx, 1:2], 10)[:, 0]
    c = _unorm(rgb, cmin[chunk_idx], cmax[chunk_idx], 8)
    a = np.clip(np.floor(alpha * 255 + 0.5), 0, 255).astype(np.uint32)
    largest = np.argmax(np.abs(q), axis=1)
    q = np.where(q[np.arange(n), largest][:, None] < 0, -q, q)
    rot = largest.astype(np.uint32)
    for i in range(4):
        keep = largest != i
        v = np.clip(np.floor((q[:, i] / SQRT2 + 0.5) * 1023 + 0.5), 0, 1023).astype(np.uint32)
        rot = np.where(keep, (rot << 10) | v, rot)
    vertex = np.empty(n, [(name, "<u4") for name in _PACKED])
    vertex["packed_position"] = (p[:, 0] << 21) | (p[:, 1] << 11) | p[:, 2]
    vertex["packed_rotation"] = rot
    vertex["packed_scale"] = (s[:, 0] << 21) | (s[:, 1] << 11) | s[:, 2]
    vertex["packed_color"] = (c[:, 0] << 24) | (c[:, 1] << 16) | (c[:, 2] << 8) | a
    chunks = np.empty(len(pmin), [(name, "<f4") for name in _CHUNK_FIELDS])
    for arr, prefix in ((pmin, "min"), (pmax, "max")):
        for i, ax in enumerate("xyz"):
            chunks[f"{prefix}_{ax}"] = arr[:, i]
    for arr, prefix in ((smin, "min_scale"), (smax, "max_scale")):
        for i, ax in enumerate("xyz"):
            chunks[f"{prefix}_{ax}"] = arr[:, i]
    for arr, prefix in ((cmin, "min"), (cmax, "max")):
        for i, ch in enumerate("rgb"):
            chunks[f"{prefix}_{ch}"] = arr[:, i]
    # float32 bounds: re-quantising against the stored (rounded) bounds keeps decode consistent with encode
    elements = [PlyElement.describe(chunks, "chunk"), PlyElement.describe(vertex, "vertex")]
    if rest.shape[1]:
        sh = np.empty(n, [(f"f_rest_{i}", "u1") for i in range(rest.shape[1])])
        codes = np.clip(np.floor((rest / 8.0 + 0.5) * 256.0), 0, 255).astype(np.uint8)
        for i in range(rest.shape[1]):
            sh[f"f_rest_{i}"] = codes[:, i]
        elements.append(PlyElement.describe(sh, "sh"))
    return PlyData(elements, text=False, byte_order="<"), order


def write_compressed_ply(path: str | os.PathLike, model: GaussianModel) -> int:
    """Write ``model`` as a compressed PLY, atomically; returns the file size in bytes."""
    data, _ = encode_compressed_ply(model)
    return write_stream(path, data.write)


def _bits(v: np.ndarray, shift: int, bits: int) -> np.ndarray:
    return ((v >> np.uint32(shift)) & np.uint32((1 << bits) - 1)).astype(np.float64) / ((1 << bits) - 1)


def read_compressed_ply(path: str | os.PathLike) -> GaussianModel:
    """A SuperSplat compressed PLY → :class:`GaussianModel` (float32, CPU)."""
    path = Path(path)
    try:
        data = PlyData.read(str(path))
    except Exception as exc:  # plyfile raises several types for a corrupt file
        raise InputError(f"{path} is a malformed compressed PLY: {exc}") from None
    names = [el.name for el in data.elements]
    if "chunk" not in names or "vertex" not in names:
        raise InputError(f"{path} is not a SuperSplat compressed PLY (elements {', '.join(names)}; needs chunk + vertex)")
    ch, vx = data["chunk"].data, data["vertex"].data
    missing = [k for k in _PACKED if k not in vx.dtype.names] + [k for k in _CHUNK_FIELDS[:12] if k not in ch.dtype.names]
    if missing:
        raise InputError(f"{path}: compressed PLY without {', '.join(missing)}")
    n = len(vx)
    if len(ch) != -(-n // CHUNK):
        raise InputError(f"{path}: {len(ch)} chunks for {n} Gaussians; expected {-(-n // CHUNK)} (256 per chunk)")
    ci = np.arange(n) // CHUNK

    def lerp(lo: str, hi: str, t: np.ndarray) -> np.ndarray:
        a, b = ch[lo].astype(np.float64)[ci], ch[hi].astype(np.float64)[ci]
        return a * (1 - t) + b * t

    pp, ps, pc, pr = (vx[k].astype(np.uint32) for k in ("packed_position", "packed_scale", "packed_color", "packed_rotation"))
    means = np.stack([lerp(f"min_{a}", f"max_{a}", _bits(pp, sh, b)) for a, sh, b in (("x", 21, 11), ("y", 11, 10), ("z", 0, 11))], 1)
    ls = np.stack([lerp(f"min_scale_{a}", f"max_scale_{a}", _bits(ps, sh, b))
                   for a, sh, b in (("x", 21, 11), ("y", 11, 10), ("z", 0, 11))], 1)
    rgb = np.stack([_bits(pc, sh, 8) for sh in (24, 16, 8)], 1)
    colour = [f"{m}_{c}" for m in ("min", "max") for c in "rgb"]
    if 0 < sum(k in ch.dtype.names for k in colour) < len(colour):
        raise InputError(f"{path}: the chunk element has some of {', '.join(colour)} but not all; a compressed PLY has "
                         "all six or none")
    if "min_r" in ch.dtype.names:
        rgb = np.stack([lerp(f"min_{c}", f"max_{c}", rgb[:, i]) for i, c in enumerate("rgb")], 1)
    alpha = np.clip(_bits(pc, 0, 8), 1e-6, 1 - 1e-6)
    largest = (pr >> np.uint32(30)).astype(np.int64)
    others = np.stack([(_bits(pr, sh, 10) - 0.5) * SQRT2 for sh in (20, 10, 0)], 1)
    q = np.zeros((n, 4))
    for i in range(4):
        slots = [j for j in range(4) if j != i]
        sel = largest == i
        q[np.ix_(sel, slots)] = others[sel]
    q[np.arange(n), largest] = np.sqrt(np.clip(1 - (others**2).sum(1), 0, None))
    k1 = 0
    rest = np.zeros((n, 0))
    if "sh" in names:
        sh = data["sh"].data
        cols = [c for c in sh.dtype.names if c.startswith("f_rest_")]
        if len(cols) not in (9, 24, 45) or len(sh) != n or set(cols) != {f"f_rest_{i}" for i in range(len(cols))}:
            raise InputError(f"{path}: the sh element has {len(cols)} f_rest columns for {len(sh)} rows; expected 9, 24 "
                             f"or 45 (f_rest_0, f_rest_1, …) for {n} rows")
        b = np.stack([sh[f"f_rest_{i}"].astype(np.float64) for i in range(len(cols))], 1)
        t = np.where(b == 0, 0.0, np.where(b == 255, 1.0, (b + 0.5) / 256.0))
        rest = (t - 0.5) * 8.0
        k1 = len(cols) // 3
    f32 = lambda x: torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))  # noqa: E731
    return GaussianModel(
        means=f32(means), quats=f32(q), log_scales=f32(ls), opacity_logits=f32(np.log(alpha / (1 - alpha))),
        sh0=f32((rgb - 0.5) / C0).reshape(n, 1, 3), shN=f32(rest.reshape(n, 3, k1).transpose(0, 2, 1)),
    )


def _detect(path: Path) -> bool:
    return is_ply(path) and is_compressed_ply(path)


def _read(path: Path, drop_invalid: bool) -> tuple[GaussianModel, dict]:
    return read_compressed_ply(path), {}


def _write(model: GaussianModel, path: Path, like: SplatProvenance) -> None:
    write_compressed_ply(path, model)


FORMAT = SplatFormatSpec("supersplat", _read, _write, detect=_detect, rank=20, lossy=True, suffixes=(".ply",))
