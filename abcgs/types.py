"""The contracts that several packages share: the modes a setting or argument may take, and the interfaces one
floor of abcgs asks of another (in the spirit of nerfbaselines' ``_types.py``).

Modes are ``typing.Literal``s, as in gsplat: the params schema (pydantic) rejects any other value with the
allowed ones listed, and a function taking one says in its signature what it accepts. Interfaces are
``typing.Protocol``s: what a function needs of an object, satisfied by the classes that have those members. The
records that one package makes and others read are dataclasses here (shapes and units in their docstrings).

This module sits on the lowest floor (``tests/test_layers.py``) and imports nothing at run time but ``typing``: the
params schema modules use its modes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal, Protocol

if TYPE_CHECKING:  # annotations only: reading params.yaml (the schema modules use this one) loads no torch

    import numpy as np
    from torch import Tensor


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

SceneFormat = Literal["photos", "colmap", "nerfstudio", "blender", "llff", "splat"]
"""Where a scene's cameras come from (:mod:`abcgs.sources`): ``photos`` = none (structure from motion finds them),
``colmap`` = a COLMAP model, ``nerfstudio`` = ``transforms.json``, ``blender`` = ``transforms_{train,test}.json``
(NeRF-synthetic), ``llff`` = ``poses_bounds.npy``, ``splat`` = only a splat file (cameras generated around it)."""

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
    stage that renders reads it from there (:func:`abcgs.layout.read_background`).

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
