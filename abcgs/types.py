"""The contracts that several packages share: the modes a setting or argument may take, and the interfaces one
floor of abcgs asks of another (in the spirit of nerfbaselines' ``_types.py``).

Modes are ``typing.Literal``s, as in gsplat: the params schema (pydantic) rejects any other value with the
allowed ones listed, and a function taking one says in its signature what it accepts. Interfaces are
``typing.Protocol``s: what a function needs of an object, satisfied by the classes that have those members. The
records that one package makes and others read are dataclasses here (shapes and units in their docstrings).

The scene contract (:class:`Cameras`, :class:`Scene`) is here too: every scene reader returns a :class:`Scene`, the
``reconstruct`` stage writes it and every later stage reads it back as one.

This module sits on the lowest floor (``tests/test_layers.py``) and imports nothing at run time but ``typing`` and
numpy (and :mod:`abcgs.cameras` when a view is taken out of a batch): the params schema modules use its modes.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol, overload

import numpy as np

if TYPE_CHECKING:  # annotations only: reading params.yaml (the schema modules use this one) loads no torch
    from torch import Tensor

    from abcgs.cameras import Camera


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
    stage that renders reads it from there (:attr:`Scene.background` of :func:`abcgs.sfm.model.read_scene`).

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
CAMERA_MODELS: tuple[tuple[str, int], ...] = (
    ("SIMPLE_PINHOLE", 3), ("PINHOLE", 4), ("SIMPLE_RADIAL", 4), ("RADIAL", 5), ("OPENCV", 8), ("OPENCV_FISHEYE", 8),
    ("FULL_OPENCV", 12), ("FOV", 5), ("SIMPLE_RADIAL_FISHEYE", 4), ("RADIAL_FISHEYE", 5), ("THIN_PRISM_FISHEYE", 12),
    ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
)
"""COLMAP's camera models, indexed by COLMAP's model id: ``(name, number of parameters)``
(https://colmap.github.io/cameras.html)."""
SINGLE_FOCAL_MODELS = frozenset({0, 2, 3, 8, 9})
"""Model ids whose parameters start ``f, cx, cy``; the others start ``fx, fy, cx, cy``."""
PINHOLE_MODEL = 1
"""The model id of a view without distortion (``PINHOLE``)."""
MAX_DISTORTION_PARAMS = 12
"""Columns of :attr:`Cameras.distortion_params`: the most parameters a model has besides focal length(s) and
principal point."""


def camera_model_id(name: str) -> int:
    """COLMAP's id of the camera model ``name``; ``ValueError`` listing the models for another name."""
    for i, (model, _) in enumerate(CAMERA_MODELS):
        if model == name:
            return i
    raise ValueError(f"unknown COLMAP camera model {name!r}; one of {', '.join(m for m, _ in CAMERA_MODELS)}")


def lens_param_count(model_id: int) -> int:
    """How many parameters of model ``model_id`` are not focal length(s) or principal point."""
    return CAMERA_MODELS[model_id][1] - (3 if model_id in SINGLE_FOCAL_MODELS else 4)


@dataclass(frozen=True)
class Distortion:
    """One view's lens as a COLMAP camera model (a view of :class:`Cameras`' ``camera_models`` and
    ``distortion_params`` with its intrinsics).

    Attributes:
        model: COLMAP's model name (``SIMPLE_RADIAL``, ``OPENCV``, ``OPENCV_FISHEYE``, …).
        params: the model's full parameter vector in COLMAP's order (focal length(s) and principal point included),
            in pixels of the view's image as it lies on disk.
    """

    model: str
    params: tuple[float, ...]


@dataclass(frozen=True, eq=False)
class Cameras:
    """A batch of ``C`` calibrated views (nerfbaselines' ``Cameras``; gsplat's batched ``viewmats``/``Ks``).

    Conventions of :mod:`abcgs.cameras`: OpenCV camera axes (x right, y down, z forward), pixel centres at +0.5. The
    arrays are read-only; ``cameras[i]`` is view ``i`` as a :class:`~abcgs.cameras.Camera` (its own copy of row ``i``),
    ``cameras[a:b]`` or ``cameras[index_array]`` a sub-batch; iterating gives the per-view cameras.

    Attributes:
        names: ``(C,)`` the views' names (image file names, unique).
        viewmats: ``(C, 4, 4) float64`` world→camera rigid transforms (world units).
        intrinsics: ``(C, 4) float64`` ``fx, fy, cx, cy`` in pixels of the view's image (the lens model's focal
            length(s) and principal point for a distorted view; ``fx == fy`` for a single-focal model).
        sizes: ``(C, 2) int64`` image ``width, height`` in pixels.
        camera_models: ``(C,) int32`` COLMAP camera model ids (:data:`CAMERA_MODELS`); :data:`PINHOLE_MODEL` (1) for
            a view without distortion.
        distortion_params: ``(C, MAX_DISTORTION_PARAMS) float64`` the model's parameters after focal length(s) and
            principal point, in COLMAP's order (dimensionless), zero-padded (:func:`lens_param_count` are used).
    """

    names: tuple[str, ...]
    viewmats: np.ndarray
    intrinsics: np.ndarray
    sizes: np.ndarray
    camera_models: np.ndarray
    distortion_params: np.ndarray

    def __post_init__(self) -> None:
        c = len(self.names)
        fields = {"viewmats": (np.float64, (c, 4, 4)), "intrinsics": (np.float64, (c, 4)), "sizes": (np.int64, (c, 2)),
                  "camera_models": (np.int32, (c,)), "distortion_params": (np.float64, (c, MAX_DISTORTION_PARAMS))}
        for name, (dtype, shape) in fields.items():
            arr = np.array(getattr(self, name), dtype=dtype)
            if arr.shape != shape:
                raise ValueError(f"Cameras.{name} has shape {arr.shape}; {c} views need {shape}")
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))
        if ((self.camera_models < 0) | (self.camera_models >= len(CAMERA_MODELS))).any():
            raise ValueError(f"Cameras.camera_models holds ids outside 0 .. {len(CAMERA_MODELS) - 1}")

    @classmethod
    def from_list(cls, cameras: Sequence[Camera], distortions: Sequence[Distortion | None] | None = None) -> Cameras:
        """The batch of per-view ``cameras`` (and their lenses, ``None`` = pinhole); a distorted view's intrinsics
        are its lens's focal length(s) and principal point."""
        c = len(cameras)
        distortions = list(distortions) if distortions is not None else [None] * c
        if len(distortions) != c:
            raise ValueError(f"{c} cameras but {len(distortions)} distortions")
        intrinsics = np.array([[cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]] for cam in cameras],
                              np.float64).reshape(c, 4)
        models = np.full(c, PINHOLE_MODEL, np.int32)
        lens = np.zeros((c, MAX_DISTORTION_PARAMS))
        for i, d in enumerate(distortions):
            if d is None:
                continue
            models[i] = camera_model_id(d.model)
            p = np.asarray(d.params, np.float64)
            if len(p) != CAMERA_MODELS[models[i]][1]:
                raise ValueError(f"{cameras[i].name}: a {d.model} lens has {CAMERA_MODELS[models[i]][1]} parameters, "
                                 f"got {len(p)}")
            single = models[i] in SINGLE_FOCAL_MODELS
            intrinsics[i] = (p[0], p[0], p[1], p[2]) if single else p[:4]
            rest = p[3:] if single else p[4:]
            lens[i, : len(rest)] = rest
        return cls(tuple(cam.name for cam in cameras), np.array([cam.viewmat for cam in cameras]).reshape(c, 4, 4),
                   intrinsics, np.array([(cam.width, cam.height) for cam in cameras]).reshape(c, 2), models, lens)

    def __len__(self) -> int:
        return len(self.names)

    @overload
    def __getitem__(self, index: int) -> Camera: ...

    @overload
    def __getitem__(self, index: slice | Sequence[int] | np.ndarray) -> Cameras: ...

    def __getitem__(self, index):
        from abcgs.cameras import Camera

        if isinstance(index, (int, np.integer)):
            i = range(len(self))[index]  # IndexError past the end, negative indices from the end
            fx, fy, cx, cy = self.intrinsics[i]
            K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
            return Camera(self.names[i], K, self.viewmats[i].copy(), int(self.sizes[i, 0]), int(self.sizes[i, 1]))
        idx = np.arange(len(self))[index]
        return Cameras(tuple(self.names[i] for i in idx), self.viewmats[idx], self.intrinsics[idx], self.sizes[idx],
                       self.camera_models[idx], self.distortion_params[idx])

    def __iter__(self) -> Iterator[Camera]:
        return (self[i] for i in range(len(self)))

    @property
    def Ks(self) -> np.ndarray:
        """``(C, 3, 3) float64`` the intrinsics as matrices (zero skew)."""
        K = np.zeros((len(self), 3, 3))
        K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2] = self.intrinsics.T
        K[:, 2, 2] = 1.0
        return K

    @property
    def distorted(self) -> np.ndarray:
        """``(C,) bool``: the views whose model is not a pinhole one."""
        return ~np.isin(self.camera_models, (0, PINHOLE_MODEL))

    def distortion(self, i: int) -> Distortion | None:
        """View ``i``'s lens with its full COLMAP parameter vector, ``None`` for a pinhole view."""
        model = int(self.camera_models[i])
        if not self.distorted[i]:
            return None
        fx, fy, cx, cy = (float(v) for v in self.intrinsics[i])
        head = (fx, cx, cy) if model in SINGLE_FOCAL_MODELS else (fx, fy, cx, cy)
        rest = tuple(float(v) for v in self.distortion_params[i, : lens_param_count(model)])
        return Distortion(CAMERA_MODELS[model][0], head + rest)


@dataclass(frozen=True)
class View:
    """One view of a :class:`Scene` (``scene.views[i]``), for code that handles views one at a time.

    Attributes:
        name: the view's name.
        image_path: its image file.
        camera: its pinhole camera (``scene.cameras[i]``).
        distortion: its lens when it is not a pinhole one, else ``None``.
        mask_path: its mask (non-zero = keep), or ``None``.
    """

    name: str
    image_path: Path
    camera: Camera
    distortion: Distortion | None = None
    mask_path: Path | None = None


@dataclass(frozen=True, eq=False)
class Scene:
    """A scene: batched cameras, their images, optional sparse points and masks (nerfbaselines' ``Dataset``).

    Every scene reader returns one (:mod:`abcgs.sources`: in the dataset's frame, possibly distorted), the
    ``reconstruct`` stage writes one as an undistorted COLMAP model with a ``scene.json`` beside it
    (:func:`abcgs.sfm.model.write_scene`) and every later stage reads it back as one
    (:func:`abcgs.sfm.model.read_scene`: PINHOLE cameras, points always present).

    Attributes:
        cameras: the ``C`` views' :class:`Cameras`, sorted by name.
        image_paths: ``(C,)`` each view's image file.
        points: ``(M, 3) float32`` sparse points in the scene frame (world units), in one canonical order (a COLMAP
            model's: by point id), or ``None`` when the dataset has none (the ``reconstruct`` stage then
            triangulates them).
        colors: ``(M, 3) float32`` their RGB colours in ``[0, 1]``, or ``None`` with ``points``.
        mask_paths: ``(C,)`` each view's mask file or ``None``: a reader's is a keep mask (non-zero = keep,
            nerfstudio's ``mask_path``); a scene read back by :func:`~abcgs.sfm.model.read_scene` names the label map
            the ``reconstruct`` stage wrote for the view (``masks/``, read by the ``masks`` stage).
        alpha_paths: ``(C,)`` each view's alpha map (single-channel PNG, 0 = empty) of an object scene whose images
            came with alpha, else ``None`` (written by the ``reconstruct`` stage beside ``images/``).
        format: the format it was read as (:data:`SceneFormat`).
        frame: ``(4, 4) float64`` similarity from the dataset files' world frame to the scene frame (identity when
            the reader keeps the files' frame).
        background: what the views show where nothing covers a pixel (:class:`Background`), or ``None``: a
            reader's colour is what its transparent pixels are composited on (Blender; given as an RGB triple in
            ``[0, 1]``, it is taken as ``Background(color)``); a scene read back by
            :func:`~abcgs.sfm.model.read_scene` holds the background the ``reconstruct`` stage resolved for it.
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
    mask_paths: tuple[Path | None, ...] | None = None
    alpha_paths: tuple[Path, ...] | None = None
    format: str = "colmap"
    frame: np.ndarray = field(default_factory=lambda: np.eye(4))
    background: Background | None = None
    depth_range: tuple[float, float] | None = None
    notes: tuple[str, ...] = ()
    metadata: dict = field(default_factory=dict)
    splat: Path | None = None

    def __post_init__(self) -> None:
        c = len(self.cameras)
        if self.background is not None and not isinstance(self.background, Background):
            color = tuple(float(v) for v in self.background)
            if len(color) != 3:
                raise ValueError(f"Scene.background is a Background or an RGB triple, got {self.background!r}")
            object.__setattr__(self, "background", Background(color))  # type: ignore[arg-type]
        if self.splat is not None:
            object.__setattr__(self, "splat", Path(self.splat))
        object.__setattr__(self, "image_paths", tuple(Path(p) for p in self.image_paths))
        for name in ("image_paths", "mask_paths", "alpha_paths"):
            value = getattr(self, name)
            if value is not None and len(value) != c:
                raise ValueError(f"Scene.{name} has {len(value)} entries for {c} cameras")
        if (self.points is None) != (self.colors is None):
            raise ValueError("Scene.points and Scene.colors are given together or not at all")
        if self.points is not None and (np.shape(self.points) != np.shape(self.colors) or np.ndim(self.points) != 2
                                        or np.shape(self.points)[1] != 3):
            raise ValueError(f"Scene.points {np.shape(self.points)} and colors {np.shape(self.colors)} must be (M, 3)")

    @classmethod
    def from_views(cls, views: Sequence[View], **fields: Any) -> Scene:
        """The scene of per-view records (sorted by name here), with its other attributes as ``fields``."""
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

    def subset(self, indices: Sequence[int] | np.ndarray) -> Scene:
        """The scene of the views ``indices`` (points and the rest kept)."""
        idx = np.arange(len(self.cameras))[np.asarray(indices, np.int64)]

        def pick(seq):
            return None if seq is None else tuple(seq[i] for i in idx)

        return replace(self, cameras=self.cameras[idx], image_paths=pick(self.image_paths),
                       mask_paths=pick(self.mask_paths), alpha_paths=pick(self.alpha_paths))
