"""Benchmark overlays (``eval/params/*.yaml``): a params file's sections laid over the workspace's ``params.yaml``.

The overlay's ``data``, ``colormatches`` and ``experiments`` (:data:`REPLACED`) replace the base params' sections;
every other section is merged into the base key by key. ``${shared}`` in an overlay stands for a data folder given
on the command line (absolute once read). ``python -m eval.bench.experiment`` turns the result into ``dvc exp run``
overrides; ``python -m abcgs.cluster submit --params`` writes it into each job's clone.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from abcgs.errors import ParamsError
from abcgs.params import deep_merge

REPLACED = ("data", "colormatches", "experiments")
"""Overlay sections that replace the base params' instead of merging into them."""


def read_overlay(path: Path, shared: Path | None, option: str = "--shared") -> dict:
    """The overlay at ``path`` with ``${shared}`` replaced by the absolute ``shared`` folder (given as ``option``)."""
    text = path.read_text(encoding="utf-8")
    if "${shared}" in text:
        if shared is None or not shared.is_dir():
            raise ParamsError(f"{path} reads ${{shared}}: pass {option} FOLDER (e.g. ../shared/data); got {shared}")
        text = text.replace("${shared}", str(shared.resolve()))
    return yaml.safe_load(text) or {}


def apply_overlay(base: Mapping[str, Any], overlay: Mapping[str, Any]) -> dict:
    """``base`` params with ``overlay`` applied (the module docstring's rule)."""
    out = dict(base)
    for section, value in overlay.items():
        if section in REPLACED or not isinstance(value, Mapping) or not isinstance(out.get(section), Mapping):
            out[section] = value
        else:
            out[section] = deep_merge(dict(out[section]), dict(value))
    return out
