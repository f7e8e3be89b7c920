"""The sections of ``params.yaml``: where each section's model lives, and a params model made of some of them.

A stage reads a few sections (its :class:`abcgs.pipeline.StageSpec`); :func:`validate_sections` validates exactly
those, importing only their models (:data:`SECTIONS`), so a stage runs no schema code of a section it does not read
and ``dvc.yaml`` lists only those modules (:func:`abcgs.dag.section_files`): editing the viewer's settings module
re-runs only the stages that read ``viewer``. The whole file is validated by :mod:`abcgs.params` (the preflight
stage, which every stage depends on, and the command-line tools), so a typo anywhere still fails before any work:

    params.yaml: fit.iteratons: unknown key; allowed keys here: iterations, sh_degree, ...

A params file's numbers are held to plausible ranges (:class:`Bounded`, each section's ``BOUNDS``): a step count, an
interval, a threshold or a size outside its range is refused naming the key, the range and why, and a soft range (a
long run on purpose) is passed by naming the key in the section's ``unbounded`` list.

Each section's model lives in a ``params`` module of the package it configures (``abcgs/fit/params.py``,
``abcgs/stylize/params.py``, …), which imports nothing heavier than pydantic; ``data`` (the scenes and paintings)
in :mod:`abcgs.sources.params`, ``runtime`` in :mod:`abcgs.runtime`.
"""

from __future__ import annotations

import functools
import importlib
import math
import os
import re
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, create_model, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

from abcgs.errors import InputError, ParamsError
from abcgs.io.guarded import load_yaml

SCENE_SECTIONS = ("reconstruct", "fit", "masks")
"""Sections a scene may override in ``data.scenes.<name>``: the stages that run once per scene."""
NAME_PATTERN = r"[A-Za-z0-9][A-Za-z0-9_.-]*"
"""Names of scenes, styles, colour matches and experiments: folder names and DVC stage names, never shell syntax."""
NAME_RE = re.compile(NAME_PATTERN)

PARAMS_FILE = "abcgs_params_file"
"""Key of the validation context of a params file's values (:data:`FILE_CONTEXT`: :func:`validate_sections`,
:meth:`ParamsBase.scene_section`): there every :class:`Bounded` model holds its numbers to their plausible ranges. A
model built in code (a test's 5-step fit, a benchmark's densify-every-step variant) is not held to them."""
FILE_CONTEXT = {PARAMS_FILE: True}
UNBOUNDED = "unbounded"
"""The key of a section that lists the keys whose soft range (:attr:`Bound.soft`) is passed on purpose."""


@dataclass(frozen=True)
class Bound:
    """The plausible range of one number of a params file: ``lo`` .. ``hi`` (None: open on that side), a float
    finite. ``off``: a value outside the range that turns the setting off (``refine_every: 0``); ``why``: the reason
    the message gives, ``low`` the one for a value under ``lo`` where it differs; ``soft``: an expert may pass the
    range by naming the key in the section's ``unbounded`` list (a long run on purpose). A list or tuple is held
    to it element by element; None (a value chosen later, by the scene) is not checked."""

    lo: float | None = None
    hi: float | None = None
    why: str = ""
    low: str = ""
    soft: bool = False
    off: float | None = None
    unit: str = ""

    def describe(self) -> str:
        """The range in words: ``35 .. 2000000 steps``, ``0 (off) or 10 .. 30000 steps``."""
        def num(v: float) -> str:
            return f"{v:g}" if isinstance(v, float) else str(v)
        if self.lo is not None and self.hi is not None:
            span = f"{num(self.lo)} .. {num(self.hi)}"
        else:
            span = f"at least {num(self.lo)}" if self.lo is not None else f"at most {num(self.hi)}"
        span += f" {self.unit}" if self.unit else ""
        return f"{num(self.off)} (off) or {span}" if self.off is not None else span

    def problem(self, value: Any) -> str | None:
        """Why ``value`` is outside the range, with the range and the reason; None when it is inside."""
        for v in value if isinstance(value, (list, tuple)) else (value,):
            if v is None or isinstance(v, bool) or not isinstance(v, (int, float)):
                continue
            if isinstance(v, float) and not math.isfinite(v):
                return f"must be a finite number, {self.describe()}: {self.why}"
            if self.off is not None and v == self.off:
                continue
            if self.lo is not None and v < self.lo:
                return f"must be {self.describe()}: {self.low or self.why}"
            if self.hi is not None and v > self.hi:
                return f"must be {self.describe()}: {self.why}"
        return None


def unbounded_field() -> Any:
    """The ``unbounded`` field of a :class:`Bounded` section that has soft ranges (declared last, after the keys)."""
    return Field(default_factory=list, description="keys of this section whose soft plausible range is passed on "
                 "purpose, e.g. [iterations] for a run longer than the range (the message of a value outside it "
                 "names the key)")


MAX_THREADS = 1024
"""The most threads a params file asks for: more than the cores of any machine these stages run on."""
SEED = Bound(0, 2**32 - 1, "a seed of numpy's and torch's generators (32 bits, not negative)")
"""The range of every ``seed`` (numpy's ``default_rng`` refuses a negative one)."""
LEARNING_RATE = Bound(0.0, 1.0, "Adam moves each value by about its learning rate every step: at 1 a colour, an "
                      "opacity logit or (x the scene's extent) a position crosses its whole range every step")
"""The range of every ``lr_*`` (the fit's, the stylization's)."""
RESOLUTION_SCALE = Bound(0.01, 1.0, "a fraction of the views' size: under 1 % a 4000-pixel photo is 40 pixels wide")
"""The range of every ``resolution_scale``."""


def from_params_file(info: ValidationInfo) -> bool:
    """Whether a validator runs on a params file's values (:data:`FILE_CONTEXT`), where the plausible ranges hold."""
    return bool((info.context or {}).get(PARAMS_FILE))


class Bounded(BaseModel):
    """A params model whose numbers have plausible ranges, :attr:`BOUNDS` (key → :class:`Bound`). In a params file
    (the :data:`FILE_CONTEXT` validation) a value outside its range is refused naming the key, the range and why:

        fit.iterations: must be 35 .. 2000000 steps: ...; to pass it on purpose, name the key in the section's
        unbounded list: unbounded: [iterations] (got 1000000000000)

    A soft range is passed by listing its key in the section's ``unbounded`` (:func:`unbounded_field`); a key
    listed there without a soft range is refused. :meth:`bounds` may make a range depend on the section's other
    values (``fit.iterations``' floor holds while the fit check's PSNR floor does)."""

    BOUNDS: ClassVar[dict[str, Bound]] = {}

    def bounds(self) -> dict[str, Bound]:
        """The ranges in force for these values (:attr:`BOUNDS`, unless a section says otherwise)."""
        return self.BOUNDS

    @model_validator(mode="after")
    def _within_bounds(self, info: ValidationInfo) -> Bounded:
        if not from_params_file(info):
            return self
        bounds = self.bounds()
        soft = [k for k, b in bounds.items() if b.soft]
        passed = list(getattr(self, UNBOUNDED, None) or ())
        errors: list[InitErrorDetails] = []

        def refuse(loc: tuple, value: Any, reason: str) -> None:
            errors.append(InitErrorDetails(type=PydanticCustomError("plausible_range", "{reason}", {"reason": reason}),
                                           loc=loc, input=value))

        for i, key in enumerate(passed):
            if key not in soft:
                refuse((UNBOUNDED, i), key, f"{key!r} is not a key of this section with a soft range; the keys it "
                       f"can name: {', '.join(soft) or 'none'}")
        for key, bound in bounds.items():
            if bound.soft and key in passed:
                continue
            value = getattr(self, key)
            if (reason := bound.problem(value)) is not None:
                if bound.soft:
                    reason += (f"; to pass it on purpose, name the key in the section's unbounded list: "
                               f"{UNBOUNDED}: [{key}]")
                refuse((key,), value, reason)
        if errors:
            raise ValidationError.from_exception_data(type(self).__name__, errors)
        return self


def deep_merge(base: dict, override: dict) -> dict:
    """``base`` with ``override``'s keys put in, recursing into mappings present in both (neither is changed)."""
    out = dict(base)
    for k, v in override.items():
        out[k] = deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


@dataclass(frozen=True)
class Section:
    """One top-level section of ``params.yaml``: the model class that validates it, named by module and class (the
    module is imported only when a stage reads the section), and whether it is a mapping of named entries."""

    module: str
    model: str
    mapping: bool = False
    required: bool = False
    description: str = ""

    def model_class(self) -> type[BaseModel]:
        return getattr(importlib.import_module(self.module), self.model)

    def file(self) -> str:
        """The model's module as a repository path (``abcgs/fit/params.py``)."""
        return self.module.replace(".", "/") + ".py"


SECTIONS: dict[str, Section] = {
    "data": Section("abcgs.sources.params", "DataParams", required=True),
    "runtime": Section("abcgs.runtime", "RuntimeParams"),
    "tiny": Section("abcgs.scene.params", "TinySceneParams"),
    "reconstruct": Section("abcgs.sfm.params", "ReconstructParams"),
    "fit": Section("abcgs.fit.params", "FitParams"),
    "masks": Section("abcgs.masks.params", "MaskParams"),
    "vgg": Section("abcgs.features.params", "VggWeightsParams"),
    "isolation": Section("abcgs.features.params", "IsolationParams"),
    "colormatch": Section("abcgs.stylize.params", "ColorMatchParams"),
    "stylize": Section("abcgs.stylize.params", "StylizeParams"),
    "evaluate": Section("abcgs.evaluation.params", "EvalParams"),
    "viewer": Section("abcgs.view.params", "ViewerParams"),
    "colormatches": Section(
        "abcgs.features.params", "TransferSpec", mapping=True,
        description="colour-matched starts: name → scene, transfer type, painting(s); shared by the experiments naming it"),
    "experiments": Section(
        "abcgs.features.params", "ExperimentParams", mapping=True,
        description="stylization runs: name → scene, colormatch (a key of colormatches), loss method"),
}
"""Every top-level section of ``params.yaml``, in the file's order."""


class ParamsBase(BaseModel):
    """What every params model (the whole file, or a stage's sections) can answer; a question about a section the
    model does not hold raises ``AttributeError``."""

    model_config = ConfigDict(extra="forbid")

    def transfer_of(self, experiment: str) -> BaseModel:
        """The colour match (scene, transfer type, painting(s): a :class:`abcgs.features.params.TransferSpec`) that
        ``experiment`` stylizes."""
        return self.colormatches[self.experiments[experiment].colormatch]

    def experiment_specs(self) -> dict[str, dict]:
        """Every experiment as one flat record: its colour match's scene/transfer/style(s) and its own fields
        (what reports and tables show)."""
        return {name: {**self.transfer_of(name).model_dump(), **exp.model_dump()}
                for name, exp in self.experiments.items()}

    def scene_section(self, scene: str, section: str) -> BaseModel:
        """The ``section`` (``reconstruct`` | ``fit`` | ``masks``) that ``scene``'s stages use: the global section
        with the scene's override merged in (:func:`deep_merge`) and validated."""
        if section not in SCENE_SECTIONS:
            raise ValueError(f"{section!r} is not a per-scene section ({', '.join(SCENE_SECTIONS)})")
        if scene not in self.data.scenes:
            raise ParamsError(f"scene {scene!r} is not in data.scenes ({', '.join(self.data.scenes)})")
        base = getattr(self, section)
        override = getattr(self.data.scenes[scene], section)
        if not override:
            return base
        return type(base).model_validate(deep_merge(base.model_dump(), override), context=FILE_CONTEXT)

    def scene_path(self, scene: str) -> str:
        return self.data.scenes[scene].path

    def _has(self, *sections: str) -> bool:
        return all(s in type(self).model_fields for s in sections)

    @model_validator(mode="after")
    def _cross_check(self) -> ParamsBase:
        """Checks across sections, each where the model holds the sections it needs."""
        if self._has("data"):
            self._check_scene_overrides()
        self._check_names()
        if self._has("data", "colormatches"):
            self._check_colormatches()
        if self._has("colormatches", "experiments"):
            self._check_experiments()
        return self

    def _check_scene_overrides(self) -> None:
        for name, scene in self.data.scenes.items():
            for section in SCENE_SECTIONS:
                if not getattr(scene, section) or not self._has(section):
                    continue
                try:
                    self.scene_section(name, section)
                except ValidationError as exc:
                    prefix = f"data.scenes.{name}.{section}"
                    body = format_validation_error(exc, prefix, type(getattr(self, section)), at=prefix)
                    lines = body.splitlines()[1:]
                    raise ValueError(f"{prefix}: the override does not fit `{section}`:\n" + "\n".join(
                        f"    {line.strip()}" for line in lines)) from None

    def _check_names(self) -> None:
        named = [("colormatches", getattr(self, "colormatches", {})), ("experiments", getattr(self, "experiments", {}))]
        if self._has("data"):
            named += [("data.scenes", self.data.scenes), ("data.styles", self.data.styles),
                      ("data.style_masks", self.data.style_masks)]
        for section, names in named:
            for name in names:
                if not NAME_RE.fullmatch(str(name)):
                    raise ValueError(f"{section}.{name!r}: a name must match {NAME_PATTERN} (letters, digits, '_', "
                                     "'.', '-'; it becomes a folder name and a DVC stage name); rename it")

    def _check_colormatches(self) -> None:
        scenes = ", ".join(self.data.scenes)
        for name, spec in self.colormatches.items():
            if spec.scene not in self.data.scenes:
                raise ValueError(f"colormatches.{name}.scene {spec.scene!r} is not in data.scenes ({scenes})")
            for key in spec.style_keys():
                if key not in self.data.styles:
                    raise ValueError(f"colormatches.{name} uses style {key!r}, not in data.styles ({', '.join(self.data.styles)})")
            if spec.transfer == "semantic" and spec.style not in self.data.style_masks:
                raise ValueError(f"colormatches.{name} is semantic but data.style_masks has no label map for {spec.style!r}")

    def _check_experiments(self) -> None:
        for name, exp in self.experiments.items():
            if exp.colormatch not in self.colormatches:
                raise ValueError(f"experiments.{name}.colormatch {exp.colormatch!r} is not in colormatches "
                                 f"({', '.join(self.colormatches) or 'none'})")
            start = self.colormatches[exp.colormatch]
            if exp.scene != start.scene:
                raise ValueError(f"experiments.{name}.scene is {exp.scene!r} but its colour match colormatches."
                                 f"{exp.colormatch} is on scene {start.scene!r}; make them the same")


@functools.cache
def params_model(sections: frozenset[str]) -> type[ParamsBase]:
    """A params model holding ``sections`` (top-level names of :data:`SECTIONS`), in the file's order, with the same
    defaults as the whole file's; it imports only those sections' modules."""
    unknown = sorted(sections - SECTIONS.keys())
    if unknown:
        raise ValueError(f"not sections of params.yaml: {unknown}; the sections are {', '.join(SECTIONS)}")
    fields: dict[str, Any] = {}
    for name, sec in SECTIONS.items():
        if name not in sections:
            continue
        model = sec.model_class()
        if sec.mapping:
            fields[name] = (dict[str, model], Field(default_factory=dict, description=sec.description))
        elif sec.required:
            fields[name] = (model, ...)
        else:
            fields[name] = (model, Field(default_factory=model))
    whole = sections == frozenset(SECTIONS)
    return create_model("Params" if whole else "StageParams", __base__=ParamsBase, **fields)


def validate_sections(raw: Any, sections: frozenset[str], source: str = "params.yaml") -> ParamsBase:
    """The ``sections`` of an already-parsed params file, validated (in :data:`FILE_CONTEXT`: every number within its
    plausible range, :class:`Bounded`); :class:`ParamsError` lists every problem. The file's other sections are
    neither read nor validated."""
    if not isinstance(raw, dict):
        raise ParamsError(f"{source} must be a YAML mapping at the top level, got {type(raw).__name__}")
    model = params_model(frozenset(sections))
    whole = frozenset(sections) == frozenset(SECTIONS)  # the whole file: an unknown top-level key is an error too
    try:
        return model.model_validate(raw if whole else {k: v for k, v in raw.items() if k in sections},
                                    context=FILE_CONTEXT)
    except ValidationError as exc:
        raise ParamsError(format_validation_error(exc, source, model)) from None


def _model_at(model: type[BaseModel], loc: tuple[Any, ...]) -> type[BaseModel] | None:
    """The pydantic model class that owns the key at ``loc`` (for listing allowed keys); ``dict[str, Model]``
    fields (``data.scenes``, ``colormatches``, ``experiments``) are followed through their keys."""
    current: Any = model
    parts = list(loc[:-1])
    while parts:
        part = parts.pop(0)
        if isinstance(part, int) or not (isinstance(current, type) and issubclass(current, BaseModel)):
            return None
        field = current.model_fields.get(part)
        if field is None:
            return None
        current = field.annotation
        if parts and (member := _tagged_member(field, parts[0])) is not None:
            parts.pop(0)  # the tag of a tagged union (a scene's source format)
            current = member
        elif typing.get_origin(current) is dict and parts:
            value = typing.get_args(current)[1]
            parts.pop(0)  # the mapping's key (a scene or experiment name)
            current = value
    return current if isinstance(current, type) and issubclass(current, BaseModel) else None


def _tagged_member(field: Any, tag: Any) -> type[BaseModel] | None:
    """The member of a tagged-union field (``Annotated[A | B, Field(discriminator=...)]``, or a field whose type names
    its members itself: a ``tagged_member(tag)`` classmethod, as a scene's ``source`` does for the registered
    formats) whose tag is ``tag``, else None."""
    member_of = getattr(field.annotation, "tagged_member", None)
    if callable(member_of):
        return member_of(tag)
    discriminator = field.discriminator
    if not isinstance(discriminator, str):
        return None
    for member in typing.get_args(field.annotation):
        if isinstance(member, type) and issubclass(member, BaseModel):
            own = member.model_fields.get(discriminator)
            if own is not None and own.default == tag:
                return member
    return None


def format_validation_error(exc: ValidationError, source: str, model: type[BaseModel], at: str = "") -> str:
    """``exc`` as one headline and one line per problem, each led by the dotted path of its key (``at``: the path
    of the validated mapping itself, e.g. a scene's override ``data.scenes.tiny.fit``)."""
    lines = [f"{source} does not match the schema ({exc.error_count()} problem(s)):"]
    for err in exc.errors():
        loc = tuple(err["loc"])
        path = ".".join(str(p) for p in ((at,) if at else ()) + loc) or "<top level>"
        if err["type"] == "extra_forbidden":
            owner = _model_at(model, loc)
            allowed = ", ".join(owner.model_fields) if owner else "?"
            hint = getattr(owner, "unknown_key_hint", lambda key: None)(loc[-1])
            lines.append(f"  {path}: unknown key; allowed keys here: {allowed}" + (f"; {hint}" if hint else ""))
        elif err["type"] == "missing":
            lines.append(f"  {path}: required key is missing")
        else:
            got = err.get("input")
            # a whole section (e.g. the top-level mapping behind a cross-check) is noise, not the culprit
            shown = "" if isinstance(got, (dict, list)) else repr(got)
            tail = "" if not shown or len(shown) > 120 else f" (got {shown})"
            msg = err["msg"].removeprefix("Value error, ")
            lines.append(f"  {path}: {msg}{tail}" if loc else f"  {at}: {msg}" if at else f"  {msg}")
    return "\n".join(lines)


MAX_PARAMS_BYTES = 4 << 20
"""Largest params file read (bytes; the repository's is about 20 KB)."""


def read_params_file(path: str | os.PathLike = "params.yaml") -> Any:
    """The parsed YAML of a params file (not validated), read through :func:`abcgs.io.guarded.load_yaml` (a regular
    file of at most :data:`MAX_PARAMS_BYTES`; depth, alias expansion and number lengths bounded); every problem is
    one :class:`ParamsError` line: missing, not YAML, or past a bound."""
    path = Path(path)
    if not path.exists() and not path.is_symlink():
        raise ParamsError(f"{path} not found; run from the repository root or pass --params")
    try:
        return load_yaml(path, "params file", MAX_PARAMS_BYTES)
    except InputError as exc:
        raise ParamsError(str(exc)) from None


