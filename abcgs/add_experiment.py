"""Adding experiments to ``params.yaml``: a colour match (scene × transfer type × painting) and one experiment per
loss method on it, checked as the preflight checks them, with the command that runs just them.

    python -m abcgs add-experiment garden_starry --scene garden --style starry                     # single
    python -m abcgs add-experiment garden_three --scene garden --style starry kandinsky matisse     # one per painting
    python -m abcgs add-experiment garden_comp --scene garden --styles 1=starry 2=kandinsky         # compositional
    python -m abcgs add-experiment garden_sem --scene garden --style starry --binding 1=3 2=2 3=1  # semantic
    python -m abcgs add-experiment garden_sem --scene garden --style starry --binding auto
    python -m abcgs add-experiment garden_comp --scene garden --styles 1=starry 2=kandinsky --content-weight 2=0.005
    python -m abcgs add-experiment garden_comp --scene garden --styles 1=starry 2=kandinsky --keep 2   # label 2's detail

Names: ``colormatches.<NAME>`` and ``experiments.<NAME>`` for the first ``--method``, ``<NAME>_<method>`` for each
further one (they share the colour match); with several single-transfer paintings, ``<NAME>_<painting>`` in place of
``<NAME>``. The params file is edited as data (:func:`abcgs.add.edit_params`), validated as a whole and checked as
:func:`abcgs.preflight.preflight` checks it (the names, the label numbers, the paintings, the label maps each
transfer binds) before it is written. Labels are given in the digits 0-9 and lie in 1 … 254 (:func:`parse_label`);
a name is one the pipeline can take (:func:`abcgs.entry_checks.name_problem`: at most 100 characters, none of the
pipeline's own outputs or stages).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_args

import yaml

from abcgs.add import check_new_name, edit_params
from abcgs.entry_checks import label_number_problem
from abcgs.errors import InputError
from abcgs.features.params import MAX_LABEL_WEIGHT
from abcgs.io.atomic import write_text
from abcgs.io.images import MAX_LABEL
from abcgs.params import load_params, validate_params
from abcgs.preflight import preflight
from abcgs.types import StyleMethod

METHODS = (*get_args(StyleMethod), "none")
"""An experiment's ``method``: a style loss, or ``none`` (the colour match alone, the baseline that stylizes nothing)."""


@dataclass(frozen=True)
class ExperimentPlan:
    """What :func:`add_experiment` writes: ``colormatches`` and ``experiments`` entries by name, and the stages that
    run just them (``stages``: DVC targets, each experiment's evaluation and export)."""

    colormatches: dict[str, dict]
    experiments: dict[str, dict]

    @property
    def stages(self) -> list[str]:
        return [f"{stage}@{name}" for name in self.experiments for stage in ("evaluate", "export")]

    def command(self) -> str:
        """The ``make repro`` command that regenerates ``dvc.yaml``, runs the preflight and then only these
        experiments' stages (and what they need)."""
        return f'make repro ARGS="{" ".join(self.stages)}"'


ASCII_DIGITS = re.compile(r"[0-9]+")
"""A label number as the command line gives it: the digits 0-9 only (``int()`` would take ``²`` or ``٣``, and fail
on those and on 5000 digits with a traceback)."""


def parse_label(text: str, what: str, word: str, role: str = "label", example: str = "1=starry") -> int:
    """``text`` (a part of the argument ``word`` of option ``what``) as a ``role`` of a label map: a number 1 …
    :data:`~abcgs.io.images.MAX_LABEL` (:func:`abcgs.entry_checks.label_number_problem`) in the digits 0-9."""
    shown = word if len(word) <= 60 else f"{word[:40]}…"
    digits = text.strip()
    if not ASCII_DIGITS.fullmatch(digits):
        digits = digits if len(digits) <= 20 else f"{digits[:12]}… ({len(digits)} characters)"
        raise InputError(f"{what} {shown}: the {role} {digits!r} is not a number in the digits 0-9; write a {role} "
                         f"1 … {MAX_LABEL}, e.g. {example}")
    value = digits.lstrip("0") or "0"
    label = int(value) if len(value) <= 6 else MAX_LABEL + 1  # more digits: out of range, not worth converting
    if (problem := label_number_problem(label, role, digits)) is not None:
        raise InputError(f"{what} {shown}: {problem}; give a {role} 1 … {MAX_LABEL}, e.g. {example}")
    return label


def parse_pairs(words: list[str], what: str) -> dict[int, str]:
    """``["1=starry", "2=kandinsky"]`` → ``{1: "starry", 2: "kandinsky"}``: content labels 1 … 254 in ASCII digits
    (:func:`parse_label`), each once."""
    out: dict[int, str] = {}
    for word in words:
        key, sep, value = word.partition("=")
        if not sep or not value.strip():
            shown = word if len(word) <= 60 else f"{word[:40]}…"
            raise InputError(f"{what} {shown!r}: expected LABEL=VALUE with LABEL a number 1 … {MAX_LABEL}, e.g. "
                             "1=starry")
        label = parse_label(key, what, word, "content label", "1=3" if what == "--binding" else "1=starry")
        if label in out:
            raise InputError(f"{what}: label {label} is given twice")
        out[label] = value.strip()
    return out


def parse_binding(words: list[str] | None) -> dict[int, int] | str | None:
    """``--binding``: ``auto``, or CONTENT=REGION pairs of label numbers (:func:`parse_label`); ``None`` when not
    given."""
    if words is None or words == ["auto"]:
        return None if words is None else "auto"
    return {label: parse_label(region, "--binding", f"{label}={region}", "painting region", "1=3")
            for label, region in parse_pairs(words, "--binding").items()}


def parse_weights(words: list[str] | None, what: str) -> dict[int, float]:
    """``--content-weight`` / ``--structure-weight``: LABEL=λ pairs (:func:`parse_pairs`), each λ a number in
    [0, :data:`~abcgs.features.params.MAX_LABEL_WEIGHT`] (the schema's bound)."""
    out: dict[int, float] = {}
    for label, text in parse_pairs(words or [], what).items():
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not math.isfinite(value) or value < 0:
            raise InputError(f"{what} {label}={text}: the weight is not a number >= 0; write e.g. {label}=0.005")
        if value > MAX_LABEL_WEIGHT:
            raise InputError(f"{what} {label}={text}: the weight is outside [0, {MAX_LABEL_WEIGHT:g}]: a λ of Eq. 8 "
                             "(paper: 0.005 to 2); over 10 000 one term drowns the others")
        out[label] = value
    return out


KEEP_STRUCTURE_WEIGHT = 3000.0
"""λ_st that ``--keep`` gives a content label: on miku's face under Starry Night it raised the face's luminance-gradient
SSIM by 0.15 with every painting's Gram distance within 0.01 (docs/FIDELITY.md "Detail per label")."""


def keep_weights(words: list[str] | None, structure: dict[int, float]) -> dict[int, float]:
    """``--keep L …``: each content label (:func:`parse_label`) whose detail the painting should not wipe gets
    :data:`KEEP_STRUCTURE_WEIGHT` as its λ_st; a label's own ``--structure-weight`` (``structure``) wins. Returns the
    experiments' ``structure_weights``."""
    kept = {parse_label(word, "--keep", word, "content label", "2"): KEEP_STRUCTURE_WEIGHT for word in words or []}
    return {**kept, **structure}


def plan_experiments(name: str, scene: str, *, style: list[str] | None = None, styles: dict[int, str] | None = None,
                     binding: dict[int, int] | str | None = None, methods: list[str] | None = None,
                     content_weights: dict[int, float] | None = None,
                     structure_weights: dict[int, float] | None = None) -> ExperimentPlan:
    """The entries for one transfer: ``styles`` (label → painting) is compositional, ``style`` with a ``binding``
    semantic (one painting), ``style`` alone single (one colour match per painting); each experiment takes
    ``content_weights`` / ``structure_weights`` (content label → its own λ) where given."""
    methods = list(dict.fromkeys(methods or ["fast"]))
    for m in methods:
        if m not in METHODS:
            raise InputError(f"--method {m!r} is not one of {', '.join(METHODS)}")
    if styles and (style or binding is not None):
        raise InputError("--styles (compositional) takes no --style or --binding; give one transfer per experiment")
    if styles:
        matches = {name: {"scene": scene, "transfer": "compositional", "styles": dict(styles)}}
    elif not style:
        raise InputError("give the painting(s): --style NAME (single, or semantic with --binding) or --styles "
                         "1=NAME 2=NAME (compositional); add a painting first with python -m abcgs add-style")
    elif binding is not None:
        if len(style) != 1:
            raise InputError("semantic transfer maps regions of one painting: give one --style with --binding")
        matches = {name: {"scene": scene, "transfer": "semantic", "style": style[0], "binding": binding}}
    else:
        names = [name] if len(style) == 1 else [f"{name}_{s}" for s in style]
        matches = {n: {"scene": scene, "transfer": "single", "style": s} for n, s in zip(names, style)}
    own = {k: dict(v) for k, v in (("content_weights", content_weights), ("structure_weights", structure_weights))
           if v}
    experiments = {(m_name if i == 0 else f"{m_name}_{method}"): {"scene": scene, "colormatch": m_name,
                                                                  "method": method, **own}
                   for m_name in matches for i, method in enumerate(methods)}
    return ExperimentPlan(matches, experiments)


def add_experiment(params_path: str | os.PathLike, plan: ExperimentPlan, *, force: bool = False,
                   dry_run: bool = False) -> list[str]:
    """Check ``plan`` against the params file and write it (``dry_run``: check only); returns the lines to print."""
    params = load_params(params_path)
    if not any(spec["scene"] in params.data.scenes for spec in plan.colormatches.values()):
        scene = next(iter(plan.colormatches.values()))["scene"]
        raise InputError(f"scene {scene!r} is not in data.scenes ({', '.join(params.data.scenes)}); add it first "
                         "with python -m abcgs add-scene")
    for n in plan.experiments:  # first: an experiment's name is the folder out/<name>/ (abcgs.entry_checks.name_problem)
        check_new_name(n, "experiments", params.experiments, force, params_path)
    for n in plan.colormatches:
        check_new_name(n, "colormatches", params.colormatches, force, params_path)

    def edit(doc: Any) -> None:
        for section, entries in (("colormatches", plan.colormatches), ("experiments", plan.experiments)):
            if doc.get(section) is None:
                doc[section] = {}
            for n, entry in entries.items():
                doc[section][n] = entry

    text = edit_params(params_path, edit, write=False)
    raw = yaml.safe_load(text)
    preflight(validate_params(raw, str(params_path)), raw, Path(params_path))  # the files each transfer reads
    if not dry_run:
        write_text(params_path, text)  # the text just checked, written atomically
    return [f"colour match {n}: {spec['transfer']} on {spec['scene']}" for n, spec in plan.colormatches.items()] + [
        f"experiment {n}: {spec['method']} from {spec['colormatch']}" for n, spec in plan.experiments.items()]
