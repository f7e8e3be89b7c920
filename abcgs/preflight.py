"""Checks that run before any stage does work: what the schema cannot see.

The schema (:mod:`abcgs.params`) checks types, names and cross-references inside ``params.yaml``. This module
checks the params against the two other things a run depends on:

- ``dvc.yaml``: every params key a stage tracks must be present in the params file itself (a default filled in by
  the schema does not count: DVC reads the YAML, and aborts with "Parameters ... are missing" after the earlier
  stages have run). :func:`check_dvc_tracked_keys`.
- the files: every painting and painting label map named in ``data`` exists and decodes; every scene folder
  exists and holds readable images, unless a ``dvc.yaml`` stage produces it (the embedded tiny scene is made by
  ``make_tiny``). :func:`check_input_files`.

:func:`check_scene_entries`: scenes are mappings when ``dvc.yaml`` reads ``${item.path}``.

:func:`preflight` runs them all; :func:`abcgs.pipeline.run_stage` calls it for every stage, and
``python -m abcgs.preflight params.yaml`` (``make run`` does) before ``dvc repro``.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import cv2
import yaml

from abcgs.errors import InputError, ParamsError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")


def _stages(dvc_yaml: Path) -> dict[str, Any]:
    try:
        doc = yaml.safe_load(dvc_yaml.read_text(encoding="utf-8")) or {}
    except yaml.YAMLError as exc:
        raise ParamsError(f"{dvc_yaml} is not valid YAML: {exc}") from None
    stages = doc.get("stages") or {}
    return stages if isinstance(stages, dict) else {}


def _bodies(stage: dict) -> dict:
    """The stage definition itself, or the ``do`` body of a ``foreach`` stage."""
    return stage.get("do", stage) if isinstance(stage, dict) else {}


def dvc_tracked_keys(dvc_yaml: Path) -> dict[str, list[str]]:
    """Dotted params keys of ``params.yaml`` tracked by ``dvc.yaml`` stages → the stages tracking them.

    Templated entries (``experiments.${key}``) are left out: their names come from the params themselves.
    Entries that name another params file (``{other.yaml: [...]}``) are left out too.
    """
    out: dict[str, list[str]] = {}
    for name, stage in _stages(dvc_yaml).items():
        for entry in _bodies(stage).get("params", []) or []:
            if isinstance(entry, str) and "${" not in entry:
                out.setdefault(entry, []).append(name)
    return out


def _has_key(raw: Any, dotted: str) -> bool:
    node = raw
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def check_dvc_tracked_keys(raw: dict, dvc_yaml: Path, source: str = "params.yaml") -> None:
    """Raise :class:`ParamsError` listing every key ``dvc.yaml`` tracks that the params file lacks."""
    missing = {k: v for k, v in dvc_tracked_keys(dvc_yaml).items() if not _has_key(raw, k)}
    if missing:
        lines = [f"{source} lacks key(s) that {dvc_yaml.name} tracks (DVC would stop at those stages after running the "
                 "earlier ones):"]
        for key, stages in sorted(missing.items()):
            parent, _, leaf = key.rpartition(".")
            hint = f"add `{leaf}: {{}}` under `{parent}:`" if parent else f"add a `{leaf}:` section"
            lines.append(f"  {key}: tracked by stage(s) {', '.join(sorted(set(stages)))}; {hint} (empty is fine)")
        raise ParamsError("\n".join(lines))


def check_scene_entries(raw: dict, dvc_yaml: Path, source: str = "params.yaml") -> None:
    """Every ``data.scenes`` entry is a mapping when a ``dvc.yaml`` stage reads ``${item.path}`` from it (DVC
    would stop with "Could not find 'item.path'" before any stage runs)."""
    reads_path = any(
        isinstance(stage, dict) and stage.get("foreach") == "${data.scenes}" and "${item.path}" in yaml.safe_dump(stage)
        for stage in _stages(dvc_yaml).values()
    )
    scenes = ((raw.get("data") or {}).get("scenes") or {}) if isinstance(raw, dict) else {}
    plain = [name for name, v in scenes.items() if isinstance(v, str)] if isinstance(scenes, dict) else []
    if reads_path and plain:
        name = plain[0]
        raise ParamsError(
            f"{source}: data.scenes.{', data.scenes.'.join(plain)}: a plain path; {dvc_yaml.name} reads "
            f"${{item.path}}, so write e.g. `{name}: {{path: {scenes[name]}}}` (a scene is a mapping so that it can "
            "carry per-scene overrides: fit, reconstruct, masks)")


def dvc_outputs(dvc_yaml: Path) -> list[str]:
    """Paths a ``dvc.yaml`` stage writes (``outs``; templated ones left out)."""
    paths = []
    for stage in _stages(dvc_yaml).values():
        for entry in _bodies(stage).get("outs", []) or []:
            p = entry if isinstance(entry, str) else next(iter(entry), None) if isinstance(entry, dict) else None
            if p and "${" not in p:
                paths.append(p)
    return paths


def _produced(path: Path, outputs: Iterable[str], root: Path) -> bool:
    target = (root / path).resolve()
    for out in outputs:
        o = (root / out).resolve()
        if target == o or o in target.parents:
            return True
    return False


def _check_image(path: Path, what: str) -> None:
    if not path.is_file():
        raise InputError(f"{what}: {path} does not exist; fix the path in params.yaml (paths are relative to the "
                         "repository root)")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise InputError(f"{what}: {path} is not a readable image (corrupt or not an image); replace the file")


def check_input_files(params, root: Path, produced: Iterable[str] = ()) -> None:
    """Scene folders and style files named in ``params.data`` exist and decode (see the module docstring)."""
    produced = list(produced)
    for section, entries in (("styles", params.data.styles), ("style_masks", params.data.style_masks)):
        for name, rel in entries.items():
            if not _produced(Path(rel), produced, root):  # e.g. the tiny scene's paintings, made by make_tiny
                _check_image(root / rel, f"data.{section}.{name}")
    for name, scene in params.data.scenes.items():
        rel = scene.path
        folder = root / rel
        if _produced(Path(rel), produced, root):
            continue
        images = folder / "images"
        if not images.is_dir():
            raise InputError(f"data.scenes.{name}: {images} does not exist; a scene folder holds images/ (and "
                             "optionally masks/)")
        files = sorted(p for p in images.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise InputError(f"data.scenes.{name}: {images} holds no images ({', '.join(IMAGE_SUFFIXES)})")
        bad = [p.name for p in files if cv2.imread(str(p), cv2.IMREAD_REDUCED_GRAYSCALE_8) is None]
        if bad:
            raise InputError(f"data.scenes.{name}: {len(bad)} image(s) in {images} do not decode: {', '.join(bad[:5])}"
                             f"{' …' if len(bad) > 5 else ''}; remove or replace them")


def preflight(params, raw: dict, params_path: str | os.PathLike) -> None:
    """Both checks for ``params`` validated from ``raw``, the parsed ``params_path``; ``dvc.yaml`` and the
    repository root are taken from the params file's folder. Without a ``dvc.yaml`` there (a params file used
    outside the pipeline) only the files are checked."""
    params_path = Path(params_path)
    root = params_path.resolve().parent
    dvc_yaml = root / "dvc.yaml"
    produced: list[str] = []
    if dvc_yaml.is_file():
        check_dvc_tracked_keys(raw, dvc_yaml, str(params_path))
        check_scene_entries(raw, dvc_yaml, str(params_path))
        produced = dvc_outputs(dvc_yaml)
    check_input_files(params, root, produced)


def main(argv: list[str] | None = None) -> int:
    """``python -m abcgs.preflight [params.yaml]``: validate the params and run the checks, before ``dvc repro``
    (DVC reads ``dvc.yaml`` templates before any stage, so some mistakes are best caught here)."""
    import sys

    from abcgs.errors import AbcgsError
    from abcgs.params import read_params_file, validate_params

    path = (argv if argv is not None else sys.argv[1:]) or ["params.yaml"]
    try:
        raw = read_params_file(path[0])
        preflight(validate_params(raw, path[0]), raw, path[0])
    except AbcgsError as exc:
        print(f"[preflight] error: {exc}", file=sys.stderr)
        return 2
    print(f"[preflight] {path[0]}: ok")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
