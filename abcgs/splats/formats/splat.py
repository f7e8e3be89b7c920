"""antimatter15's ``.splat``: a headerless array of 32-byte records, one per Gaussian, SH degree 0.

============  ======  ==========================================================================
bytes         type    value
============  ======  ==========================================================================
0–11          f32×3   position (world units)
12–23         f32×3   scale: standard deviations (``exp`` of the log-scales)
24–27         u8×4    RGBA: ``C0·f_dc + 0.5`` and ``sigmoid(opacity)``, × 255, rounded and clipped
28–31         u8×4    rotation wxyz of the unit quaternion, ``q·128 + 128`` rounded and clipped
============  ======  ==========================================================================

Records are written sorted by ``−σx·σy·σz·opacity`` (antimatter15's ``convert.py`` order, which web viewers
stream). Positions and scales are exact; colour, opacity and rotation are 8-bit. Higher SH bands are dropped
(:func:`encode_splat` refuses a degree > 0 model unless ``drop_sh=True``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.io.atomic import write_bytes
from abcgs.render.sh import C0
from abcgs.splats.contract import SplatFormatSpec, SplatProvenance, read_bytes

RECORD = np.dtype([("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])
assert RECORD.itemsize == 32


def encode_splat(model: GaussianModel, *, drop_sh: bool = False) -> bytes:
    """``model`` → ``.splat`` bytes."""
    if model.sh_degree and not drop_sh:
        raise InputError(f".splat stores SH degree 0 only; the scene has degree {model.sh_degree} (its view-dependent "
                         "colour would be lost): write .spz or PLY, or drop the bands explicitly")
    with torch.no_grad():
        scales = model.scales.double().cpu().numpy()
        opac = model.opacities.double().cpu().numpy()
        rgb = (model.sh0[:, 0, :].double().cpu().numpy() * C0 + 0.5)
        q = torch.nn.functional.normalize(model.quats.double(), dim=-1).cpu().numpy()
    rec = np.empty(model.num_gaussians, RECORD)
    rec["pos"] = model.means.detach().cpu().numpy()
    rec["scale"] = scales
    rec["rgba"][:, :3] = np.clip(np.round(rgb * 255), 0, 255)
    rec["rgba"][:, 3] = np.clip(np.round(opac * 255), 0, 255)
    rec["rot"] = np.clip(np.round(q * 128 + 128), 0, 255)
    order = np.argsort(-(scales.prod(axis=1) * opac), kind="stable")
    return rec[order].tobytes()


def decode_splat(data: bytes, *, source: str = ".splat data") -> GaussianModel:
    """``.splat`` bytes → :class:`GaussianModel` (float32, CPU, SH degree 0)."""
    if len(data) == 0 or len(data) % RECORD.itemsize:
        raise InputError(f"{source}: {len(data)} bytes is not a positive multiple of the 32-byte .splat record; "
                         "the file is truncated or not a .splat")
    rec = np.frombuffer(data, RECORD)
    n = len(rec)
    scale = rec["scale"].astype(np.float64)
    if not (np.isfinite(rec["pos"]).all() and np.isfinite(scale).all()) or (scale <= 0).any():
        raise InputError(f"{source}: non-finite positions or non-positive scales; the file is not a .splat")
    a = np.clip(rec["rgba"][:, 3].astype(np.float64) / 255.0, 1e-6, 1 - 1e-6)
    q = (rec["rot"].astype(np.float64) - 128.0) / 128.0
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 0, q / np.maximum(norm, 1e-12), np.array([1.0, 0, 0, 0]))
    f32 = lambda x: torch.from_numpy(np.array(x, dtype=np.float32))  # noqa: E731  (a copy: the buffer is read-only)
    return GaussianModel(
        means=f32(rec["pos"]), quats=f32(q), log_scales=f32(np.log(scale)), opacity_logits=f32(np.log(a / (1 - a))),
        sh0=f32((rec["rgba"][:, :3].astype(np.float64) / 255.0 - 0.5) / C0).reshape(n, 1, 3),
        shN=torch.zeros(n, 0, 3),
    )


def read_splat_file(path: str | os.PathLike) -> GaussianModel:
    """Read a ``.splat`` file (missing file or malformed content: :class:`InputError`)."""
    return decode_splat(read_bytes(path, ".splat file"), source=os.fspath(path))


def write_splat_file(path: str | os.PathLike, model: GaussianModel, *, drop_sh: bool = False) -> int:
    """Write ``model`` as ``.splat``, atomically; returns the file size in bytes."""
    return write_bytes(path, encode_splat(model, drop_sh=drop_sh))


def _read(path: Path, drop_invalid: bool) -> tuple[GaussianModel, dict]:
    return read_splat_file(path), {}


def _write(model: GaussianModel, path: Path, like: SplatProvenance) -> None:
    write_splat_file(path, model)


FORMAT = SplatFormatSpec("splat", _read, _write, detect=lambda p: p.suffix.lower() == ".splat", rank=50, lossy=True,
                         suffixes=(".splat",))
