"""Reading trained splats of any registered format into the scene's frame, and writing them back.

    imported = read_splat("data/garden/splat/point_cloud.ply", scene=scene)   # auto-detected
    imported.model                 # GaussianModel in the scene's frame
    write_splat(stylized, "out/garden_x/returned", like=imported.provenance)  # same format, frame and layout

Every format is a module of :mod:`abcgs.splats.formats` whose ``FORMAT`` is a
:class:`~abcgs.splats.contract.SplatFormatSpec`; :func:`registered` finds them all (adding a format is adding one
module; :class:`abcgs.plugins.Registry`, as for the scene readers), and :func:`register` adds one at run time. The built-in ones:

==================  =====================================================  =============================================
format              input                                                  frame (file → scene)
==================  =====================================================  =============================================
``inria``           INRIA output folder (highest ``point_cloud/iteration_*``) ``cameras.json`` centres aligned to the scene's
``ply``             any INRIA-layout PLY, SH degree 0–3 (OpenSplat, …)     the scene's
``splatfacto``      ``ns-export gaussian-splat`` PLY + dataparser_transforms  nerfstudio's dataparser transform undone
``gsplat_ckpt``     gsplat ``ckpts/ckpt_*.pt``                             gsplat's ``normalize_world_space`` undone
``gsplat_ply``      gsplat's exported PLY                                  gsplat's ``normalize_world_space`` undone
``opensplat``       OpenSplat's PLY (trained without ``--keep-crs``)       OpenSplat's centring and scaling undone
``supersplat``      SuperSplat / splat-transform compressed PLY            the scene's
``splat``           antimatter15 ``.splat``                                the scene's
``spz``             Niantic ``.spz`` (v2, v3)                              the scene's
==================  =====================================================  =============================================

A PLY is told apart by its header (packed properties: ``supersplat``) and its surroundings (a
``dataparser_transforms.json`` next to it or above: ``splatfacto``); gsplat's and OpenSplat's PLYs look like any other and must be
named (``splat_format: gsplat_ply`` / ``opensplat``) — the import check says so when a plain PLY renders well only in
their frame.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel, valid_gaussians
from abcgs.plugins import Registry
from abcgs.splats import frames
from abcgs.splats.contract import SplatFormatSpec, SplatProvenance

FORMATS: Registry[SplatFormatSpec] = Registry("splat format", SplatFormatSpec, "abcgs.splats.formats", "FORMAT",
                                               order=lambda f: (f.rank, f.name))
"""Every splat format (:class:`abcgs.plugins.Registry`, as the scene readers): the modules of
:mod:`abcgs.splats.formats` and the formats registered at run time."""

register = FORMATS.register
unregister = FORMATS.unregister


def registered() -> dict[str, SplatFormatSpec]:
    """Name → format, in detection order (rank, then name)."""
    return FORMATS.items()


def format_of(name: str) -> SplatFormatSpec:
    """The format named ``name``; :class:`InputError` listing the registered names when there is none."""
    formats = registered()
    if name not in formats:
        raise InputError(f"unknown splat_format {name!r}; use auto or one of {', '.join(sorted(formats))}")
    return formats[name]


def lossy_formats() -> frozenset[str]:
    """Formats that quantise (their round trip is bounded, not exact)."""
    return frozenset(n for n, f in registered().items() if f.lossy)


@dataclass
class ImportedSplat:
    """A trained splat in the scene's frame (:attr:`model`) and where it came from (:attr:`provenance`)."""

    model: GaussianModel
    provenance: SplatProvenance


def detect_splat_format(path: str | os.PathLike) -> str:
    """The format of ``path`` (a file or folder): the first registered format, in detection order, whose ``detect``
    takes it."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"splat {p} does not exist")
    formats = registered()
    for name, spec in formats.items():
        if spec.detect is not None and spec.detect(p):
            return name
    names = ", ".join(sorted(formats))
    if p.is_dir():
        raise InputError(f"{p} is a folder but neither an INRIA output folder (point_cloud/iteration_*/point_cloud.ply) "
                         "nor a splatfacto export (a .ply with dataparser_transforms.json); name the splat file")
    suffixes = ", ".join(sorted({s for f in formats.values() for s in f.suffixes}))
    raise InputError(f"{p}: unknown splat file type {p.suffix.lower() or '(no extension)'!r}; give a file of a known "
                     f"type ({suffixes}) or an INRIA output folder, or set splat_format ({names})")


def read_splat(path: str | os.PathLike, fmt: str = "auto", *, scene=None, drop_invalid: bool = False) -> ImportedSplat:
    """Read a trained splat into the scene's frame.

    Args:
        path: the file or folder (see the module table). fmt: a registered format's name or ``"auto"``.
        scene: the scene (``cameras``, ``points``) when known: gsplat's frame is computed from it, and an INRIA
            folder's ``cameras.json`` is aligned to its cameras.
        drop_invalid: drop the Gaussians with a NaN or infinite value (with a warning and their count) instead of
            refusing the file (:func:`abcgs.gaussians.valid_gaussians`; the scene entry's ``splat_nonfinite``).
    """
    p = Path(path)
    fmt = detect_splat_format(p) if fmt == "auto" else fmt
    spec = format_of(fmt)
    model, fields = _read_valid(spec, p, drop_invalid)
    to_file = spec.frame(p, scene, fields)
    prov = SplatProvenance(fmt, os.fspath(p), model.sh_degree, model.num_gaussians,
                           frames.similarity_matrix(to_file).tolist(), **fields)
    return ImportedSplat(frames.transform_model(model, frames.inverse(to_file)), prov)


def _read_valid(spec: SplatFormatSpec, p: Path, drop_invalid: bool) -> tuple[GaussianModel, dict]:
    """The format's reader on ``p`` (its header and value checks), then at least one Gaussian and every value
    finite (:func:`abcgs.gaussians.valid_gaussians`); the model in the file's frame and the reader's fields."""
    if not p.exists():
        raise InputError(f"splat {p} does not exist")
    model, fields = spec.read(p, drop_invalid)
    if model.num_gaussians == 0:
        raise InputError(f"splat {p} holds 0 Gaussians; export the trained scene again (a splat needs at least one)")
    return valid_gaussians(model, str(p), drop=drop_invalid), fields


def check_splat_file(path: str | os.PathLike, fmt: str = "auto", *, scene=None, drop_invalid: bool = False) -> int:
    """What the ``preflight`` stage checks of a scene's trained splat before any stage runs: the reader's header and
    value checks (:func:`_read_valid`) and, given the ``scene`` (a dataset's cameras and points), its frame as
    :func:`read_splat` finds it (an INRIA folder's ``cameras.json`` against the scene's cameras). The check of its
    renders against the photos stays in the fit stage. Returns the number of Gaussians; :class:`InputError` in one
    line otherwise."""
    if scene is not None:
        return read_splat(path, fmt, scene=scene, drop_invalid=drop_invalid).model.num_gaussians
    p = Path(path)
    return _read_valid(format_of(detect_splat_format(p) if fmt == "auto" else fmt), p, drop_invalid)[0].num_gaussians


def returned_name(prov: SplatProvenance) -> str:
    """The file (or folder) name :func:`write_splat` gives the scene: the source's own name."""
    return Path(prov.source).name


def write_splat(model: GaussianModel, path: str | os.PathLike, like: SplatProvenance) -> Path:
    """Write ``model`` (in the scene's frame) in ``like``'s format, frame and (PLY) property layout to ``path``
    (a folder for ``inria``: ``point_cloud/iteration_<N>/point_cloud.ply`` with the source's ``cameras.json`` and
    ``cfg_args``; a splatfacto PLY gets its ``dataparser_transforms.json`` beside it). The SH degree must be the
    source's. Returns ``path``."""
    path = Path(path)
    if model.sh_degree != like.sh_degree:
        raise InputError(f"the scene has SH degree {model.sh_degree} but {like.source} had {like.sh_degree}; "
                         "the returned file would not be in the source's layout")
    spec = format_of(like.format)
    spec.write(frames.transform_model(model, like.similarity), path, like)
    return path


def read_provenance(path: str | os.PathLike) -> SplatProvenance | None:
    """The provenance JSON the fit stage writes (``None`` for a scene fitted from its photos)."""
    data = json.loads(Path(path).read_text())
    if data.get("format") is None:
        return None
    if data["format"] not in registered():
        raise InputError(f"splat provenance has format {data.get('format')!r}; expected one of "
                         f"{', '.join(sorted(registered()))}")
    return SplatProvenance.from_dict(data)
