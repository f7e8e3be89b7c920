"""The contract of a splat file format: what a format module under :mod:`abcgs.splats.formats` brings.

A format module defines ``FORMAT``, a :class:`SplatFormatSpec`: its name, ``detect`` (whether it claims a path in
auto-detection), ``read`` (the file's Gaussians in the file's own frame and what is needed to write it back),
``frame`` (the similarity from the scene's frame to the file's) and ``write`` (Gaussians in the file's frame back to
the file). :mod:`abcgs.splats.registry` finds the modules, picks the format of a path and moves the Gaussians between
the file's frame and the scene's. A file of bytes is read with :func:`read_bytes` (one existence and type check) and
written with :func:`abcgs.io.atomic.write_stream` or its :func:`~abcgs.io.atomic.write_bytes` (atomic).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.io.guarded import read_bounded
from abcgs.sfm.align import Similarity
from abcgs.splats import frames


@dataclass
class SplatProvenance:
    """Where an imported splat came from: what a format's ``write`` needs to give it back.

    Attributes:
        format: the format's name. source: the file or folder read.
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
        return cls(**data)


Reader = Callable[[Path, bool], tuple[GaussianModel, dict[str, Any]]]
"""``(path, drop_invalid) → (Gaussians in the file's frame, provenance fields)``: the fields are keyword arguments
of :class:`SplatProvenance` (``ply_layout``, ``spz_version``, ``step``, ``iteration``, ``side_files``)."""
Writer = Callable[[GaussianModel, Path, SplatProvenance], None]
"""``(Gaussians in the file's frame, path, provenance of the source)``: write the file (or folder) at ``path``."""
Frame = Callable[[Path, Any, dict[str, Any]], Similarity]
"""``(path, scene or None, the reader's provenance fields) → similarity from the scene's frame to the file's``."""


def scene_frame(path: Path, scene: Any, fields: dict[str, Any]) -> Similarity:
    """The frame of a format stored in the scene's own frame: the identity."""
    return frames.IDENTITY


def needs_scene(name: str, scene: Any) -> None:
    """Refuse a format whose frame is computed from the scene's cameras (and points) when there is no scene."""
    if scene is None:
        raise InputError(f"splat format {name} is stored in its trainer's normalised world, which is computed from the "
                         "scene's cameras (and points); import it into a scene that has them")


@dataclass(frozen=True)
class SplatFormatSpec:
    """One splat file format.

    Attributes:
        name: the ``splat_format`` value that names it (:data:`abcgs.types.SplatFormat` lists the built-in ones,
            which ``params.yaml`` accepts).
        read: :data:`Reader`. write: :data:`Writer`. frame: :data:`Frame` (default: the scene's frame).
        detect: whether auto-detection takes a path (file or folder) for this format; ``None``: never (the format
            must be named, e.g. gsplat's PLY, which looks like any other). It may raise :class:`InputError` for a
            file of its kind that is broken (a ``.ply`` without the PLY magic).
        rank: detection order, lowest first (a specific format before the general one it is a case of).
        lossy: whether the format quantises (its round trip is bounded, not exact).
        suffixes: file extensions of the format (lower case, with the dot), for messages.
    """

    name: str
    read: Reader
    write: Writer
    frame: Frame = scene_frame
    detect: Callable[[Path], bool] | None = None
    rank: int = 100
    lossy: bool = False
    suffixes: tuple[str, ...] = ()


MAX_SPLAT_BYTES = 8 << 30
"""Largest splat file read whole (bytes): 30 M Gaussians of SH degree 3 in a PLY (248 bytes each) take 7 GiB."""


def read_bytes(path: str | os.PathLike, what: str) -> bytes:
    """The bytes of the file ``path`` (:func:`abcgs.io.guarded.read_bounded`, at most :data:`MAX_SPLAT_BYTES`);
    :class:`InputError` naming ``what`` (``.spz file``) when it is missing, not a regular file or larger."""
    return read_bounded(path, what, MAX_SPLAT_BYTES)
