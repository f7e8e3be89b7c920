"""Benchmark overlays (``eval/params/*.yaml``): a params file's sections laid over the workspace's ``params.yaml``.

The overlay's ``data``, ``colormatches`` and ``experiments`` (:data:`REPLACED`) replace the base params' sections;
every other section is merged into the base key by key. ``${shared}`` in an overlay's values stands for a data folder
given on the command line (absolute once read; put into the parsed values, never into the YAML text).
``python -m eval run experiment`` turns the result into ``dvc exp run`` overrides; ``python -m abcgs.cluster
submit --params`` writes it into each job's clone.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from abcgs.errors import ParamsError
from abcgs.sections import deep_merge

REPLACED = ("data", "colormatches", "experiments")
"""Overlay sections that replace the base params' instead of merging into them."""


def read_overlay(path: Path, shared: Path | None, option: str = "--shared", path_option: str = "the overlay") -> dict:
    """The overlay at ``path`` (given as ``path_option``) with ``${shared}`` in its string values replaced by the
    absolute ``shared`` folder (given as ``option``). The file is parsed first and the folder put into the parsed
    strings, so no folder name can change the overlay's structure."""
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ParamsError(f"{path_option} {path}: cannot be read ({exc.strerror or exc})") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        reason = " ".join(str(exc).split())
        raise ParamsError(f"{path_option} {path}: not a YAML params overlay ({reason})") from None
    doc = {} if doc is None else doc
    if not isinstance(doc, Mapping):
        raise ParamsError(f"{path_option} {path}: an overlay is a mapping of params sections, not a "
                          f"{type(doc).__name__}")

    def uses_shared(node: Any) -> bool:
        if isinstance(node, str):
            return "${shared}" in node
        items = node.values() if isinstance(node, Mapping) else node if isinstance(node, list) else ()
        return any(uses_shared(v) for v in items)

    if not uses_shared(doc):
        return dict(doc)
    if shared is None or not shared.is_dir():
        raise ParamsError(f"{path_option} {path} reads ${{shared}}: pass {option} FOLDER (an existing folder, e.g. "
                          f"../shared/data); got {shared}")
    folder = str(shared.resolve())

    def put(node: Any) -> Any:
        if isinstance(node, str):
            return node.replace("${shared}", folder)
        if isinstance(node, Mapping):
            return {k: put(v) for k, v in node.items()}
        if isinstance(node, list):
            return [put(v) for v in node]
        return node

    return put(dict(doc))


def apply_overlay(base: Mapping[str, Any], overlay: Mapping[str, Any]) -> dict:
    """``base`` params with ``overlay`` applied (the module docstring's rule)."""
    out = dict(base)
    for section, value in overlay.items():
        if section in REPLACED or not isinstance(value, Mapping) or not isinstance(out.get(section), Mapping):
            out[section] = value
        else:
            out[section] = deep_merge(dict(out[section]), dict(value))
    return out
