"""DVC metrics files: numbers in the metric, everything else in an ``*_info.json`` beside it.

`dvc metrics show` / `dvc metrics diff` / `dvc exp show` print every leaf of a metrics file as a column, so
a metric that also carries provenance (weights paths, hashes, versions, notes) becomes an unreadable table.
A stage therefore writes one record twice: the metrics file keeps only its numeric leaves (ints, floats,
bools; nested dicts kept, lists and strings dropped) and ``<stem>_info.json`` keeps the complete record.
Readers that need names or provenance read the info file (:func:`read_record`: the info file when present,
else the metrics file itself, e.g. for runs written before this split).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from abcgs.io.atomic import jsonable, write_json


def info_path(metrics_path: str | os.PathLike) -> Path:
    """``out/E/eval.json`` → ``out/E/eval_info.json``."""
    p = Path(metrics_path)
    return p.with_name(f"{p.stem}_info{p.suffix}")


def numeric_leaves(record: Any) -> Any:
    """The numeric part of a JSON-like record: dicts keep their numeric (or non-empty dict) entries."""
    if isinstance(record, dict):
        out = {}
        for k, v in record.items():
            v = numeric_leaves(v)
            if v is not None and v != {}:
                out[k] = v
        return out
    if isinstance(record, bool):
        return record
    if isinstance(record, (int, float)):
        return record if math.isfinite(record) else None
    return None


def write_metrics(path: str | os.PathLike, record: dict[str, Any]) -> Path:
    """Write ``record`` as a DVC metric (numeric leaves, at ``path``) plus its complete ``*_info.json``.

    Both writes are atomic. Returns the info file's path.
    """
    plain = jsonable(record)
    info = info_path(path)
    write_json(info, plain)
    write_json(path, numeric_leaves(plain))
    return info


def read_record(metrics_path: str | os.PathLike) -> dict[str, Any]:
    """The complete record behind a metrics file: its ``*_info.json`` when present, else the file itself."""
    p = Path(metrics_path)
    info = info_path(p)
    return json.loads((info if info.is_file() else p).read_text())
