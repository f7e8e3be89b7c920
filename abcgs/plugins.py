"""One plugin pattern: a format is a module that defines one named object, found by the registry of its kind.

    READERS = Registry("scene format", SceneReader, "abcgs.sources.formats", "READER",
                       order=lambda r: (r.priority, r.name), plugins_env="ABCGS_READERS")
    READERS.get("colmap")        # the reader of format colmap
    READERS.items()              # name → item, in ``order``
    READERS.register(toy)        # a format added at run time (a test's toy format)

The built-in formats are the modules of one package (``abcgs.sources.formats``: scene readers, each defining ``READER``;
``abcgs.splats.formats``: splat codecs, each defining ``FORMAT``), imported on first use in name order; a module without
the attribute is a helper. Where the registry names an environment variable, the ``*.py`` files of the folders it lists
(``os.pathsep``-separated; not ``_*.py``, the helpers) are imported as ``<env variable, lowercase>.<stem>``
(``abcgs_readers.my_format``) and each must define the attribute. An item's ``name`` is unique; a built-in one cannot be
removed. Adding a format is adding one module: :mod:`abcgs.sources.registry` and :mod:`abcgs.splats.registry` are this
class with their kind's lookups around it.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import pkgutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

from abcgs.errors import InputError

T = TypeVar("T")


@dataclass
class Registry(Generic[T]):
    """The items of one kind of plugin, by name.

    Attributes:
        kind: what an item is, for messages (``"scene format"``).
        item_type: the class every item is an instance of (it has a ``name: str``).
        package: the package whose modules are the built-in formats (``"abcgs.sources.formats"``).
        attribute: the module attribute that holds a format's item (``"READER"``).
        order: the sort key of :meth:`items` (e.g. detection priority, then name).
        plugins_env: the environment variable naming plugin folders, or ``None`` (built-in and registered only).
        on_change: called after the set of items changed (a cache built from them is cleared).
    """

    kind: str
    item_type: type[T]
    package: str
    attribute: str
    order: Callable[[T], Any]
    plugins_env: str | None = None
    on_change: Callable[[], None] | None = None
    _items: dict[str, T] = field(default_factory=dict, init=False, repr=False)
    _built_in: set[str] = field(default_factory=set, init=False, repr=False)
    _discovered: bool = field(default=False, init=False, repr=False)

    def _discover(self) -> None:
        """Add the item of every module of :attr:`package`, then of the plugin folders (once)."""
        if self._discovered:
            return
        self._discovered = True
        folder = Path(importlib.import_module(self.package).__file__).parent
        for info in sorted(pkgutil.iter_modules([str(folder)]), key=lambda m: m.name):
            module = importlib.import_module(".".join((self.package, info.name)))  # abcgs.dag: Registry's package arg
            item = getattr(module, self.attribute, None)
            if isinstance(item, self.item_type):
                self._add(item)
                self._built_in.add(item.name)
        for plugin_dir in self.plugin_dirs():
            for path in sorted(plugin_dir.glob("*.py")):
                if not path.name.startswith("_"):
                    self._add(self._plugin_item(path))

    def plugin_dirs(self) -> list[Path]:
        """The folders :attr:`plugins_env` names; :class:`InputError` for one that is not a folder."""
        if self.plugins_env is None:
            return []
        dirs = [Path(d) for d in os.environ.get(self.plugins_env, "").split(os.pathsep) if d]
        for d in dirs:
            if not d.is_dir():
                raise InputError(f"{self.plugins_env}: {d} is not a folder; name folders of {self.kind} modules (*.py, "
                                 f"each with a {self.attribute}), separated by {os.pathsep!r}")
        return dirs

    def _plugin_item(self, path: Path) -> T:
        """The item of the plugin module ``path``, imported as ``<plugins_env, lowercase>.<stem>``."""
        name = f"{str(self.plugins_env).lower()}.{path.stem}"
        spec = importlib.util.spec_from_file_location(name, path)
        if spec is None or spec.loader is None:
            raise InputError(f"{self.plugins_env}: {path} cannot be imported as a Python module")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        item = getattr(module, self.attribute, None)
        if not isinstance(item, self.item_type):
            raise InputError(f"{self.plugins_env}: {path} defines no {self.attribute} (a {self.item_type.__module__}."
                             f"{self.item_type.__name__}); define one, or name the file _*.py if it is a helper")
        return item

    def _add(self, item: T) -> None:
        name = item.name  # type: ignore[attr-defined]
        if name in self._items:
            raise ValueError(f"{self.kind} {name!r} is already registered")
        self._items[name] = item
        if self.on_change is not None:
            self.on_change()

    def register(self, item: T) -> None:
        """Add ``item`` at run time (a module of the package or of a plugin folder is found without this); its name
        must be new."""
        self._discover()
        self._add(item)

    def unregister(self, name: str) -> None:
        """Remove the item ``name`` added with :meth:`register` or from a plugin folder (a built-in one stays)."""
        self._discover()
        if name not in self._built_in and self._items.pop(name, None) is not None and self.on_change is not None:
            self.on_change()

    def items(self) -> dict[str, T]:
        """Name → item, sorted by :attr:`order`."""
        self._discover()
        return dict(sorted(self._items.items(), key=lambda kv: self.order(kv[1])))

    def get(self, name: str) -> T | None:
        """The item ``name``, or ``None``."""
        self._discover()
        return self._items.get(name)
