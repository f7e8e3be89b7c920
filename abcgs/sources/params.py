"""The ``data`` section of ``params.yaml``: the scenes (folders, formats, per-scene overrides, trained splats) and the
paintings."""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Annotated, Any, Literal, Union

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializeAsAny,
    TypeAdapter,
    ValidationInfo,
    WrapValidator,
    field_validator,
    model_validator,
)

from abcgs.errors import InputError
from abcgs.sources.base import AutoSource, Source
from abcgs.sources.registry import option_models, reader_of
from abcgs.splats.params import SplatFormatParam, SplatViewsParams
from abcgs.types import Background


def _tagged(value: Any, handler: Any, info: ValidationInfo) -> Source:
    """``value`` validated as the options of the format its ``format`` tags: a tagged union of every registered
    reader's options model (:func:`abcgs.sources.registry.option_models`), built when the registry changes; in the
    validation context of the whole (a params file's: the plausible ranges of a bare splat's ``views``)."""
    return _source_adapter(tuple(option_models().values())).validate_python(value, context=info.context)


@functools.lru_cache(maxsize=8)
def _source_adapter(kinds: tuple[type[Source], ...]) -> TypeAdapter:
    return TypeAdapter(Annotated[Union[kinds], Field(discriminator="format")])  # noqa: UP007  (a runtime tuple)


SourceParams = Annotated[SerializeAsAny[Source], WrapValidator(_tagged)]
"""A scene's reading options: a tagged union on ``format``, one options model per registered format (``auto``, the
formats of :mod:`abcgs.sources.formats` and plugin readers); each model is the ``options`` of its reader."""

_MOVED = ("format", "images", "views")
"""Keys of a scene entry that are its format's options (under ``source:``)."""


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
    source: SourceParams = Field(
        default_factory=AutoSource, description="where the cameras come from and the format's options: "
        "{format: auto | photos | colmap | nerfstudio | llff | blender | splat | a plugin's format, ...its options} "
        "(images: the image subfolder of auto, photos, colmap, nerfstudio, llff; views: the cameras made around a bare "
        "splat); auto detects the format from the folder's files (abcgs/sources/detect.py); every format is a reader "
        "module of abcgs/sources/formats/ or of a folder in ABCGS_READERS (abcgs/sources/registry.py)")
    background: tuple[float, float, float] | Literal["transparent"] | None = Field(
        None, description="an object on nothing: RGB in [0, 1] behind it in every render and loss (RGBA views are "
        "composited on it), or transparent (RGBA renders); colour match and stylization then act on the object only "
        "and keep empty space empty. Default: white for blender, black for a bare splat, none (a frame-filling scene) "
        "otherwise (resolved_background)")
    reconstruct: dict[str, Any] = Field(default_factory=dict, description="overrides of `reconstruct` for this scene")
    fit: dict[str, Any] = Field(default_factory=dict, description="overrides of `fit` for this scene")
    masks: dict[str, Any] = Field(default_factory=dict, description="overrides of `masks` for this scene")
    splat: str | None = Field(
        None, description="a trained 3DGS splat (file or INRIA output folder), relative to `path` (so that DVC tracks "
        "it with the scene) or absolute: the fit stage imports it instead of fitting (docs/SPLATS.md)")
    splat_format: SplatFormatParam = Field("auto", description="the splat's format; auto detects it")
    splat_nonfinite: Literal["refuse", "drop"] = Field(
        "refuse", description="Gaussians of the splat with a NaN or infinite value (or a zero quaternion): refuse the "
        "file naming their count, or drop them with a warning and the count")

    @model_validator(mode="before")
    @classmethod
    def _path_shorthand(cls, data: Any) -> Any:
        if isinstance(data, str):
            return {"path": data}
        if isinstance(data, dict) and (moved := [k for k in _MOVED if k in data]):
            opts = {k: data[k] for k in moved}
            opts.setdefault("format", "auto")
            shown = ", ".join(f"{k}: {v}" for k, v in opts.items())
            raise ValueError(f"{', '.join(moved)}: a format's options live in the scene's `source:` section, tagged by "
                             f"the format; write `source: {{{shown}}}` instead")
        if isinstance(data, dict) and isinstance(data.get("source"), dict) and "format" not in data["source"]:
            return {**data, "source": {"format": "auto", **data["source"]}}  # the tag's default
        return data

    @classmethod
    def at(cls, path: str | os.PathLike, fmt: str = "auto") -> SceneParams:
        """The entry of the scene at ``path`` read as ``fmt`` (``auto``: detected), every other setting its default."""
        return cls.model_validate({"path": str(path), "source": {"format": fmt}})

    @property
    def format(self) -> str:
        """The scene's format (``source.format``: a registered reader's name; ``auto``: detected)."""
        return self.source.format

    @property
    def images(self) -> str | None:
        """The image subfolder the format's options name (``None``: the default ``images/``, or a format without one)."""
        return getattr(self.source, "images", None)

    @property
    def views(self) -> SplatViewsParams | None:
        """The cameras made around a bare splat (``source: {format: splat, views: ...}``), else ``None``."""
        return getattr(self.source, "views", None)

    def splat_path(self, folder: str | os.PathLike | None = None) -> Path | None:
        """The splat's path (``splat`` joined to the scene's folder, ``path`` or the given ``folder``, when relative),
        ``None`` when the scene names none."""
        if self.splat is None:
            return None
        p = Path(self.splat)
        return p if p.is_absolute() else Path(self.path if folder is None else folder) / p

    def recorded_splat(self, recorded: str | os.PathLike, folder: str | os.PathLike) -> Path:
        """The splat a scene record (``scene.json``) names, ``recorded``, when it is this entry's splat or lies inside
        the scene's ``folder`` (the file DVC tracks with the scene): the record is read from ``out/``, and a splat it
        names elsewhere would be imported with nothing tracking it. :class:`InputError` otherwise."""
        got = Path(recorded).resolve()
        named = self.splat_path(folder)
        base = Path(folder).resolve()
        if (named is not None and got == named.resolve()) or got == base or got.is_relative_to(base):
            return Path(recorded)
        raise InputError(f"the scene record names the splat {recorded}, which is neither the scene's splat "
                         f"({named}) nor inside its folder {folder}; re-run the reconstruct stage of this scene (dvc "
                         "repro reconstruct@<scene>)")

    def resolved_background(self, fmt: str) -> Background:
        """The scene's :class:`~abcgs.types.Background` when read as ``fmt``: the entry's ``background`` when given
        (an object scene), else the format's default (:meth:`~abcgs.sources.base.SceneReader.default_background`:
        white for ``blender``, NeRF-synthetic's convention, and black for a bare ``splat``, objects both; a
        frame-filling scene on black for the others)."""
        if self.background == "transparent":
            return Background(transparent=True, object=True)
        if self.background is not None:
            return Background(tuple(float(c) for c in self.background), object=True)  # type: ignore[arg-type]
        return reader_of(fmt).default_background()

    @field_validator("background")
    @classmethod
    def _unit_rgb(cls, v):
        if isinstance(v, tuple) and not all(0.0 <= c <= 1.0 for c in v):
            raise ValueError(f"background: {list(v)} must be RGB in [0, 1], e.g. [1, 1, 1] for white")
        return v


def scene_name_problem(name: str) -> str | None:
    """Why ``name`` cannot be a scene's name (``None`` when it can): letters, digits, ``-`` and ``_`` only."""
    if not name.replace("_", "").replace("-", "").isalnum():
        return f"scene name {name!r} must be letters, digits, '-' or '_' (it becomes a folder name)"
    return None


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
            if (problem := scene_name_problem(name)) is not None:
                raise ValueError(problem)
        return v
