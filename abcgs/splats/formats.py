"""Reading trained splats of any supported format into the scene's frame, and writing them back.

    imported = read_splat("data/garden/splat/point_cloud.ply", scene=scene)   # auto-detected
    imported.model                 # GaussianModel in the scene's frame
    write_splat(stylized, "out/garden_x/returned", like=imported.provenance)  # same format, frame and layout

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

import gzip
import json
import os
import struct
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import get_args

import numpy as np

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel, valid_gaussians
from abcgs.io.atomic import atomic_path, write_text
from abcgs.io.ply import PlyLayout, read_ply_layout, write_ply
from abcgs.io.spz import read_spz, write_spz
from abcgs.sfm.align import Similarity
from abcgs.splats import frames, inria, splatfacto, supersplat
from abcgs.splats.gsplat_ckpt import read_gsplat_ckpt, write_gsplat_ckpt
from abcgs.splats.splat import read_splat_file, write_splat_file
from abcgs.types import SplatFormat

FORMATS: tuple[str, ...] = get_args(SplatFormat)
LOSSY: frozenset[str] = frozenset({"supersplat", "splat", "spz"})
"""Formats that quantise (their round trip is bounded, not exact)."""


@dataclass
class SplatProvenance:
    """Where an imported splat came from: what :func:`write_splat` needs to give it back.

    Attributes:
        format: a :data:`SplatFormat`. source: the file or folder read.
        sh_degree: the file's SH degree (0–3). n_gaussians: its Gaussian count.
        to_file: ``(4, 4)`` similarity from the scene's frame to the file's (``[s R | t]``; identity when they agree).
        ply_layout: the PLY's properties in file order with their types (PLY-based formats), else ``None``.
        spz_version: the ``.spz`` version read. step: gsplat's checkpoint step. iteration: the INRIA iteration.
        side_files: file name → text of the files that say the source's frame, written back beside it: an INRIA
            folder's ``cameras.json`` and ``cfg_args``, a splatfacto export's ``dataparser_transforms.json``.
    """

    format: str
    source: str
    sh_degree: int
    n_gaussians: int
    to_file: list = field(default_factory=lambda: np.eye(4).tolist())
    ply_layout: list | None = None
    spz_version: int | None = None
    step: int | None = None
    iteration: int | None = None
    side_files: dict[str, str] = field(default_factory=dict)

    @property
    def similarity(self) -> Similarity:
        return frames.similarity_from_matrix(np.asarray(self.to_file), source=f"{self.source}: to_file")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> SplatProvenance:
        if data.get("format") not in FORMATS:
            raise InputError(f"splat provenance has format {data.get('format')!r}; expected one of {', '.join(FORMATS)}")
        return cls(**data)


@dataclass
class ImportedSplat:
    """A trained splat in the scene's frame (:attr:`model`) and where it came from (:attr:`provenance`)."""

    model: GaussianModel
    provenance: SplatProvenance


def detect_splat_format(path: str | os.PathLike) -> str:
    """The :data:`SplatFormat` of ``path`` from its kind, extension, header and neighbours."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"splat {p} does not exist")
    if p.is_dir():
        if inria.is_inria_folder(p):
            return "inria"
        if splatfacto.find_transforms(p) is not None and any(p.glob("*.ply")):
            return "splatfacto"
        raise InputError(f"{p} is a folder but neither an INRIA output folder (point_cloud/iteration_*/point_cloud.ply) "
                         "nor a splatfacto export (a .ply with dataparser_transforms.json); name the splat file")
    ext = p.suffix.lower()
    if ext in (".pt", ".pth", ".ckpt"):
        return "gsplat_ckpt"
    if ext in (".splat", ".spz"):
        return ext[1:]
    if ext == ".ply":
        with open(p, "rb") as f:
            if not f.read(4).startswith(b"ply"):
                raise InputError(f"{p} is not a PLY file (it does not start with the 'ply' magic line)")
        if supersplat.is_compressed_ply(p):
            return "supersplat"
        if splatfacto.find_transforms(p) is not None:
            return "splatfacto"
        return "ply"
    raise InputError(f"{p}: unknown splat file type {ext or '(no extension)'!r}; give a .ply, .splat, .spz, gsplat .pt or an "
                     f"INRIA output folder, or set splat_format ({', '.join(FORMATS)})")


def _scene_frame_needed(fmt: str, scene) -> None:
    if scene is None:
        raise InputError(f"splat format {fmt} is stored in its trainer's normalised world, which is computed from the "
                         "scene's cameras (and points); import it into a scene that has them")


def read_splat(path: str | os.PathLike, fmt: str = "auto", *, scene=None, drop_invalid: bool = False) -> ImportedSplat:
    """Read a trained splat into the scene's frame.

    Args:
        path: the file or folder (see the module table). fmt: a :data:`SplatFormat` or ``"auto"``.
        scene: the scene (``cameras``, ``points``) when known: gsplat's frame is computed from it, and an INRIA
            folder's ``cameras.json`` is aligned to its cameras.
        drop_invalid: drop the Gaussians with a NaN or infinite value (with a warning and their count) instead of
            refusing the file (:func:`abcgs.gaussians.valid_gaussians`; the scene entry's ``splat_nonfinite``).
    """
    p = Path(path)
    fmt = detect_splat_format(p) if fmt == "auto" else fmt
    if fmt not in FORMATS:
        raise InputError(f"unknown splat_format {fmt!r}; use auto or one of {', '.join(FORMATS)}")
    if not p.exists():
        raise InputError(f"splat {p} does not exist")
    to_file = frames.IDENTITY
    layout: PlyLayout | None = None
    extra: dict = {}
    if fmt == "inria":
        folder = inria.read_inria_folder(p)
        model, layout, _ = read_ply_layout(folder.ply, drop_invalid=drop_invalid)
        extra = {"iteration": folder.iteration,
                 "side_files": {k: v for k, v in (("cameras.json", folder.cameras_json), ("cfg_args", folder.cfg_args)) if v}}
        if folder.cameras_json and scene is not None:
            sim = inria.frame_from_cameras(inria.inria_camera_centres(folder.cameras_json, source=str(p / "cameras.json")),
                                           scene.cameras, source=str(p / "cameras.json"))
            if sim is not None and not frames.is_identity(sim, inria.CAMERA_ALIGN_TOLERANCE * max(1.0, abs(sim.t).max())):
                to_file = frames.inverse(sim)
    elif fmt in ("ply", "gsplat_ply", "opensplat", "splatfacto"):
        ply = splatfacto.splatfacto_ply(p) if fmt == "splatfacto" else p
        if supersplat.is_compressed_ply(ply):
            raise InputError(f"{ply} is a SuperSplat compressed PLY; set splat_format: supersplat (or auto)")
        model, layout, _ = read_ply_layout(ply, drop_invalid=drop_invalid)
        if fmt == "splatfacto":
            tf = splatfacto.find_transforms(p)
            if tf is None:
                raise InputError(f"{p}: no {splatfacto.TRANSFORMS} next to the PLY or above it; copy the splatfacto run's "
                                 f"{splatfacto.TRANSFORMS} beside the exported PLY (its frame cannot be undone without it)")
            to_file = frames.nerfstudio_similarity(tf)
            extra = {"side_files": {splatfacto.TRANSFORMS: tf.read_text()}}
        elif fmt == "gsplat_ply":
            _scene_frame_needed(fmt, scene)
            to_file = frames.gsplat_similarity(scene.cameras, scene.points)
        elif fmt == "opensplat":
            _scene_frame_needed(fmt, scene)
            to_file = frames.opensplat_similarity(scene.cameras)
    elif fmt == "gsplat_ckpt":
        _scene_frame_needed(fmt, scene)
        model, step = read_gsplat_ckpt(p)
        extra = {"step": step}
        to_file = frames.gsplat_similarity(scene.cameras, scene.points)
    elif fmt == "supersplat":
        model = supersplat.read_compressed_ply(p)
    elif fmt == "splat":
        model = read_splat_file(p)
    else:
        model = read_spz(p)
        with gzip.open(p, "rb") as f:  # the header's version, to write the same one back
            extra = {"spz_version": struct.unpack("<II", f.read(8))[1]}
    model = valid_gaussians(model, str(p), drop=drop_invalid)
    prov = SplatProvenance(fmt, os.fspath(p), model.sh_degree, model.num_gaussians,
                           frames.similarity_matrix(to_file).tolist(), layout.to_list() if layout else None, **extra)
    scene_model = frames.transform_model(model, frames.inverse(to_file))
    return ImportedSplat(scene_model, prov)


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
    out = frames.transform_model(model, like.similarity)
    layout = PlyLayout.from_list(like.ply_layout) if like.ply_layout else None
    fmt = like.format
    if fmt == "inria":
        with atomic_path(path, is_dir=True) as tmp:
            write_ply(tmp / "point_cloud" / f"iteration_{like.iteration or 0}" / "point_cloud.ply", out, layout)
            for name, text in like.side_files.items():
                write_text(tmp / name, text)
    elif fmt in ("ply", "gsplat_ply", "opensplat", "splatfacto"):
        write_ply(path, out, layout)
        for name, text in like.side_files.items():
            write_text(path.parent / name, text)
    elif fmt == "gsplat_ckpt":
        write_gsplat_ckpt(path, out, like.step)
    elif fmt == "supersplat":
        supersplat.write_compressed_ply(path, out)
    elif fmt == "splat":
        write_splat_file(path, out)
    elif fmt == "spz":
        write_spz(path, out, version=like.spz_version or 3)
    else:
        raise InputError(f"cannot write splat format {fmt!r}")
    return path


def read_provenance(path: str | os.PathLike) -> SplatProvenance | None:
    """The provenance JSON the fit stage writes (``None`` for a scene fitted from its photos)."""
    data = json.loads(Path(path).read_text())
    return None if data.get("format") is None else SplatProvenance.from_dict(data)
