"""The scene readers, by format: every module of :mod:`abcgs.sources.formats` and of the plugin folders, each with
its ``READER`` (a :class:`~abcgs.sources.base.SceneReader`).

    reader_of("colmap").read(folder, ReadOptions(images="images_4"))
    formats()                # ('photos', 'colmap', 'nerfstudio', 'llff', 'blender', 'splat', ...plugins)

Adding a format is adding one module: to :mod:`abcgs.sources.formats` in this repository, or to a folder named by
the environment variable :data:`PLUGINS_ENV` (``ABCGS_READERS=/path/to/readers``; several folders separated by
``os.pathsep``), whose ``*.py`` files (but ``_*.py``) are imported as ``abcgs_readers.<stem>`` and must each define a
``READER``. Its name then is a ``format`` of ``params.yaml`` (with its options model), an ``add-scene --format``
choice, and a candidate of :func:`abcgs.sources.detect.detect_format` at its ``priority``. :func:`register` adds a
reader at run time (a test's toy format). DVC does not track a plugin folder: list it as a dependency of the stages
yourself if its readers change.

The modules are imported on first use (not when this module is), each importing only light modules at its top: the
heavy reading code (pycolmap, torch) loads when a scene is read.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import pkgutil
import sys
from pathlib import Path
from typing import Literal

from pydantic import create_model

from abcgs.errors import InputError
from abcgs.sources.base import AutoSource, SceneReader, Source

PLUGINS_ENV = "ABCGS_READERS"
"""Environment variable: folders (``os.pathsep``-separated) of reader modules added to the built-in ones."""

_READERS: dict[str, SceneReader] = {}
_BUILT_IN: set[str] = set()
_DISCOVERED = False
_OPTIONS: dict[str, type[Source]] = {}


def _discover() -> None:
    """Register the ``READER`` of every module of :mod:`abcgs.sources.formats`, then of the plugin folders (once)."""
    global _DISCOVERED
    if _DISCOVERED:
        return
    _DISCOVERED = True
    folder = Path(__file__).with_name("formats")
    for info in sorted(pkgutil.iter_modules([str(folder)]), key=lambda m: m.name):
        reader = getattr(importlib.import_module(f"abcgs.sources.formats.{info.name}"), "READER", None)
        if isinstance(reader, SceneReader):
            _add(reader)
            _BUILT_IN.add(reader.name)
    for plugin_dir in filter(None, os.environ.get(PLUGINS_ENV, "").split(os.pathsep)):
        for path in sorted(Path(plugin_dir).glob("*.py")) if Path(plugin_dir).is_dir() else _missing(plugin_dir):
            if not path.name.startswith("_"):
                _add(_plugin_reader(path))


def _missing(plugin_dir: str) -> list[Path]:
    raise InputError(f"{PLUGINS_ENV}: {plugin_dir} is not a folder; name folders of reader modules (*.py, each with "
                     "a READER), separated by " + repr(os.pathsep))


def _plugin_reader(path: Path) -> SceneReader:
    """The ``READER`` of the plugin module ``path``, imported as ``abcgs_readers.<stem>``."""
    name = f"abcgs_readers.{path.stem}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise InputError(f"{PLUGINS_ENV}: {path} cannot be imported as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    reader = getattr(module, "READER", None)
    if not isinstance(reader, SceneReader):
        raise InputError(f"{PLUGINS_ENV}: {path} defines no READER (an abcgs.sources.base.SceneReader); define one, "
                         "or name the file _*.py if it is a helper")
    return reader


def _add(reader: SceneReader) -> None:
    if reader.name in _READERS:
        raise ValueError(f"scene format {reader.name!r} already has a reader")
    _READERS[reader.name] = reader
    _OPTIONS.clear()


def register(reader: SceneReader) -> None:
    """Add a reader at run time (a module of :mod:`abcgs.sources.formats` or of a plugin folder is found without
    this); its name must be new."""
    _discover()
    _add(reader)


def unregister(name: str) -> None:
    """Remove a reader added with :func:`register` or from a plugin folder (a built-in one stays)."""
    _discover()
    if name not in _BUILT_IN and _READERS.pop(name, None) is not None:
        _OPTIONS.clear()


def registered() -> dict[str, SceneReader]:
    """Name → reader, in detection order (priority, then name)."""
    _discover()
    return dict(sorted(_READERS.items(), key=lambda kv: (kv[1].priority, kv[0])))


def formats() -> tuple[str, ...]:
    """Every format a scene can be read as, in listing order (``order``, then name)."""
    _discover()
    return tuple(sorted(_READERS, key=lambda n: (_READERS[n].order, n)))


def reader_of(fmt: str) -> SceneReader:
    """The reader of ``fmt``; :class:`InputError` listing the formats for another name."""
    _discover()
    if fmt not in _READERS:
        raise InputError(f"format {fmt!r} is not one of {', '.join(formats())}")
    return _READERS[fmt]


def option_models() -> dict[str, type[Source]]:
    """Format → its options model (``auto`` first, then the formats in listing order; a reader without options gets
    a model of ``format`` alone): the members of ``data.scenes.<name>.source``'s tagged union
    (:data:`abcgs.sources.params.SourceParams`)."""
    names = formats()  # first: loading the readers registers them, which empties _OPTIONS
    if not _OPTIONS:
        _OPTIONS["auto"] = AutoSource
        for name in names:
            reader = _READERS[name]
            _OPTIONS[name] = reader.options or create_model(  # type: ignore[call-overload]
                f"{name.title()}Source", __base__=Source, __doc__=f"``source: {{format: {name}}}`` (no options).",
                format=(Literal[name], name))
    return dict(_OPTIONS)


Source.registered_options = staticmethod(option_models)  # the options hooks of base.Source ask this registry
