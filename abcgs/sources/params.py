"""The ``data`` section of ``params.yaml``: the scenes (folders, formats, per-scene overrides, trained splats) and the
paintings."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from abcgs.sections import NAME_RE
from abcgs.splats.params import SplatFormatParam, SplatViewsParams
from abcgs.types import Background, SceneFormat


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
    views: SplatViewsParams | None = Field(
        None, description="for a scene that is only a splat (no photos, no cameras): the cameras made around it")

    @model_validator(mode="before")
    @classmethod
    def _path_shorthand(cls, data: Any) -> Any:
        return {"path": data} if isinstance(data, str) else data

    def splat_path(self, folder: str | os.PathLike | None = None) -> Path | None:
        """The splat's path (``splat`` joined to the scene's folder, ``path`` or the given ``folder``, when relative),
        ``None`` when the scene names none."""
        if self.splat is None:
            return None
        p = Path(self.splat)
        return p if p.is_absolute() else Path(self.path if folder is None else folder) / p

    @field_validator("images")
    @classmethod
    def _subfolder(cls, v: str | None) -> str | None:
        if v is not None and (not NAME_RE.fullmatch(v) or v in (".", "..")):
            raise ValueError(f"images: {v!r} must be the name of a subfolder of the scene's folder (e.g. images_8)")
        return v

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
