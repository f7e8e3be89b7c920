"""Reading ``dvc.yaml``: its stages, a stage's body (a ``foreach`` stage's ``do``) and the paths it writes. Used by
preflight and by the checks of entry names (:mod:`abcgs.entry_checks`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from abcgs.errors import ParamsError


def dvc_stages(dvc_yaml: Path) -> dict[str, Any]:
    """The ``stages`` mapping of ``dvc.yaml`` (empty when it has none)."""
    try:
        doc = yaml.safe_load(dvc_yaml.read_text(encoding="utf-8")) or {}
    except yaml.YAMLError as exc:
        raise ParamsError(f"{dvc_yaml} is not valid YAML: {exc}") from None
    stages = doc.get("stages") or {}
    return stages if isinstance(stages, dict) else {}


def stage_body(stage: dict) -> dict:
    """The stage definition itself, or the ``do`` body of a ``foreach`` stage."""
    return stage.get("do", stage) if isinstance(stage, dict) else {}


def stage_outs(stage: Any) -> list[str]:
    """The paths a stage's ``outs`` name (templated ones included), as written in ``dvc.yaml``."""
    paths = []
    for entry in stage_body(stage).get("outs", []) or []:
        p = entry if isinstance(entry, str) else next(iter(entry), None) if isinstance(entry, dict) else None
        if isinstance(p, str) and p:
            paths.append(p)
    return paths
