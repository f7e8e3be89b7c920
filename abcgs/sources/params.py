"""The ``data`` section of ``params.yaml``: the scenes (folders, formats, per-scene overrides, trained splats) and the
paintings."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from abcgs.sections import NAME_RE
from abcgs.splats.params import SplatFormatParam, SplatViewsParams
from abcgs.types import Background, SceneFormat


def _image_subfolder(v: str | None) -> str | None:
    if v is not None and (not NAME_RE.fullmatch(v) or v in (".", "..")):
        raise ValueError(f"images: {v!r} must be the name of a subfolder of the scene's folder (e.g. images_8)")
    return v


class _Source(BaseModel):
    """A format's reading options (``data.scenes.<name>.source``), tagged by ``format``."""

    model_config = ConfigDict(extra="forbid")

    @classmethod
    def unknown_key_hint(cls, key: str) -> str | None:
        """For a key this format does not take: the formats that take it and how to write it
        (:func:`abcgs.sections.format_validation_error`)."""
        takers = [fmt for fmt, kind in SOURCE_KINDS.items() if key in kind.model_fields]
        if not takers:
            return None
        fmt, named = cls.model_fields["format"].default, [t for t in takers if t != "auto"] or takers
        return (f"`{key}` is an option of format {', '.join(named)}, not of {fmt}: remove it, or set "
                f"`source: {{format: {named[0]}, {key}: ...}}` if the scene is of that format")


class _ImagesSource(_Source):
    images: str | None = Field(
        None, description="image subfolder (default images/), e.g. images_8 beside a full-size COLMAP model or LLFF poses")

    @field_validator("images")
    @classmethod
    def _subfolder(cls, v: str | None) -> str | None:
        return _image_subfolder(v)


class AutoSource(_ImagesSource):
    """``source: {format: auto}`` (the default): the format detected from the folder's files
    (:mod:`abcgs.sources.detect`); ``images`` as the detected format's."""

    format: Literal["auto"] = "auto"


class PhotosSource(_ImagesSource):
    """``source: {format: photos}``: photos without cameras (structure from motion finds them)."""

    format: Literal["photos"] = "photos"


class ColmapSource(_ImagesSource):
    """``source: {format: colmap}``: a COLMAP model (``sparse/0``) and its images."""

    format: Literal["colmap"] = "colmap"


class NerfstudioSource(_ImagesSource):
    """``source: {format: nerfstudio}``: ``transforms.json`` and the images it names (``images``: where they are
    when not where the file says)."""

    format: Literal["nerfstudio"] = "nerfstudio"


class LlffSource(_ImagesSource):
    """``source: {format: llff}``: ``poses_bounds.npy`` and the sorted images of ``images``."""

    format: Literal["llff"] = "llff"


class BlenderSource(_Source):
    """``source: {format: blender}``: NeRF-synthetic's ``transforms_{train,test}.json`` (no options)."""

    format: Literal["blender"] = "blender"


class SplatSource(_Source):
    """``source: {format: splat}``: only a trained splat; ``views``: the cameras made around it."""

    format: Literal["splat"] = "splat"
    views: SplatViewsParams | None = Field(
        None, description="the cameras made around the splat (count, size, field of view, kind)")


SOURCE_KINDS: dict[str, type[_Source]] = {kind.model_fields["format"].default: kind for kind in (
    AutoSource, PhotosSource, ColmapSource, NerfstudioSource, LlffSource, BlenderSource, SplatSource)}
"""Each format's options, by the format's name (``auto`` too)."""
SourceParams = Annotated[AutoSource | PhotosSource | ColmapSource | NerfstudioSource | LlffSource | BlenderSource
                         | SplatSource, Field(discriminator="format")]
"""A scene's reading options: a tagged union on ``format``, one typed section per format."""

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
        "{format: auto | photos | colmap | nerfstudio | llff | blender | splat, ...its options} (images: the image "
        "subfolder of auto, photos, colmap, nerfstudio, llff; views: the cameras made around a bare splat); auto "
        "detects the format from the folder's files (abcgs/sources/detect.py)")
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

    @property
    def format(self) -> Literal["auto"] | SceneFormat:
        """The scene's format (``source.format``; ``auto``: detected)."""
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

    def resolved_background(self, fmt: str) -> Background:
        """The scene's :class:`~abcgs.types.Background` when read as ``fmt``: the entry's ``background`` when given
        (an object scene), else white for ``blender`` (NeRF-synthetic's convention) and black for a bare ``splat``
        (objects both), else a frame-filling scene on black."""
        if self.background == "transparent":
            return Background(transparent=True, object=True)
        if self.background is not None:
            return Background(tuple(float(c) for c in self.background), object=True)  # type: ignore[arg-type]
        if fmt == "blender":
            return Background((1.0, 1.0, 1.0), object=True)
        if fmt == "splat":
            return Background(object=True)
        return Background()

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
