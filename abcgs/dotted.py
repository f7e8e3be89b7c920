"""Dotted keys into nested mappings, and DVC's ``${...}`` interpolation over them.

A params key is written as a path of mapping keys, ``stylize.fast.knn_search``; ``dvc.yaml`` names the same keys
in ``params:`` lists and fills ``${key}``, ``${item.F}`` and ``${section.key}`` into its paths. This module is the one
place that walks such a path (:func:`lookup`, :func:`has_key`, :func:`set_dotted`) and the one place that fills in
``${...}`` as DVC does (:func:`interpolate`).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, MutableMapping
from typing import Any

DVC_VARIABLE = re.compile(r"\$\{\s*([A-Za-z0-9_.]+)\s*\}")
"""A ``${name}`` reference in ``dvc.yaml`` (``name`` is ``key``, ``item``, ``item.F`` or a dotted params key)."""

_MISSING: Any = object()


def lookup(tree: Any, dotted: str, default: Any = _MISSING) -> Any:
    """``tree[a][b][c]`` for ``dotted = "a.b.c"``; ``default`` where a key is missing or a parent is not a mapping,
    :class:`KeyError` (naming ``dotted``) when no default is given."""
    node = tree
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            if default is _MISSING:
                raise KeyError(dotted)
            return default
        node = node[part]
    return node


def has_key(tree: Any, dotted: str) -> bool:
    """Whether ``tree`` holds the dotted key ``dotted`` (its value may be anything, ``None`` included)."""
    try:
        lookup(tree, dotted)
    except KeyError:
        return False
    return True


def set_dotted(tree: MutableMapping[str, Any], dotted: str, value: Any) -> None:
    """``tree[a][b][c] = value`` for ``dotted = "a.b.c"``, creating mappings on the way (``--set`` overrides)."""
    *parents, leaf = dotted.split(".")
    for key in parents:
        tree = tree.setdefault(key, {})
    tree[leaf] = value


def interpolate(text: str, key: Any, item: Any, params: Mapping[str, Any]) -> str:
    """``text`` with ``${key}``, ``${item}``, ``${item.F}`` and ``${section.key}`` (a params key) filled in, as DVC
    fills them in for the ``foreach`` entry ``key: item``. :class:`KeyError` names the first reference that does not
    resolve."""

    def fill(m: re.Match) -> str:
        name = m.group(1)
        try:
            if name == "key":
                return str(key)
            if name == "item":
                return str(item)
            if name.startswith("item."):
                return str(lookup(item, name.removeprefix("item.")))
            return str(lookup(params, name))
        except KeyError:
            raise KeyError(name) from None

    return DVC_VARIABLE.sub(fill, text)
