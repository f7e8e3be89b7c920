"""What a scene reader is: a format's name, how a folder of it is recognised, its options in ``params.yaml`` and its
``read(folder, options)``.

A reader turns a dataset folder into an :class:`abcgs.types.SourceScene` (the reader's half of the scene contract: batched
:class:`~abcgs.cameras.Cameras`, images, optional points and masks):

- its cameras are in the *scene frame* with OpenCV camera axes (x right, y down, z forward), ``viewmats``
  world→camera, intrinsics at the pixel size of the view's image file as it lies on disk (pixel centres at +0.5);
- a view whose lens has distortion carries it as a COLMAP camera model (``Cameras.camera_models`` and
  ``distortion_params``); the ``reconstruct`` stage undistorts it as it undistorts its own SfM model;
- the views are sorted by name (:meth:`abcgs.types.SourceScene.from_views` sorts them);
- the scene frame is the dataset's own world frame up to the similarity :attr:`abcgs.types.SourceScene.frame` that the
  reader undoes (nerfstudio's ``applied_transform`` / ``applied_scale``); nothing is re-centred or re-scaled, so that a
  splat trained on the same dataset lines up with the cameras.

Each reader is the ``READER`` of one module of :mod:`abcgs.sources.formats` (or of a plugin folder,
:mod:`abcgs.sources.registry`). This module imports nothing heavier than numpy and pydantic, and no other module of
:mod:`abcgs.sources`: :mod:`abcgs.preflight` (which every stage imports) and the ``params.yaml`` schema reach it
through the registry, which it does not import (:attr:`Source.registered_options`).
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from abcgs.sections import NAME_RE
from abcgs.types import Background, SourceScene

LOADER_RE = re.compile(r"[a-z_][a-z0-9_]*:[A-Za-z_][A-Za-z0-9_]*")
"""A built-in reader's ``read`` / ``reconstruct`` named as ``"<module of abcgs.sources>:<function>"``."""

CameraSource = Literal["read", "sfm", "made"]
"""Where a format's cameras come from: ``read`` from the dataset (and checked,
:func:`abcgs.sources.validate.check_cameras`), ``sfm`` found by structure from motion from its photos (the reader's
``reconstruct``), ``made`` around the scene by the reader itself (a bare splat's, not checked)."""


@dataclass(frozen=True)
class ReadOptions:
    """What a reader may be told besides the folder; each reader uses the options of its format and ignores the rest.

    Attributes:
        images: the image subfolder (``colmap``, ``llff``, ``nerfstudio``, ``photos``; default ``images``).
        background: RGB in ``[0, 1]`` behind RGBA images (``blender``) and a bare splat's renders.
        views: a :class:`~abcgs.splats.params.SplatViewsParams`: the cameras made around a bare splat.
        work: a folder for what a reader makes: a bare splat's renders (its views' images), a ``photos`` scene's
            structure-from-motion model.
        drop_invalid: drop a bare splat's non-finite Gaussians instead of refusing it.
        source: the scene entry's validated options (``data.scenes.<name>.source``: the format's ``options`` model;
            ``None`` outside the pipeline): where a reader finds options of its own.
    """

    images: str | None = None
    background: tuple[float, float, float] | None = None
    views: Any = None
    work: Path | None = None
    drop_invalid: bool = False
    source: Source | None = None


# ------------------------------------------------------------------------------------------------ options
def image_subfolder(v: str | None) -> str | None:
    """``v`` when it names a subfolder of the scene's folder (or is ``None``); else ``ValueError``."""
    if v is not None and (not NAME_RE.fullmatch(v) or v in (".", "..")):
        raise ValueError(f"images: {v!r} must be the name of a subfolder of the scene's folder (e.g. images_8)")
    return v


class Source(BaseModel):
    """A format's reading options (``data.scenes.<name>.source``), tagged by ``format``: a reader's options model
    subclasses this (or :class:`ImagesSource`) with ``format: Literal["<name>"] = "<name>"``."""

    model_config = ConfigDict(extra="forbid")

    registered_options: ClassVar[Callable[[], dict[str, type[Source]]]] = staticmethod(dict)
    """Format → options model of every registered format, for the hooks below: the registry sets
    :func:`abcgs.sources.registry.option_models` here as it loads, so that this module (which the registry imports)
    imports no registry. The package's face and :mod:`abcgs.sources.params` import the registry, so it is set
    wherever a scene's options are validated; before, no format is known and the hooks answer ``None``."""

    @classmethod
    def unknown_key_hint(cls, key: str) -> str | None:
        """For a key this format does not take: the formats that take it and how to write it
        (:func:`abcgs.sections.format_validation_error`)."""
        takers = [fmt for fmt, kind in cls.registered_options().items() if key in kind.model_fields]
        if not takers:
            return None
        fmt, named = cls.model_fields["format"].default, [t for t in takers if t != "auto"] or takers
        return (f"`{key}` is an option of format {', '.join(named)}, not of {fmt}: remove it, or set "
                f"`source: {{format: {named[0]}, {key}: ...}}` if the scene is of that format")

    @classmethod
    def tagged_member(cls, tag: Any) -> type[BaseModel] | None:
        """The options model of the format ``tag`` (for :func:`abcgs.sections.format_validation_error`, which lists
        the keys it allows)."""
        return cls.registered_options().get(tag) if isinstance(tag, str) else None


class ImagesSource(Source):
    """Options of a format whose images lie in a subfolder (``images``, default ``images/``)."""

    images: str | None = Field(
        None, description="image subfolder (default images/), e.g. images_8 beside a full-size COLMAP model or LLFF poses")

    @field_validator("images")
    @classmethod
    def _subfolder(cls, v: str | None) -> str | None:
        return image_subfolder(v)


class AutoSource(ImagesSource):
    """``source: {format: auto}`` (the default): the format detected from the folder's files
    (:mod:`abcgs.sources.detect`); ``images`` as the detected format's."""

    format: Literal["auto"] = "auto"


# ------------------------------------------------------------------------------------------------ readers
@dataclass(frozen=True)
class SceneReader:
    """One scene format's reader: the ``READER`` of a module of :mod:`abcgs.sources.formats` (found by
    :mod:`abcgs.sources.registry`), or one given to :func:`abcgs.sources.registry.register`.

    Attributes:
        name: the format (``params.yaml``'s ``source: {format: <name>}``, ``add-scene --format``).
        read: ``(folder, options) → SourceScene``, or ``"<module>:<function>"`` naming one of a module of
            :mod:`abcgs.sources` (a built-in format's reading code, loaded when a scene is read:
            :func:`abcgs.sources.read.loaded`; so that the ``params.yaml`` schema, which every stage validates, does
            not import it).
        marker: what a scene of the format is recognised by (for messages: ``sparse/0``, ``transforms.json``).
        detect: whether a folder is of this format: ``detect(folder)`` or ``detect(folder, images)`` (``images``: the
            image subfolder the scene's entry names, default ``images``); ``None``: never detected, only named.
        priority: detection order, lowest first (the built-in formats use 10–60: a dataset with cameras before a
            folder of photos, a bare splat last).
        order: where the format is listed (``--format`` choices, the tags of ``params.yaml``, messages).
        options: its options model (a :class:`Source` subclass tagged ``format: <name>``); ``None``: no options.
        cameras: where its cameras come from (:data:`CameraSource`).
        reconstruct: for ``cameras="sfm"``: ``(folder, out_dir, params, *, images, background, splat) → report``
            (``report.metrics()``, ``report.summary()``; or ``"<module>:<function>"`` as ``read``), the
            ``reconstruct`` stage's COLMAP layout made from the photos; the other formats' scene is read and written
            by :func:`abcgs.sources.model.write_source_model`.
        background: the default of a scene entry without ``background``: RGB of an object on nothing (``blender``
            white, a bare splat black), ``None`` a frame-filling scene.
    """

    name: str
    read: Callable[[Path, ReadOptions], SourceScene] | str
    marker: str
    detect: Callable[..., bool] | None = None
    priority: int = 100
    order: int = 100
    options: type[Source] | None = None
    cameras: CameraSource = "read"
    reconstruct: Callable[..., Any] | str | None = None
    background: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        if not NAME_RE.fullmatch(self.name) or self.name == "auto":
            raise ValueError(f"scene format {self.name!r}: a format's name is letters, digits, _ - . (not auto)")
        if (self.cameras == "sfm") != (self.reconstruct is not None):
            raise ValueError(f"scene format {self.name!r}: a reconstruct is given exactly when cameras='sfm'")
        for target in (self.read, self.reconstruct):
            if isinstance(target, str) and not LOADER_RE.fullmatch(target):
                raise ValueError(f"scene format {self.name!r}: {target!r} is not '<module of abcgs.sources>:<function>'")

    @property
    def check(self) -> bool:
        """Whether the cameras read are checked (:func:`abcgs.sources.validate.check_cameras`): those read from the
        dataset are; those structure from motion finds or the reader makes are not."""
        return self.cameras == "read"

    def detects(self, folder: Path, images: str | None = None) -> bool:
        """Whether :attr:`detect` takes ``folder`` (with the scene entry's image subfolder ``images``)."""
        if self.detect is None:
            return False
        takes_images = len(inspect.signature(self.detect).parameters) >= 2
        return bool(self.detect(folder, images) if takes_images else self.detect(folder))

    def default_background(self) -> Background:
        """The :class:`~abcgs.types.Background` of a scene entry of this format that names none."""
        return Background(self.background, object=True) if self.background is not None else Background()

