"""Reading a scene of any format through one call and a registry of readers.

    scene = load("data/garden")                             # the format detected, its reader run, cameras checked
    scene = load("data/lego", "blender", background=(1, 1, 1))

Each format's reader is the ``READER`` (a :class:`~abcgs.sources.base.SceneReader`) of the module of
:mod:`abcgs.sources` named like the format (``colmap``, ``nerfstudio``, ``blender``, ``llff``, ``splat``,
``photos``), with one signature, ``read(folder, options)``; :func:`register` adds a reader at run time.
:func:`resolve_format` is the params' ``format`` or detection (:mod:`abcgs.sources.detect`, which
:mod:`abcgs.preflight` uses without loading any reader); :func:`read_source` runs the reader and then
:func:`abcgs.sources.validate.check_cameras`.
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path
from typing import Any

from abcgs.errors import InputError
from abcgs.sources.base import FORMATS, ReadOptions, SceneReader
from abcgs.sources.detect import detect_format
from abcgs.types import Scene

_READERS: dict[str, SceneReader] = {}


def register(reader: SceneReader) -> None:
    """Add a reader for a new format (a built-in format's reader is found without this); its name must be new."""
    if reader.name in _READERS or reader.name in FORMATS:
        raise ValueError(f"scene format {reader.name!r} already has a reader")
    _READERS[reader.name] = reader


def unregister(name: str) -> None:
    """Remove a reader added with :func:`register` (a test's toy format)."""
    if name not in FORMATS:
        _READERS.pop(name, None)


def formats() -> tuple[str, ...]:
    """Every format a scene can be read as: the built-in ones, then those registered at run time."""
    return FORMATS + tuple(n for n in _READERS if n not in FORMATS)


def reader_of(fmt: str) -> SceneReader:
    """The reader of ``fmt`` (the ``READER`` of ``abcgs.sources.<fmt>`` for a built-in format);
    :class:`InputError` listing the formats for another name."""
    if fmt not in _READERS:
        if fmt not in FORMATS:
            raise InputError(f"format {fmt!r} is not one of {', '.join(formats())}")
        _READERS[fmt] = importlib.import_module(f"abcgs.sources.{fmt}").READER
    return _READERS[fmt]


def marker(fmt: str) -> str:
    """What a scene of ``fmt`` is recognised by (for messages)."""
    return reader_of(fmt).marker


def resolve_format(folder: str | os.PathLike, fmt: str = "auto", images: str | None = None) -> str:
    """``fmt`` when the params name one, else the first reader added at run time whose ``detect`` takes ``folder``,
    else what :func:`abcgs.sources.detect.detect_format` finds."""
    if fmt == "auto":
        for name, reader in _READERS.items():
            if name not in FORMATS and reader.detect is not None and reader.detect(Path(folder)):
                return name
        return detect_format(folder, images)
    if fmt not in formats():
        raise InputError(f"format {fmt!r} is not one of auto, {', '.join(formats())}")
    return fmt


def read_source(folder: str | os.PathLike, fmt: str, *, images: str | None = None,
                background: tuple[float, float, float] | None = None, views=None,
                work: str | os.PathLike | None = None, drop_invalid: bool = False) -> Scene:
    """The scene at ``folder`` read as ``fmt`` by its reader (a ``photos`` scene has no cameras to read: structure
    from motion finds them, :mod:`abcgs.sources.photos`), its cameras checked. The options are
    :class:`~abcgs.sources.base.ReadOptions`' (``work``: the folder a bare splat's views are rendered into)."""
    from abcgs.sources.validate import check_cameras

    folder = Path(folder)
    reader = reader_of(fmt)
    scene = reader.read(folder, ReadOptions(images, background, views, Path(work) if work is not None else None,
                                            drop_invalid))
    if reader.check:
        check_cameras(scene, f"{folder} ({reader.marker})")
    return scene


def load(path: str | os.PathLike, format: str = "auto", **options: Any) -> Scene:
    """The scene at ``path``: its format (``auto``: detected) read by that format's reader, its cameras checked;
    ``options``: :class:`~abcgs.sources.base.ReadOptions`' fields."""
    return read_source(path, resolve_format(path, format, options.get("images")), **options)
