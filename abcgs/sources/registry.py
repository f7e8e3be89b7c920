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
heavy reading code (pycolmap, torch) loads when a scene is read. The finding and registering is
:class:`abcgs.plugins.Registry`, the same for splat formats (:mod:`abcgs.splats.registry`).
"""

from __future__ import annotations

from typing import Literal

from pydantic import create_model

from abcgs.errors import InputError
from abcgs.plugins import Registry
from abcgs.sources.base import AutoSource, SceneReader, Source

PLUGINS_ENV = "ABCGS_READERS"
"""Environment variable: folders (``os.pathsep``-separated) of reader modules added to the built-in ones."""

_OPTIONS: dict[str, type[Source]] = {}

READERS: Registry[SceneReader] = Registry("scene format", SceneReader, "abcgs.sources.formats", "READER",
                                          order=lambda r: (r.priority, r.name), plugins_env=PLUGINS_ENV,
                                          on_change=_OPTIONS.clear)
"""Every scene reader (:class:`abcgs.plugins.Registry`): the built-in format modules and the plugin folders'."""

register = READERS.register
unregister = READERS.unregister


def registered() -> dict[str, SceneReader]:
    """Name → reader, in detection order (priority, then name)."""
    return READERS.items()


def formats() -> tuple[str, ...]:
    """Every format a scene can be read as, in listing order (``order``, then name)."""
    readers = READERS.items()
    return tuple(sorted(readers, key=lambda n: (readers[n].order, n)))


def reader_of(fmt: str) -> SceneReader:
    """The reader of ``fmt``; :class:`InputError` listing the formats for another name."""
    reader = READERS.get(fmt)
    if reader is None:
        raise InputError(f"format {fmt!r} is not one of {', '.join(formats())}")
    return reader


def option_models() -> dict[str, type[Source]]:
    """Format → its options model (``auto`` first, then the formats in listing order; a reader without options gets
    a model of ``format`` alone): the members of ``data.scenes.<name>.source``'s tagged union
    (:data:`abcgs.sources.params.SourceParams`)."""
    readers = READERS.items()  # first: loading the readers registers them, which empties _OPTIONS
    if not _OPTIONS:
        _OPTIONS["auto"] = AutoSource
        for name in formats():
            reader = readers[name]
            _OPTIONS[name] = reader.options or create_model(  # type: ignore[call-overload]
                f"{name.title()}Source", __base__=Source, __doc__=f"``source: {{format: {name}}}`` (no options).",
                format=(Literal[name], name))
    return dict(_OPTIONS)


Source.registered_options = staticmethod(option_models)  # the options hooks of base.Source ask this registry
