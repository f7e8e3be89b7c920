"""Reading a scene of any registered format through one call.

    scene = load("data/garden")                             # the format detected, its reader run, cameras checked
    scene = load("data/lego", "blender", background=(1, 1, 1))

Each format's reader is the ``READER`` (a :class:`~abcgs.sources.base.SceneReader`) of its module of
:mod:`abcgs.sources.formats` (or of a plugin folder), found by :mod:`abcgs.sources.registry`.
:func:`resolve_format` is the params' ``format`` or detection (:func:`abcgs.sources.detect.detect_format`);
:func:`read_source` runs the reader and then, for cameras read from the dataset,
:func:`abcgs.sources.validate.check_cameras`; :func:`read_entry` reads a ``data.scenes`` entry with its options, as the
``reconstruct`` stage does (:func:`abcgs.sources.reconstruct.reconstruct_scene`), for the checks before it.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from abcgs.errors import InputError
from abcgs.sources.base import ReadOptions, Source
from abcgs.sources.detect import detect_format
from abcgs.sources.registry import formats, reader_of
from abcgs.types import SourceScene

if TYPE_CHECKING:
    from abcgs.sources.params import SceneParams


def loaded(target: Callable | str) -> Callable:
    """A reader's ``read`` or ``reconstruct``: the callable itself, or the function ``"<module>:<function>"`` names
    of that module of :mod:`abcgs.sources`, imported now (a built-in format's reading code)."""
    if callable(target):
        return target
    module, _, function = target.partition(":")
    return getattr(importlib.import_module(f"abcgs.sources.{module}"), function)


def marker(fmt: str) -> str:
    """What a scene of ``fmt`` is recognised by (for messages)."""
    return reader_of(fmt).marker


def resolve_format(folder: str | os.PathLike, fmt: str = "auto", images: str | None = None) -> str:
    """``fmt`` when the params name one, else what :func:`abcgs.sources.detect.detect_format` finds."""
    if fmt == "auto":
        return detect_format(folder, images)
    if fmt not in formats():
        raise InputError(f"format {fmt!r} is not one of auto, {', '.join(formats())}")
    return fmt


def read_source(folder: str | os.PathLike, fmt: str, *, images: str | None = None,
                background: tuple[float, float, float] | None = None, views=None,
                work: str | os.PathLike | None = None, drop_invalid: bool = False, source: Source | None = None
                ) -> SourceScene:
    """The scene at ``folder`` read as ``fmt`` by its reader, its cameras checked where they are read from the
    dataset. The options are :class:`~abcgs.sources.base.ReadOptions`' (``work``: the folder a bare splat's views are
    rendered into, or a ``photos`` scene's structure-from-motion model is written to; ``source``: the scene entry's
    options)."""
    from abcgs.sources.validate import check_cameras

    folder = Path(folder)
    reader = reader_of(fmt)
    scene = loaded(reader.read)(folder, ReadOptions(images, background, views, Path(work) if work is not None else None,
                                            drop_invalid, source))
    if reader.check:
        check_cameras(scene, f"{folder} ({reader.marker})")
    return scene


def read_entry(entry: SceneParams, folder: str | os.PathLike | None = None, fmt: str | None = None, *,
               work: str | os.PathLike | None = None) -> SourceScene:
    """The dataset of the scene entry ``entry`` read as the ``reconstruct`` stage reads it: as ``fmt`` (default: the
    entry's format, detected when ``auto``), with the entry's image folder, bare-splat views, reading options and
    non-finite policy; an object's RGBA views composited on its background colour; the cameras checked where they are
    read. ``folder``: the entry's folder (default ``entry.path``); ``work``: where a bare splat's views are rendered
    (a ``photos`` scene is not read: :func:`abcgs.sources.reconstruct.reconstruct_scene` finds its cameras)."""
    folder = Path(entry.path if folder is None else folder)
    fmt = fmt or resolve_format(folder, entry.format, entry.images)
    background = entry.resolved_background(fmt)
    return read_source(folder, fmt, images=entry.images, background=background.color if background.object else None,
                       views=entry.views, work=work, drop_invalid=entry.splat_nonfinite == "drop", source=entry.source)


def load(path: str | os.PathLike, format: str = "auto", **options: Any) -> SourceScene:
    """The scene at ``path``: its format (``auto``: detected) read by that format's reader, its cameras checked;
    ``options``: :class:`~abcgs.sources.base.ReadOptions`' fields."""
    return read_source(path, resolve_format(path, format, options.get("images")), **options)
