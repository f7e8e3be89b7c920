"""Checks of the params file's entries that read no input file: their names (a file name the pipeline's own outputs
and stages do not take, :func:`check_names`) and the label numbers a colour match binds (1 … 254,
:func:`check_label_numbers`). :mod:`abcgs.preflight` runs them, and ``add-scene``, ``add-style`` and
``add-experiment`` before they write an entry."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

from abcgs import layout
from abcgs.dvc_file import dvc_stages, stage_outs
from abcgs.errors import InputError
from abcgs.io.images import MAX_LABEL
from abcgs.masks.params import UNDECIDED

MAX_NAME_LENGTH = 100
"""The longest name of a scene, painting, colour match or experiment: each is a file or folder name (``out/<E>/``,
``out/styles/<P>.labels.png``) and a part of longer ones (``<NAME>_<painting>_<method>``, DVC's ``stylize@<E>``);
a name of more than 255 bytes ends a stage in "File name too long"."""
OUT_FOLDER_SECTIONS = ("data.scenes", "experiments")
"""The entries whose outputs lie in a folder ``out/<name>/`` (:func:`abcgs.layout.scene`,
:func:`abcgs.layout.experiment`): they share that folder's names with each other and with the pipeline's own
files under ``out/``."""
STAGE_NAMED_SECTIONS = ("data.scenes", "colormatches", "experiments")
"""The entries that name stages of their own (``fit@<S>``, ``colormatch@<M>``, ``stylize@<E>``)."""


def pipeline_names(dvc_yaml: Path | None) -> tuple[frozenset[str], dict[str, str]]:
    """The stage names of ``dvc.yaml`` and the names that its outputs of a fixed name take directly under ``out/``
    (name → the stage writing it: ``preflight.json``, ``label_use``, ``styles`` …; :mod:`abcgs.layout`'s own too,
    so that they are known without a ``dvc.yaml``)."""
    outputs = {layout.PREFLIGHT_STAMP.name: "preflight", layout.PREFLIGHT_REPORT.name: "preflight",
               layout.LABEL_USE.name: "preflight", layout.STYLES.name: "styles"}
    stages: dict[str, Any] = dvc_stages(dvc_yaml) if dvc_yaml is not None and dvc_yaml.is_file() else {}
    for stage, body in stages.items():
        for p in stage_outs(body):
            parts = Path(p).parts
            if len(parts) >= 2 and parts[0] == layout.OUT.as_posix() and "${" not in parts[1]:
                outputs.setdefault(parts[1], stage)
    return frozenset(stages), outputs


def _shown(text: str) -> str:
    """``text`` for a message: its first 40 characters when it is long."""
    return text if len(text) <= 60 else f"{text[:40]}…"


def name_problem(name: str, section: str, stages: Collection[str] = (),
                 outputs: Mapping[str, str] | None = None) -> str | None:
    """Why ``name`` (already of :data:`abcgs.sections.NAME_PATTERN`) cannot name an entry of ``section``
    (``data.scenes``, ``data.styles``, ``colormatches``, ``experiments`` …), or ``None``: longer than
    :data:`MAX_NAME_LENGTH`; for a scene or an experiment, a name the pipeline's own outputs take under ``out/``
    (``outputs``: :func:`pipeline_names`; DVC refuses overlapping outputs before any stage runs); for an entry with
    stages of its own, the name of a stage (``stages``). Names are compared without case (one file on macOS)."""
    key = f"{section}.{_shown(name)}"
    if len(name) > MAX_NAME_LENGTH:
        return (f"{key}: the name has {len(name)} characters, more than the {MAX_NAME_LENGTH} abcgs takes (it becomes "
                "a file name under out/ and a part of longer ones, and a file system allows 255 bytes); choose a "
                "shorter name")
    folded = name.casefold()
    if section in OUT_FOLDER_SECTIONS:
        for out, stage in (outputs or {}).items():
            if out.casefold() == folded:
                return (f"{key}: its outputs would lie in out/{name}/, but out/{out} is the pipeline's own (stage "
                        f"{stage}), so every dvc repro would stop (output paths overlap, or a path is both a "
                        "dependency and an output); choose another name")
    if section in STAGE_NAMED_SECTIONS and folded in {s.casefold() for s in stages}:
        return (f"{key}: {name} is the name of a pipeline stage (dvc.yaml), so dvc repro {name} would run that stage, "
                "not this entry's; choose another name")
    return None


def check_names(params, stages: Collection[str] = (), outputs: Mapping[str, str] | None = None) -> None:
    """Every entry's name passes :func:`name_problem`; no two of a section differ only in case (their files are one
    on a case-insensitive file system); no experiment is named as a scene (``out/<name>/point_cloud.spz`` is
    written by both ``export_scene`` and ``export``); no painting's copy ``out/styles/<P>.png`` is another's region
    map ``out/styles/<Q>.labels.png``. Raises :class:`InputError` naming the entry and the fix."""
    named = {"data.scenes": params.data.scenes, "data.styles": params.data.styles,
             "data.style_masks": params.data.style_masks, "experiments": params.experiments,
             "colormatches": params.colormatches}
    for section, entries in named.items():
        seen: dict[str, str] = {}
        for name in entries:
            if (problem := name_problem(name, section, stages, outputs)) is not None:
                raise InputError(problem)
            other = seen.setdefault(name.casefold(), name)
            if other != name:
                raise InputError(f"{section}.{name} and {section}.{other} differ only in case: on a case-insensitive "
                                 "file system (macOS, Windows) their outputs are one file; rename one")
    scenes = {n.casefold(): n for n in params.data.scenes}
    for name in params.experiments:
        if (scene := scenes.get(name.casefold())) is not None:
            raise InputError(f"experiments.{name}: its outputs would lie in out/{name}/, the folder of the scene "
                             f"data.scenes.{scene} (out/{scene}/point_cloud.spz is written by export_scene@{scene} "
                             f"and export@{name}), so every dvc repro would stop (output paths overlap); choose "
                             "another name")
    copies = layout.styles()
    maps = {copies.labels(n).name.casefold(): n for n in params.data.style_masks}
    for name in params.data.styles:
        if (base := maps.get(copies.painting(name).name.casefold())) is not None:
            raise InputError(f"data.styles.{name}: its copy {copies.painting(name)} would be the region map of "
                             f"data.style_masks.{base} ({copies.labels(base)}), so every dvc repro would stop (output "
                             "paths overlap); choose another name")


def _number(n: int) -> str:
    """An integer for a message: its first digits and its length when it is long (the schema parses up to Python's
    4300 digits)."""
    text = str(n)
    return text if len(text) <= 12 else f"{text[:6]}… ({len(text)} digits)"


def label_number_problem(label: int, role: str, shown: str | None = None) -> str | None:
    """Why ``label`` (written ``shown``, if given) cannot be a ``role`` (``content label``, ``painting region``) of
    a label map, or ``None``: label maps number their regions 1 … :data:`abcgs.io.images.MAX_LABEL`."""
    if 1 <= label <= MAX_LABEL:
        return None
    if shown is None or len(shown) > 12:
        shown = _number(label) if shown is None else f"{shown[:6]}… ({len(shown)} digits)"
    return (f"{role} {shown} is outside 1 … {MAX_LABEL}, the labels a label map holds (0 is no label, {UNDECIDED} a "
            "pixel left undecided)")


def check_label_numbers(params) -> None:
    """Every label a colour match binds is one a label map can hold (:func:`label_number_problem`): a compositional
    transfer's content labels (``styles``' keys), an explicit semantic binding's content labels and painting
    regions. Needs no file: the labels are checked against the label maps by :func:`check_bindings`."""
    for name, spec in params.colormatches.items():
        key = f"colormatches.{name}"
        if spec.transfer == "compositional":
            for label in sorted(spec.styles):
                if (problem := label_number_problem(label, "content label")) is not None:
                    raise InputError(f"{key}.styles.{_number(label)}: {problem}; bind labels of the scene's label maps")
        elif spec.transfer == "semantic" and spec.binding != "auto":
            for c_label, s_label in sorted(spec.binding.items()):
                for value, role, where in ((c_label, "content label", "the scene's label maps"),
                                           (s_label, "painting region", f"data.style_masks.{spec.style}")):
                    if (problem := label_number_problem(value, role)) is not None:
                        raise InputError(f"{key}.binding.{_number(c_label)}: {problem}; bind {role}s of {where}")
