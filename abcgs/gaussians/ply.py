"""Reading and writing 3-D Gaussians in the standard INRIA 3DGS PLY layout.

One ``vertex`` element, binary little endian, all properties ``float32``, in this order::

    x y z  nx ny nz  f_dc_0 f_dc_1 f_dc_2  f_rest_0 … f_rest_{3(K-1)-1}  opacity  scale_0 scale_1 scale_2
    rot_0 rot_1 rot_2 rot_3

- ``f_dc_*``: the DC SH coefficient per channel (R, G, B).
- ``f_rest_*``: the higher SH bands stored channel-major as INRIA does: the K-1 coefficients of R, then
  those of G, then of B (``shN.transpose(1, 2).flatten(1)``). K = (degree+1)², so 0, 9, 24 or 45 fields.
- ``opacity``: the logit; ``scale_*``: log standard deviations; ``rot_*``: the quaternion wxyz, unnormalised.
- ``nx ny nz`` are written as zeros (3DGS does) and ignored on reading.

This is what the reference implementation writes and what common viewers (SuperSplat, the INRIA SIBR
viewer, gsplat's viewer, antimatter15/splat) read. Raw ``float32`` values are written unchanged, so
:func:`write_ply` → :func:`read_ply` is bit-exact.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement, PlyListProperty, PlyParseError

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel, valid_gaussians
from abcgs.io.atomic import write_stream
from abcgs.io.guarded import regular_file

_REST_COUNTS = {0: 0, 9: 1, 24: 2, 45: 3}
"""Number of ``f_rest_*`` fields → SH degree."""


def ply_property_names(sh_degree: int) -> list[str]:
    """Vertex property names, in file order, for a given SH degree (0..3)."""
    n_rest = 3 * ((sh_degree + 1) ** 2 - 1)
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(n_rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


@dataclass(frozen=True)
class PlyLayout:
    """The ``vertex`` properties of a 3DGS PLY as a file had them: ``(name, numpy dtype string)`` in file order.

    Another trainer may order the properties differently, leave out ``nx ny nz``, store other types or add
    properties of its own; :func:`write_ply` with a layout writes that order and those types back.
    """

    properties: tuple[tuple[str, str], ...]

    @classmethod
    def standard(cls, sh_degree: int) -> PlyLayout:
        """The INRIA layout (all ``float32``) of :func:`ply_property_names`."""
        return cls(tuple((name, "<f4") for name in ply_property_names(sh_degree)))

    @property
    def names(self) -> list[str]:
        return [name for name, _ in self.properties]

    @property
    def sh_degree(self) -> int:
        return _REST_COUNTS[sum(1 for name in self.names if name.startswith("f_rest_"))]

    def extra_names(self) -> list[str]:
        """Properties that are not Gaussian parameters (``nx ny nz`` and any a trainer added)."""
        known = set(ply_property_names(self.sh_degree)) - {"nx", "ny", "nz"}
        return [name for name in self.names if name not in known]

    def to_list(self) -> list[list[str]]:
        return [[name, dtype] for name, dtype in self.properties]

    @classmethod
    def from_list(cls, items: list) -> PlyLayout:
        return cls(tuple((str(name), str(dtype)) for name, dtype in items))


PLY_CHUNK = 1 << 17
"""Gaussians per block of rows when a PLY is written: the writer holds one block, not a copy of the scene."""


def _model_columns(model: GaussianModel, lo: int, hi: int) -> dict[str, np.ndarray]:
    """Every 3DGS property of Gaussians ``lo:hi`` of ``model`` as a ``float32`` column, by its PLY name."""
    n = hi - lo

    def host(t: torch.Tensor) -> np.ndarray:
        return t.detach()[lo:hi].to("cpu", torch.float32).numpy().reshape(n, -1)

    blocks = [
        ("x y z", host(model.means)), ("f_dc_0 f_dc_1 f_dc_2", host(model.sh0)),
        (" ".join(f"f_rest_{i}" for i in range(3 * model.shN.shape[1])), host(model.shN.transpose(1, 2))),
        ("opacity", host(model.opacity_logits)), ("scale_0 scale_1 scale_2", host(model.log_scales)),
        ("rot_0 rot_1 rot_2 rot_3", host(model.quats)),
    ]
    return {name: block[:, i] for names, block in blocks for i, name in enumerate(names.split())}


def _ply_dtype(model: GaussianModel, layout: PlyLayout | None) -> np.dtype:
    """The row type: the INRIA layout (``float32`` fields, normals zero), or ``layout``'s order and types."""
    if layout is None:
        return np.dtype([(name, "<f4") for name in ply_property_names(model.sh_degree)])
    if layout.sh_degree != model.sh_degree:
        raise InputError(f"the PLY layout has SH degree {layout.sh_degree} but the scene has degree {model.sh_degree}")
    return np.dtype([(name, dtype) for name, dtype in layout.properties])


def _rows(model: GaussianModel, dtype: np.dtype, extras: dict[str, np.ndarray] | None, lo: int, hi: int) -> np.ndarray:
    """Rows ``lo:hi`` of the PLY body as a structured array of ``dtype``. Properties that are not Gaussian
    parameters take their values from ``extras`` when it holds one column per Gaussian for them, else zeros."""
    cols = _model_columns(model, lo, hi)
    n, total = hi - lo, model.num_gaussians
    arr = np.empty(n, dtype=dtype)
    for name in dtype.names:
        value = cols.get(name)
        if value is None:
            extra = (extras or {}).get(name)
            value = extra[lo:hi] if extra is not None and len(extra) == total else np.zeros(n)
        arr[name] = np.asarray(value).astype(dtype[name])
    return arr


def gaussians_to_array(model: GaussianModel, layout: PlyLayout | None = None,
                       extras: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """The model as a ``(N,)`` numpy structured array: the INRIA layout (``float32`` fields), or ``layout``'s order
    and types (see :func:`_rows` for ``extras``)."""
    return _rows(model, _ply_dtype(model, layout), extras, 0, model.num_gaussians)


def write_ply(path: str | os.PathLike, model: GaussianModel, layout: PlyLayout | None = None,
              extras: dict[str, np.ndarray] | None = None) -> None:
    """Write ``model`` as an INRIA-layout 3DGS PLY (binary little endian), atomically; with ``layout``, in that
    property order and those types (see :func:`_rows` for ``extras``). The body is written :data:`PLY_CHUNK`
    rows at a time, the same bytes as plyfile writes for the whole array."""
    dtype = _ply_dtype(model, layout)
    n = model.num_gaussians
    properties = PlyElement.describe(np.empty(0, dtype=dtype), "vertex").properties
    header = PlyData([PlyElement("vertex", properties, n)], text=False, byte_order="<").header

    def write(fh) -> None:
        fh.write(header.encode("ascii") + b"\n")
        for lo in range(0, n, PLY_CHUNK):
            fh.write(_rows(model, dtype, extras, lo, min(n, lo + PLY_CHUNK)).tobytes())

    write_stream(path, write)


def _check_body_size(path: Path, head: bytes, size: int, data: PlyData) -> None:
    """Binary files of fixed-size rows must end exactly after the counted rows (catches a wrong count); ``head``
    holds at least the header, ``size`` is the file's size."""
    if data.text or any(isinstance(p, PlyListProperty) for el in data.elements for p in el.properties):
        return
    end = head.find(b"end_header")
    newline = head.find(b"\n", end) if end >= 0 else -1
    if newline < 0:
        raise InputError(f"{path}: its PLY header does not end within the first {HEADER_LIMIT} bytes; a 3DGS PLY's "
                         "header is a few kB")
    body = newline + 1
    expected = sum(el.count * np.dtype(el.dtype()).itemsize for el in data.elements)
    extra = size - body - expected
    if extra:
        counts = ", ".join(f"{el.count} {el.name}" for el in data.elements)
        raise InputError(
            f"{path} has {extra} bytes after the {counts} rows its header declares; the element count in the "
            "header is wrong or the file is corrupt"
        )


UNKNOWN_LAYOUT_FIX = (
    "a 3DGS PLY stores per vertex x y z, f_dc_0..2, f_rest_* (0, 9, 24 or 45), opacity, scale_0..2 and rot_0..3 "
    "(the INRIA layout that 3DGS, gsplat, nerfstudio, OpenSplat and SuperSplat write); export the scene from its tool "
    "in that layout, or name the format with data.scenes.<scene>.splat_format (supersplat, splat, spz, gsplat_ckpt)"
)


def read_ply(path: str | os.PathLike, *, device: torch.device | str = "cpu", drop_invalid: bool = False) -> GaussianModel:
    """Read a 3DGS PLY written by this module, by the INRIA code or by tools that keep its layout.

    The SH degree is inferred from the number of ``f_rest_*`` fields. Any numeric property type is
    accepted and converted to ``float32``. A missing file, a file that is not a PLY, a truncated body, a
    missing ``vertex`` element or property, or an ``f_rest`` count that is not 0/9/24/45 raises
    :class:`InputError` saying which. So do Gaussians with a NaN or infinite value (their count), unless
    ``drop_invalid`` drops them with a warning (:func:`abcgs.gaussians.valid_gaussians`).
    """
    return read_ply_layout(path, device=device, drop_invalid=drop_invalid)[0]


HEADER_LIMIT = 1 << 20
"""Bytes read for a PLY header (the body is memory-mapped, never read whole)."""


def _read_head(path: Path) -> bytes:
    """The file's first :data:`HEADER_LIMIT` bytes (or all of a shorter file)."""
    with open(path, "rb") as fh:
        return fh.read(HEADER_LIMIT)


def read_ply_layout(
    path: str | os.PathLike, *, device: torch.device | str = "cpu", drop_invalid: bool = False
) -> tuple[GaussianModel, PlyLayout, dict[str, np.ndarray]]:
    """:func:`read_ply`, also returning the file's :class:`PlyLayout` and the values of its properties that are
    not Gaussian parameters (``{name: (N,) array}``), so that :func:`write_ply` can write the same layout back."""
    path = Path(path)
    regular_file(path, "PLY file")
    head = _read_head(path)
    if not (head.startswith(b"ply\n") or head.startswith(b"ply\r\n")):
        raise InputError(f"{path} is not a PLY file (it does not start with the 'ply' magic line)")
    try:
        # Memory-mapped (copy-on-write): plyfile's only bulk path for binary rows. From a byte stream it reads
        # property by property, row by row, two orders of magnitude slower in every stage that loads a scene
        # (docs/measurements/settings.yaml, ply_read_mmap). The columns are copied out below, so nothing keeps the
        # mapping once this returns.
        data = PlyData.read(str(path), mmap="c")
    except (PlyParseError, ValueError, EOFError, IndexError, UnicodeDecodeError) as exc:
        raise InputError(f"{path} is a malformed or truncated PLY file: {exc}") from exc
    _check_body_size(path, head, path.stat().st_size, data)
    if "vertex" not in [el.name for el in data.elements]:
        raise InputError(f"{path} has no 'vertex' element, a PLY of an unknown layout: {UNKNOWN_LAYOUT_FIX}")
    vertex = data["vertex"]
    names = [p.name for p in vertex.properties]
    if any(isinstance(p, PlyListProperty) for p in vertex.properties):
        raise InputError(f"{path}: its vertex element has list properties, a PLY of an unknown layout: {UNKNOWN_LAYOUT_FIX}")
    rest = [n for n in names if n.startswith("f_rest_")]
    if len(rest) not in _REST_COUNTS:
        raise InputError(
            f"{path} has {len(rest)} f_rest_* properties; a 3DGS PLY has 0, 9, 24 or 45 "
            "(SH degree 0, 1, 2 or 3)"
        )
    degree = _REST_COUNTS[len(rest)]
    if sorted(int(re.sub(r"\D", "", n) or -1) for n in rest) != list(range(len(rest))):
        raise InputError(f"{path}: the f_rest_* properties are not numbered 0..{len(rest) - 1}")
    required = [n for n in ply_property_names(degree) if n not in ("nx", "ny", "nz")]
    missing = [n for n in required if n not in names]
    if missing:
        raise InputError(f"{path} is missing the vertex properties {', '.join(missing)} of the 3DGS layout (it has "
                         f"{', '.join(names[:12])}{', ...' if len(names) > 12 else ''}), a PLY of an unknown layout: "
                         f"{UNKNOWN_LAYOUT_FIX}")
    arr = vertex.data
    n = len(arr)

    def col(*props: str) -> np.ndarray:
        if not props:
            return np.zeros((n, 0), np.float32)
        return np.stack([np.asarray(arr[p], dtype=np.float32) for p in props], axis=1)

    k1 = len(rest) // 3
    sh_rest = np.empty((n, k1, 3), np.float32)  # f_rest_{c·k1 + j} is band j, channel c: filled in place
    for c in range(3):
        for j in range(k1):
            sh_rest[:, j, c] = arr[f"f_rest_{c * k1 + j}"]
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(device)  # noqa: E731
    layout = PlyLayout(tuple((p.name, arr.dtype[p.name].str) for p in vertex.properties))
    extras = {name: np.array(arr[name]) for name in layout.extra_names()}
    model = GaussianModel(
        means=t(col("x", "y", "z")),
        quats=t(col("rot_0", "rot_1", "rot_2", "rot_3")),
        log_scales=t(col("scale_0", "scale_1", "scale_2")),
        opacity_logits=t(col("opacity")[:, 0]),
        sh0=t(col("f_dc_0", "f_dc_1", "f_dc_2")[:, None, :]),
        shN=t(sh_rest),
    )
    bad = model.invalid_rows().cpu().numpy()
    model = valid_gaussians(model, str(path), drop=drop_invalid)
    if bad.any():
        extras = {name: v[~bad] for name, v in extras.items()}
    return model, layout, extras
