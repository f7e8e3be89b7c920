"""DVC metrics files: numbers in the metric, everything else in an ``*_info.json`` beside it.

`dvc metrics show` / `dvc metrics diff` / `dvc exp show` print every leaf of a metrics file as a column, so
a metric that also carries provenance (weights paths, hashes, versions, notes) becomes an unreadable table.
A stage therefore writes one record twice: the metrics file keeps only its numeric leaves (ints, floats,
bools; nested dicts kept, lists and strings dropped) and ``<stem>_info.json`` keeps the complete record.
Readers that need names or provenance read the info file (:func:`read_record`: the info file when present,
else the metrics file itself, e.g. for runs written before this split).

What DVC declares as metrics is smaller still: a few headline numbers per scene (:data:`FIT_HEADLINE`) and per
experiment (:data:`EXPERIMENT_HEADLINE`), written by :func:`write_headline` to ``out/<scene>/fit_metrics.json``
and ``out/<exp>/metrics.json``. The full numeric records (per-view scores, timings, counters) stay beside them
as plain outputs, so that ``dvc metrics show`` / ``dvc exp show`` print one readable table.
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


FIT_HEADLINE: dict[str, str] = {"heldout_psnr": "psnr", "heldout_ssim": "ssim", "n_gaussians": "n_gaussians",
                                "fit_minutes": "fit_minutes"}
"""Per scene, headline name → key of the fit record: held-out PSNR/SSIM of the baseline fit (views the fit never
trained on, against the photos), its size and wall time."""
EXPERIMENT_HEADLINE: dict[str, str] = {
    "content_ssim": "ssim", "short_rmse": "short_rmse", "long_rmse": "long_rmse", "short_rmse_floor": "short_rmse_floor",
    "long_rmse_floor": "long_rmse_floor", "short_lpips": "short_lpips", "long_lpips": "long_lpips",
    "gram_distance": "gram_distance", "kid": "kid", "artfid": "artfid", "stylize_minutes": "stylize_minutes"}
OBJECT_HEADLINE: dict[str, str] = {
    "content_ssim_object": "ssim_object", "background_change": "background_change", "silhouette_iou": "silhouette_iou"}
"""An object scene's headline numbers besides :data:`EXPERIMENT_HEADLINE` (:mod:`abcgs.evaluation.objects`); a
frame-filling scene's record has none of them."""
"""Per experiment, headline name → key of the evaluate record: content (SSIM between the original and the stylized
renders), consistency (warp RMSE, the unstylized scene's warp RMSE over the same pairs — the floor the stylized
number is read against — and the perceptual distance), style (Gram distance, KID, ArtFID) and stylization
wall time. ``short_lpips``/``long_lpips``/``kid``/``artfid`` stand for whichever variant was computed (``lpips`` or
``lpips_proxy_vgg``, ``kid_tf_inception``, ``artfid`` or ``artfid_proxy``): :func:`experiment_headline` keeps the
full name, so a proxy never appears under the official one. No headline name is shared with :data:`FIT_HEADLINE`."""


def fit_headline(record: dict[str, Any]) -> dict[str, Any]:
    """The scene's headline numbers from a fit ``metrics.json`` record (``seconds`` → ``fit_minutes``)."""
    values = dict(record)
    if record.get("seconds") is not None:
        values["fit_minutes"] = record["seconds"] / 60.0
    return {name: values[key] for name, key in FIT_HEADLINE.items() if values.get(key) is not None}


def experiment_headline(record: dict[str, Any]) -> dict[str, Any]:
    """The experiment's headline numbers from an evaluate record, under the names that were computed.

    Picks each key of :data:`EXPERIMENT_HEADLINE` (and of :data:`OBJECT_HEADLINE`, for an object scene) by exact key, or for ``short_lpips``/``long_lpips``/``kid``/
    ``artfid`` the first key of the record that starts with it (e.g. ``short_lpips_proxy_vgg``,
    ``kid_tf_inception``, ``artfid_proxy``; the ``_std`` companions are left out)."""
    numbers = {k: v for k, v in record.items()
               if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)}
    out: dict[str, Any] = {}
    for name, want in (EXPERIMENT_HEADLINE | OBJECT_HEADLINE).items():
        if want in numbers:
            out[name] = numbers[want]
            continue
        key = next((k for k in numbers if k.startswith(want + "_") and not k.endswith("_std")), None)
        if key is not None:
            out[key] = numbers[key]
    return out


def write_headline(path: str | os.PathLike, values: dict[str, Any]) -> Path:
    """Write headline numbers as the DVC metric at ``path`` (atomic; numbers only)."""
    write_json(path, numeric_leaves(jsonable(values)))
    return Path(path)


def read_record(metrics_path: str | os.PathLike) -> dict[str, Any]:
    """The complete record behind a metrics file: its ``*_info.json`` when present, else the file itself."""
    p = Path(metrics_path)
    info = info_path(p)
    return json.loads((info if info.is_file() else p).read_text())
