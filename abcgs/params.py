"""The ``params.yaml`` schema and its loader.

Every stage validates the whole file before it does any work, so a typo anywhere fails fast with the
key's path, what was wrong and the allowed keys or values:

    params.yaml: fit.iteratons: unknown key; allowed keys here: iterations, sh_degree, ...

Each section's model lives in a ``params`` module of the package it configures (``abcgs/fit/params.py``,
``abcgs/stylize/params.py``, …), which imports nothing but pydantic; this module only assembles them.
"""

from __future__ import annotations

import os
import re
import typing
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from abcgs.errors import ParamsError
from abcgs.evaluation.params import EvalParams
from abcgs.features.params import ExperimentParams, IsolationParams, TransferSpec, VggWeightsParams
from abcgs.fit.params import FitParams
from abcgs.masks.params import MaskParams
from abcgs.scene.params import TinySceneParams
from abcgs.sfm.params import ReconstructParams
from abcgs.splats.params import SplatFormatParam, SplatViewsParams
from abcgs.stylize.params import ColorMatchParams, StylizeParams
from abcgs.types import Device, SceneFormat
from abcgs.view.params import ViewerParams

SCENE_SECTIONS = ("reconstruct", "fit", "masks")
NAME_PATTERN = r"[A-Za-z0-9][A-Za-z0-9_.-]*"
"""Names of scenes, styles, colour matches and experiments: folder names and DVC stage names, never shell syntax."""
NAME_RE = re.compile(NAME_PATTERN)
"""Sections a scene may override in ``data.scenes.<name>``: the stages that run once per scene."""


class SceneParams(BaseModel):
    """``data.scenes.<name>``: the scene's folder, its format, and its overrides of the per-scene sections.

    ``{path: data/fern, fit: {iterations: 3000}}`` fits this scene for 3000 steps and every other scene with
    the global ``fit``. An override is a partial section, merged key by key (nested mappings too) over the
    global one and validated as a whole: :meth:`Params.scene_section`. DVC tracks ``data.scenes.<name>`` for
    that scene's stages only, so changing one scene's override re-runs that scene's branch alone.
    A plain path is accepted as short for ``{path: ...}`` by the library; ``dvc.yaml`` reads ``${item.path}``,
    so ``params.yaml`` writes the mapping (checked before any stage: :mod:`abcgs.preflight`).
    """

    model_config = ConfigDict(extra="forbid")

    path: str = Field(description="the scene's folder: photos in images/ (and optional masks/ with label PNGs of the "
                      "same stem), or a dataset with its cameras (sparse/0/, transforms.json, transforms_train.json, "
                      "poses_bounds.npy; abcgs/sources)")
    format: Literal["auto", SceneFormat] = Field(
        "auto", description="where the cameras come from; auto = detected from the folder's files (abcgs/sources/detect.py)")
    images: str | None = Field(
        None, description="image subfolder (default images/), e.g. images_8 beside a full-size COLMAP model or LLFF poses")
    background: tuple[float, float, float] | None = Field(
        None, description="RGB in [0, 1] that RGBA views are composited on (blender; default white)")
    reconstruct: dict[str, Any] = Field(default_factory=dict, description="overrides of `reconstruct` for this scene")
    fit: dict[str, Any] = Field(default_factory=dict, description="overrides of `fit` for this scene")
    masks: dict[str, Any] = Field(default_factory=dict, description="overrides of `masks` for this scene")
    splat: str | None = Field(
        None, description="a trained 3DGS splat (file or INRIA output folder), relative to `path` (so that DVC tracks "
        "it with the scene) or absolute: the fit stage imports it instead of fitting (docs/SPLATS.md)")
    splat_format: SplatFormatParam = Field("auto", description="the splat's format; auto detects it")
    views: SplatViewsParams | None = Field(
        None, description="for a scene that is only a splat (no photos, no cameras): the cameras made around it")

    @model_validator(mode="before")
    @classmethod
    def _path_shorthand(cls, data: Any) -> Any:
        return {"path": data} if isinstance(data, str) else data

    def splat_path(self) -> Path | None:
        """The splat's path (``splat`` joined to ``path`` when relative), ``None`` when the scene names none."""
        if self.splat is None:
            return None
        p = Path(self.splat)
        return p if p.is_absolute() else Path(self.path) / p

    @field_validator("images")
    @classmethod
    def _subfolder(cls, v: str | None) -> str | None:
        if v is not None and (not NAME_RE.fullmatch(v) or v in (".", "..")):
            raise ValueError(f"images: {v!r} must be the name of a subfolder of the scene's folder (e.g. images_8)")
        return v

    @field_validator("background")
    @classmethod
    def _unit_rgb(cls, v: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
        if v is not None and not all(0.0 <= c <= 1.0 for c in v):
            raise ValueError(f"background: {list(v)} must be RGB in [0, 1], e.g. [1, 1, 1] for white")
        return v


def deep_merge(base: dict, override: dict) -> dict:
    """``base`` with ``override``'s keys put in, recursing into mappings present in both (neither is changed)."""
    out = dict(base)
    for k, v in override.items():
        out[k] = deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


class RuntimeParams(BaseModel):
    """``runtime:``: how every stage runs, not what it computes (:mod:`abcgs.runtime`)."""

    model_config = ConfigDict(extra="forbid")

    device: Device = Field(
        "auto", description="auto | cpu | cuda: where every stage keeps its tensors (scenes, images, VGG, losses, "
                            "metrics); the renders follow (gsplat on CUDA, the C++ kernels on the CPU)")


class DataParams(BaseModel):
    """Where the scenes and style images are. Paths are relative to the repository root."""

    model_config = ConfigDict(extra="forbid")

    scenes: dict[str, SceneParams] = Field(
        description="scene name → {path: folder with images/ (and optional masks/) or a dataset with cameras, "
        "format, images, background, reconstruct/fit/masks: overrides}"
    )
    styles: dict[str, str] = Field(default_factory=dict, description="style name → painting image file")
    style_masks: dict[str, str] = Field(
        default_factory=dict, description="style name → label PNG of that painting (semantic transfer)"
    )

    @field_validator("scenes")
    @classmethod
    def _some_scene(cls, v: dict[str, SceneParams]) -> dict[str, SceneParams]:
        if not v:
            raise ValueError("at least one scene is needed")
        for name in v:
            if not name.replace("_", "").replace("-", "").isalnum():
                raise ValueError(f"scene name {name!r} must be letters, digits, '-' or '_' (it becomes a folder name)")
        return v


class Params(BaseModel):
    """The whole ``params.yaml``."""

    model_config = ConfigDict(extra="forbid")

    data: DataParams
    runtime: RuntimeParams = Field(default_factory=RuntimeParams)
    tiny: TinySceneParams = Field(default_factory=TinySceneParams)
    reconstruct: ReconstructParams = Field(default_factory=ReconstructParams)
    fit: FitParams = Field(default_factory=FitParams)
    masks: MaskParams = Field(default_factory=MaskParams)
    vgg: VggWeightsParams = Field(default_factory=VggWeightsParams)
    isolation: IsolationParams = Field(default_factory=IsolationParams)
    colormatch: ColorMatchParams = Field(default_factory=ColorMatchParams)
    stylize: StylizeParams = Field(default_factory=StylizeParams)
    evaluate: EvalParams = Field(default_factory=EvalParams)
    viewer: ViewerParams = Field(default_factory=ViewerParams)
    colormatches: dict[str, TransferSpec] = Field(
        default_factory=dict,
        description="colour-matched starts: name → scene, transfer type, painting(s); shared by the experiments naming it",
    )
    experiments: dict[str, ExperimentParams] = Field(
        default_factory=dict, description="stylization runs: name → scene, colormatch (a key of colormatches), loss method"
    )

    def transfer_of(self, experiment: str) -> TransferSpec:
        """The colour match (scene, transfer type, painting(s)) that ``experiment`` stylizes."""
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
        return type(base).model_validate(deep_merge(base.model_dump(), override))

    def scene_path(self, scene: str) -> str:
        return self.data.scenes[scene].path

    @model_validator(mode="after")
    def _cross_check(self) -> Params:
        for name, scene in self.data.scenes.items():
            for section in SCENE_SECTIONS:
                if not getattr(scene, section):
                    continue
                try:
                    self.scene_section(name, section)
                except ValidationError as exc:
                    prefix = f"data.scenes.{name}.{section}"
                    body = format_validation_error(exc, prefix, type(getattr(self, section)))
                    lines = body.splitlines()[1:]
                    raise ValueError(f"{prefix}: the override does not fit `{section}`:\n" + "\n".join(
                        f"    {prefix}.{line.strip()}" for line in lines)) from None
        for section, names in (("data.scenes", self.data.scenes), ("data.styles", self.data.styles),
                               ("data.style_masks", self.data.style_masks), ("colormatches", self.colormatches),
                               ("experiments", self.experiments)):
            for name in names:
                if not NAME_RE.fullmatch(str(name)):
                    raise ValueError(f"{section}.{name!r}: a name must match {NAME_PATTERN} (letters, digits, '_', "
                                     "'.', '-'; it becomes a folder name and a DVC stage name); rename it")
        scenes = ", ".join(self.data.scenes)
        for name, spec in self.colormatches.items():
            if spec.scene not in self.data.scenes:
                raise ValueError(f"colormatches.{name}.scene {spec.scene!r} is not in data.scenes ({scenes})")
            for key in spec.style_keys():
                if key not in self.data.styles:
                    raise ValueError(f"colormatches.{name} uses style {key!r}, not in data.styles ({', '.join(self.data.styles)})")
            if spec.transfer == "semantic" and spec.style not in self.data.style_masks:
                raise ValueError(f"colormatches.{name} is semantic but data.style_masks has no label map for {spec.style!r}")
        for name, exp in self.experiments.items():
            if exp.colormatch not in self.colormatches:
                raise ValueError(f"experiments.{name}.colormatch {exp.colormatch!r} is not in colormatches "
                                 f"({', '.join(self.colormatches) or 'none'})")
            start = self.colormatches[exp.colormatch]
            if exp.scene != start.scene:
                raise ValueError(f"experiments.{name}.scene is {exp.scene!r} but its colour match colormatches."
                                 f"{exp.colormatch} is on scene {start.scene!r}; make them the same")
        return self


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
        if typing.get_origin(current) is dict and parts:
            value = typing.get_args(current)[1]
            parts.pop(0)  # the mapping's key (a scene or experiment name)
            current = value
    return current if isinstance(current, type) and issubclass(current, BaseModel) else None


def format_validation_error(exc: ValidationError, source: str, model: type[BaseModel] = Params) -> str:
    lines = [f"{source} does not match the schema ({exc.error_count()} problem(s)):"]
    for err in exc.errors():
        loc = tuple(err["loc"])
        path = ".".join(str(p) for p in loc) or "<top level>"
        if err["type"] == "extra_forbidden":
            owner = _model_at(model, loc)
            allowed = ", ".join(owner.model_fields) if owner else "?"
            lines.append(f"  {path}: unknown key; allowed keys here: {allowed}")
        elif err["type"] == "missing":
            lines.append(f"  {path}: required key is missing")
        else:
            got = err.get("input")
            shown = repr(got)
            # a whole section (e.g. the top-level mapping behind a cross-check) is noise, not the culprit
            tail = "" if isinstance(got, (dict, list)) or len(shown) > 120 else f" (got {shown})"
            msg = err["msg"].removeprefix("Value error, ")
            lines.append(f"  {msg}" if not loc else f"  {path}: {msg}{tail}")
    return "\n".join(lines)


def validate_params(raw: Any, source: str = "params.yaml") -> Params:
    """Validate an already-parsed mapping; raise :class:`ParamsError` with every problem listed."""
    if not isinstance(raw, dict):
        raise ParamsError(f"{source} must be a YAML mapping at the top level, got {type(raw).__name__}")
    try:
        return Params.model_validate(raw)
    except ValidationError as exc:
        raise ParamsError(format_validation_error(exc, source)) from None


def read_params_file(path: str | os.PathLike = "params.yaml") -> Any:
    """The parsed YAML of a params file (not validated), with a clear error when it is missing or not YAML."""
    path = Path(path)
    if not path.is_file():
        raise ParamsError(f"{path} not found; run from the repository root or pass --params")
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ParamsError(f"{path} is not valid YAML: {exc}") from None


def load_params(path: str | os.PathLike = "params.yaml") -> Params:
    """Read and validate ``params.yaml``."""
    return validate_params(read_params_file(path), str(path))
