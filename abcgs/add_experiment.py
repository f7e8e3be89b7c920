"""Adding experiments to ``params.yaml``: a colour match (scene × transfer type × painting) and one experiment per
loss method on it, checked as the preflight checks them, with the command that runs just them.

    python -m abcgs add-experiment garden_starry --scene garden --style starry                     # single
    python -m abcgs add-experiment garden_three --scene garden --style starry kandinsky matisse     # one per painting
    python -m abcgs add-experiment garden_comp --scene garden --styles 1=starry 2=kandinsky         # compositional
    python -m abcgs add-experiment garden_sem --scene garden --style starry --binding 1=3 2=2 3=1  # semantic
    python -m abcgs add-experiment garden_sem --scene garden --style starry --binding auto

Names: ``colormatches.<NAME>`` and ``experiments.<NAME>`` for the first ``--method``, ``<NAME>_<method>`` for each
further one (they share the colour match); with several single-transfer paintings, ``<NAME>_<painting>`` in place of
``<NAME>``. The params file is edited as data (:func:`abcgs.add.edit_params`), validated as a whole and checked as
:func:`abcgs.preflight.preflight` checks it (the paintings, the label maps each transfer binds) before it is written.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_args

import yaml

from abcgs.add import check_new_name, edit_params
from abcgs.errors import InputError
from abcgs.io.atomic import write_text
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


def parse_pairs(words: list[str], what: str) -> dict[int, str]:
    """``["1=starry", "2=kandinsky"]`` → ``{1: "starry", 2: "kandinsky"}``: label numbers ≥ 1, each once."""
    out: dict[int, str] = {}
    for word in words:
        key, sep, value = word.partition("=")
        if not sep or not key.strip().isdigit() or int(key) < 1 or not value.strip():
            raise InputError(f"{what} {word!r}: expected LABEL=VALUE with LABEL a number >= 1, e.g. 1=starry")
        if int(key) in out:
            raise InputError(f"{what}: label {int(key)} is given twice")
        out[int(key)] = value.strip()
    return out


def plan_experiments(name: str, scene: str, *, style: list[str] | None = None, styles: dict[int, str] | None = None,
                     binding: dict[int, int] | str | None = None, methods: list[str] | None = None) -> ExperimentPlan:
    """The entries for one transfer: ``styles`` (label → painting) is compositional, ``style`` with a ``binding``
    semantic (one painting), ``style`` alone single (one colour match per painting)."""
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
    experiments = {(m_name if i == 0 else f"{m_name}_{method}"): {"scene": scene, "colormatch": m_name,
                                                                  "method": method}
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
    for n in plan.colormatches:
        check_new_name(n, "colormatches", params.colormatches, force)
    for n in plan.experiments:
        check_new_name(n, "experiments", params.experiments, force)

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
