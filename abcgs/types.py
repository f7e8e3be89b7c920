"""The contracts that several packages share: the modes a setting or argument may take, and the interfaces one
floor of abcgs asks of another (in the spirit of nerfbaselines' ``_types.py``).

Modes are ``typing.Literal``s, as in gsplat: the params schema (pydantic) rejects any other value with the
allowed ones listed, and a function taking one says in its signature what it accepts. Interfaces are
``typing.Protocol``s: what a function needs of an object, satisfied by the classes that have those members. The
records that one package makes and others read are dataclasses here (shapes and units in their docstrings).

The scene contract is here too, in two types for its two states: every scene reader returns a :class:`SourceScene`
(the dataset as found: lenses, keep masks, optional points), the ``reconstruct`` stage writes it as an undistorted
layout, and every later stage reads that back as a :class:`CalibratedScene` (pinhole cameras, points, label maps, the
resolved background). The batched cameras and their lenses are in :mod:`abcgs.cameras`.

This module sits on the lowest floor (``tests/test_layers.py``) and imports nothing at run time but ``typing`` and
numpy (and :mod:`abcgs.cameras` when a reader batches its views): the params schema modules use its modes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal, Protocol, TypeVar

import numpy as np

if TYPE_CHECKING:  # annotations only: reading params.yaml (the schema modules use this one) loads no torch
    from torch import Tensor

    from abcgs.cameras import Camera, Cameras, Distortion


# ------------------------------------------------------------------------------------------------ modes
Backend = Literal["auto", "reference", "cpu", "gsplat"]
"""Rasterizer backend (:mod:`abcgs.render.rasterize`): ``reference`` pure PyTorch, ``cpu`` the compiled C++
kernels, ``gsplat`` gsplat on CUDA, ``auto`` gsplat for CUDA tensors and the C++ kernels for CPU tensors."""

RenderMode = Literal["RGB", "RGB+D", "RGB+ED"]
"""What a render returns besides the image (gsplat's names): nothing; the accumulated depth Σ T_i α_i z_i; or the
expected depth, that divided by alpha."""

Device = Literal["auto", "cpu", "cuda"]
"""Where tensors live (``runtime.device``): ``auto`` = the first CUDA GPU when torch sees one, else the CPU."""

StyleMethod = Literal["fast", "nnfm", "knnfm", "gram"]
"""Style loss (:func:`abcgs.losses.terms.style_loss`): ABC-GS's FAST, ARF's NNFM, the k-NN average, Gatys' Gram."""

KnnSearch = Literal["auto", "exact", "bf16"]
"""Nearest-neighbour search over VGG features (:mod:`abcgs.features.knn`): ``exact`` float32 products, ``bf16``
candidates from bfloat16 products re-ranked exactly (the same neighbours), ``auto`` bf16 where it pays."""

CandidateProducts = Literal["auto", "float32", "bfloat16"]
"""Dtype of the projected products that pick the approximate search's candidates (:mod:`abcgs.features.knn`)."""

PathKind = Literal["auto", "spiral", "orbit"]
"""Camera path of the videos and the viewer (:mod:`abcgs.camera_paths`): ``spiral`` for forward-facing captures,
``orbit`` around an object, ``auto`` chosen from the capture's layout."""

SceneFormat = str
"""Where a scene's cameras come from: the name of a registered scene reader (:mod:`abcgs.sources.registry`; the
built-in ones: ``photos`` = none, structure from motion finds them, ``colmap`` = a COLMAP model, ``nerfstudio`` =
``transforms.json``, ``blender`` = ``transforms_{train,test}.json`` (NeRF-synthetic), ``llff`` = ``poses_bounds.npy``,
``splat`` = only a splat file, cameras generated around it)."""

SplatFormat = Literal["inria", "ply", "splatfacto", "gsplat_ckpt", "gsplat_ply", "opensplat", "supersplat", "splat", "spz"]
"""A built-in trained splat file format, one module each of :mod:`abcgs.splats.formats` (tests/test_splats.py checks
that the two agree)."""

FlowMethod = Literal["auto", "raft", "dis", "deepflow", "dualtvl1"]
"""Optical flow of the consistency metrics (:mod:`abcgs.evaluation.consistency`): torchvision's RAFT, OpenCV's
DIS, DeepFlow or Dual TV-L1; ``auto`` = RAFT when its weights are on disk, else DIS."""

VggPrecision = Literal["auto", "float32", "bfloat16"]
"""``evaluate.proxy_precision``: the perceptual proxy's VGG convolutions
(:func:`abcgs.evaluation.content.proxy_precision`)."""


# ------------------------------------------------------------------------------------------------ interfaces
class FlowEstimatorLike(Protocol):
    """Dense optical flow between two renders (:func:`abcgs.evaluation.consistency.make_flow_estimator`)."""

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Flow ``a → b`` of two ``(H, W, 3)`` images: ``(H, W, 2) float32`` px, with ``a(x) ≈ b(x + f(x))``."""
        ...

    def provenance(self) -> dict:
        """What computed the flows (method, implementation, versions), for the evaluation record."""
        ...


class ProjectionSettings(Protocol):
    """The approximate neighbour search's settings (``stylize.fast``; :func:`abcgs.features.knn.projection_of`)."""

    projection_rank: int
    """0: exact search; ``r > 0``: candidates from the features projected on ``r`` principal directions."""
    projection_candidates: int
    """Candidates per feature and direction."""
    projection_min_similarities: int
    """Searches of fewer ``N_r · N_s`` similarities run exactly."""
    projection_products: CandidateProducts
    """Dtype of the projected products."""


# ------------------------------------------------------------------------------------------------ records
@dataclass
class RenderMeta:
    """What a render returns besides the image (:func:`abcgs.render.rasterize`).

    Attributes:
        means2d: ``(N, 2)`` screen positions in px, part of the autograd graph: call ``retain_grad()`` on it
            before ``backward()`` to read the view-space positional gradient the densifier needs (loss per px
            of screen motion on every backend). Rows of the Gaussians that gsplat culls are 0 with the
            gsplat backend.
        radii: ``(N, 2)`` int32 3.33-sigma screen half-extent in px (0 = not rendered).
        depths: ``(N,)`` camera-space z (world units), for every Gaussian.
        visible: ``(N,)`` bool, rendered in this view: in depth range, with a box of alpha ≥ 1/255 that
            overlaps the image.
        depth: ``(H, W, 1)`` expected depth Σ T_i α_i z_i (or normalised by alpha), when requested.
        backend: the backend that produced the image.
        width, height: the image size in px.

    A render of C cameras (batched ``viewmats``) gives every tensor field a leading camera axis: means2d
    ``(C, N, 2)``, radii ``(C, N, 2)``, depths ``(C, N)``, visible ``(C, N)``, depth ``(C, H, W, 1)``.
    """

    means2d: Tensor
    radii: Tensor
    depths: Tensor
    visible: Tensor
    depth: Tensor | None
    backend: Backend
    width: int
    height: int

    def view(self, c: int) -> RenderMeta:
        """View ``c`` of a batched render's meta (the fields of one camera, as an unbatched render returns them)."""
        return RenderMeta(self.means2d[c], self.radii[c], self.depths[c], self.visible[c],
                          None if self.depth is None else self.depth[c], self.backend, self.width, self.height)


@dataclass
class SceneMasks:
    """The masks stage's output read back (:func:`abcgs.masks.outputs.load_scene_masks`).

    Attributes:
        gaussian_labels: ``(N,) int64``: the lifted content label of each Gaussian (0 = none).
        view_labels: per camera, the ``(H, W)`` integer label map of its view.
    """

    gaussian_labels: Tensor
    view_labels: list[np.ndarray]

    def at_rows(self, rows: Tensor) -> SceneMasks:
        """The same masks for a re-fitted scene whose Gaussian ``i`` descends from fitted row ``rows[i]``."""
        return SceneMasks(self.gaussian_labels[rows.to(self.gaussian_labels.device)], self.view_labels)


@dataclass
class MatchingGroup:
    """One matching group Ω^z of a colour match (:func:`abcgs.features.matching.build_groups`).

    Attributes:
        content_label: the content label it styles (``abcgs.features.params.ALL_PIXELS`` = every pixel, a single
            transfer).
        style_name: the painting's key in ``data.styles``.
        style_pixels: ``(M, 3) float32`` RGB in [0, 1] of the painting's region (the colour match's target).
        features: ``(C, N_s)`` VGG features of the region.
        style_image: the painting ``(H, W, 3) float32`` (for reports).
        style_region: ``(H, W) bool``: the painting's region of a semantic group; None otherwise.
    """

    content_label: int
    style_name: str
    style_pixels: np.ndarray
    features: Tensor
    style_image: np.ndarray = field(repr=False, default=None)
    style_region: np.ndarray | None = field(repr=False, default=None)


@dataclass(frozen=True)
class Background:
    """What a scene shows where no Gaussian covers a pixel, and whether that empty space is kept empty.

    The ``reconstruct`` stage resolves it from the scene's entry (``data.scenes.<name>.background``) and its format
    (:meth:`abcgs.sources.params.SceneParams.resolved_background`) and records it beside the scene's model; every
    stage that renders reads it from there (:attr:`CalibratedScene.background` of :func:`abcgs.sfm.model.read_scene`).

    Attributes:
        color: RGB in ``[0, 1]`` composited behind the Gaussians in every render and loss
            (``image + (1 - alpha) · color``).
        transparent: renders are written as RGBA (straight alpha); the composited ``color`` is black.
        object: the scene is an object on nothing: the original scene's own alpha says where the object is, colour
            match and stylization act on the object only, and empty space keeps ``color``
            (:mod:`abcgs.silhouette`). False: a frame-filling scene, every pixel is content.
    """

    color: tuple[float, float, float] = (0.0, 0.0, 0.0)
    transparent: bool = False
    object: bool = False

    def to_json(self) -> dict:
        return {"color": list(self.color), "transparent": self.transparent, "object": self.object}

    @classmethod
    def from_json(cls, d: dict) -> Background:
        color = tuple(float(c) for c in d.get("color", (0.0, 0.0, 0.0)))
        if len(color) != 3:
            raise ValueError(f"a background colour has 3 channels, got {list(color)}")
        return cls(color, bool(d.get("transparent", False)), bool(d.get("object", False)))  # type: ignore[arg-type]


FRAME_FILLING = Background()
"""The background of a frame-filling scene (every pixel is content; renders on black): the default."""


# ------------------------------------------------------------------------------------------------ scenes
@dataclass(frozen=True)
class View:
    """One view of a :class:`SourceScene` (``scene.views[i]``), for code that handles views one at a time.

    Attributes:
        name: the view's name.
        image_path: its image file.
        camera: its pinhole camera (``scene.cameras[i]``).
        distortion: its lens when it is not a pinhole one, else ``None``.
        mask_path: its keep mask (non-zero = keep), or ``None``.
    """

    name: str
    image_path: Path
    camera: Camera
    distortion: Distortion | None = None
    mask_path: Path | None = None


_S = TypeVar("_S", bound="SceneViews")


@dataclass(frozen=True, eq=False)
class SceneViews:
    """What both scene types hold: batched cameras, their images, sparse points, and what the dataset says of itself.

    Attributes:
        cameras: the ``C`` views' :class:`~abcgs.cameras.Cameras`, sorted by name.
        image_paths: ``(C,)`` each view's image file.
        points: ``(M, 3) float32`` sparse points in the scene frame (world units), in one canonical order (a COLMAP
            model's: by point id), or ``None`` (a :class:`SourceScene` without points).
        colors: ``(M, 3) float32`` their RGB colours in ``[0, 1]``, or ``None`` with ``points``.
        alpha_paths: ``(C,)`` each view's alpha map (single-channel PNG, 0 = empty) of an object scene whose images
            came with alpha, else ``None`` (written by the ``reconstruct`` stage beside ``images/``).
        format: the format it was read as (:data:`SceneFormat`).
        frame: ``(4, 4) float64`` similarity from the dataset files' world frame to the scene frame (identity when
            the reader keeps the files' frame).
        depth_range: ``(near, far)`` in world units when the dataset states it (LLFF's bounds), else ``None``.
        notes: what the reader did that the user should know (scaled a model, composited alpha, …), for logs.
        metadata: what a reader records about how it made the scene for code to read (a bare splat's
            ``views_kind``: the kind of cameras made around it); JSON values.
        splat: the trained splat file the scene names (the entry's ``splat:``, or the file of a bare splat), which
            the ``fit`` stage imports instead of fitting, or ``None``.
    """

    cameras: Cameras
    image_paths: tuple[Path, ...]
    points: np.ndarray | None = None
    colors: np.ndarray | None = None
    alpha_paths: tuple[Path, ...] | None = None
    format: str = "colmap"
    frame: np.ndarray = field(default_factory=lambda: np.eye(4))
    depth_range: tuple[float, float] | None = None
    notes: tuple[str, ...] = ()
    metadata: dict = field(default_factory=dict)
    splat: Path | None = None

    PER_VIEW: ClassVar[tuple[str, ...]] = ("image_paths", "alpha_paths")
    """The attributes with one entry per view (:meth:`subset` picks from them)."""

    def __post_init__(self) -> None:
        c = len(self.cameras)
        if self.splat is not None:
            object.__setattr__(self, "splat", Path(self.splat))
        object.__setattr__(self, "image_paths", tuple(Path(p) for p in self.image_paths))
        for name in self.PER_VIEW:
            value = getattr(self, name)
            if value is not None and len(value) != c:
                raise ValueError(f"{type(self).__name__}.{name} has {len(value)} entries for {c} cameras")
        if (self.points is None) != (self.colors is None):
            raise ValueError(f"{type(self).__name__}.points and colors are given together or not at all")
        if self.points is not None and (np.shape(self.points) != np.shape(self.colors) or np.ndim(self.points) != 2
                                        or np.shape(self.points)[1] != 3):
            raise ValueError(f"{type(self).__name__}.points {np.shape(self.points)} and colors "
                             f"{np.shape(self.colors)} must be (M, 3)")

    def subset(self: _S, indices: Sequence[int] | np.ndarray) -> _S:
        """The scene of the views ``indices`` (points and the rest kept)."""
        idx = np.arange(len(self.cameras))[np.asarray(indices, np.int64)]
        picked = {name: None if (seq := getattr(self, name)) is None else tuple(seq[i] for i in idx)
                  for name in self.PER_VIEW}
        return replace(self, cameras=self.cameras[idx], **picked)


@dataclass(frozen=True, eq=False)
class SourceScene(SceneViews):
    """A dataset as its reader found it (nerfbaselines' ``UnloadedDataset``): every scene reader of
    :mod:`abcgs.sources` returns one, in the dataset's frame, its views possibly distorted, with or without points;
    the ``reconstruct`` stage writes it as the undistorted layout of a :class:`CalibratedScene`.

    Attributes (besides :class:`SceneViews`'):
        mask_paths: ``(C,)`` each view's keep mask (non-zero = keep: nerfstudio's ``mask_path``) or ``None``.
        background: the colour the reader composited transparent pixels on (Blender's white), as a
            :class:`Background` (an RGB triple in ``[0, 1]`` is taken as ``Background(color)``), or ``None``.
    """

    mask_paths: tuple[Path | None, ...] | None = None
    background: Background | None = None

    PER_VIEW: ClassVar[tuple[str, ...]] = ("image_paths", "alpha_paths", "mask_paths")

    def __post_init__(self) -> None:
        if self.background is not None and not isinstance(self.background, Background):
            color = tuple(float(v) for v in self.background)
            if len(color) != 3:
                raise ValueError(f"SourceScene.background is a Background or an RGB triple, got {self.background!r}")
            object.__setattr__(self, "background", Background(color))  # type: ignore[arg-type]
        super().__post_init__()

    @classmethod
    def from_views(cls, views: Sequence[View], **fields: Any) -> SourceScene:
        """The scene of per-view records (sorted by name here), with its other attributes as ``fields``."""
        from abcgs.cameras import Cameras

        views = sorted(views, key=lambda v: v.name)
        masks = tuple(v.mask_path for v in views)
        return cls(Cameras.from_list([v.camera for v in views], [v.distortion for v in views]),
                   tuple(v.image_path for v in views), mask_paths=masks if any(m is not None for m in masks) else None,
                   **fields)

    @property
    def views(self) -> tuple[View, ...]:
        """The per-view records, same order as :attr:`cameras`."""
        masks = self.mask_paths or (None,) * len(self.cameras)
        return tuple(View(cam.name, path, cam, self.cameras.distortion(i), mask)
                     for i, (cam, path, mask) in enumerate(zip(self.cameras, self.image_paths, masks)))


@dataclass(frozen=True, eq=False)
class CalibratedScene(SceneViews):
    """The scene every stage after ``reconstruct`` reads (nerfbaselines' ``Dataset``;
    :func:`abcgs.sfm.model.read_scene`): undistorted PINHOLE cameras, sparse points (always), each view's label map
    and the background the ``reconstruct`` stage resolved.

    Attributes (besides :class:`SceneViews`'):
        label_paths: ``(C,)`` each view's label map (``masks/<stem>.png``, 0 = unlabelled, read by the ``masks``
            stage) or ``None``; ``None`` when no view has one.
        background: what the views show where nothing covers a pixel (:class:`Background`).
    """

    label_paths: tuple[Path | None, ...] | None = None
    background: Background = FRAME_FILLING

    PER_VIEW: ClassVar[tuple[str, ...]] = ("image_paths", "alpha_paths", "label_paths")

    def __post_init__(self) -> None:
        if self.points is None:
            raise ValueError("CalibratedScene.points: a calibrated scene has its sparse points (M may be 0)")
        if not isinstance(self.background, Background):
            raise ValueError(f"CalibratedScene.background is a Background, got {self.background!r}")
        super().__post_init__()

    def as_source(self) -> SourceScene:
        """This scene as a reader returns one (the ``photos`` reader's: its cameras found by structure from motion):
        the views, points and records kept, its background as the source's; label maps are no keep masks (left out)."""
        return SourceScene(**{f.name: getattr(self, f.name) for f in fields(SceneViews)}, background=self.background)
