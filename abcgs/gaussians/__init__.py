"""A 3-D Gaussian scene as a plain container of raw (unactivated) parameter tensors.

Parameters are stored the way the optimiser sees them (the 3DGS / gsplat convention):

==================  ==============  ==================================================
field               shape           activation → physical quantity
==================  ==============  ==================================================
``means``           ``(N, 3)``      identity → world position (world units)
``quats``           ``(N, 4)``      normalise → rotation, wxyz
``log_scales``      ``(N, 3)``      ``exp`` → standard deviations (world units)
``opacity_logits``  ``(N,)``        ``sigmoid`` → opacity in ``[0, 1]``
``sh0``             ``(N, 1, 3)``   DC spherical-harmonic coefficient (colour = C0·sh0 + 0.5)
``shN``             ``(N, K-1, 3)`` higher SH bands, ``K = (degree + 1)²`` (``K - 1 = 0`` for degree 0)
==================  ==============  ==================================================

Besides the parameters, ``attributes`` holds any other per-Gaussian tensors, ``(N, ...)`` each and never
optimised (content labels, a mask, a per-Gaussian style id): every operation that selects, copies, splits or
prunes Gaussians applies to them as to the parameters (:meth:`GaussianModel.map`, :mod:`abcgs.fit.strategy.ops`),
so a value stays with its Gaussian and a split's children inherit their parent's. Two names have a meaning:
:data:`FROZEN` (``(N,)`` bool: Gaussians that keep their values, see :func:`freeze_gaussians`) and :data:`FITTED_ROW`
(``(N,)`` int64: the row of the fitted scene each Gaussian descends from, set by the colour match's re-fit).

The densification strategies (:mod:`abcgs.fit.strategy`) replace these tensors in place of the
dataclass fields (``setattr``) when they add or remove Gaussians; nothing else holds on to them.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.io.guarded import load_npy, regular_file
from abcgs.render import RenderMeta, num_sh_bases, rasterize, rgb_to_sh0, sh0_to_rgb
from abcgs.render.rasterize import select_backend
from abcgs.types import Backend

log = logging.getLogger(__name__)
PARAM_NAMES = ("means", "quats", "log_scales", "opacity_logits", "sh0", "shN")
"""Names of the per-Gaussian parameter tensors, in a fixed order (also the optimiser keys)."""
FROZEN = "frozen"
"""Attribute ``(N,)`` bool: Gaussians that keep their values. They take no gradient (:func:`freeze_gaussians`), and
the densification strategy never clones, splits, prunes or resets them."""
FITTED_ROW = "fitted_row"
"""Attribute ``(N,)`` int64: the row of the fitted scene (the ``fit`` stage's PLY) that a Gaussian is or descends from
(a clone or split child carries its parent's): what maps the fitted scene's labels and SH bands onto a re-fitted one."""


@dataclass
class GaussianModel:
    """N Gaussians with raw parameters (see the module docstring for shapes and activations)."""

    means: Tensor
    quats: Tensor
    log_scales: Tensor
    opacity_logits: Tensor
    sh0: Tensor
    shN: Tensor
    attributes: dict[str, Tensor] = field(default_factory=dict)
    """Per-Gaussian tensors that are not parameters (name → ``(N, ...)``), carried through every selection."""

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        for name, value in self.attributes.items():
            if value.dim() == 0 or value.shape[0] != n:
                raise InputError(f"GaussianModel attribute {name!r} has shape {tuple(value.shape)}, expected ({n}, ...)")
        expected = {
            "means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,), "sh0": (n, 1, 3),
        }
        for name, shape in expected.items():
            got = tuple(getattr(self, name).shape)
            if got != shape:
                raise InputError(f"GaussianModel.{name} has shape {got}, expected {shape}")
        shn = tuple(self.shN.shape)
        if len(shn) != 3 or shn[0] != n or shn[2] != 3 or shn[1] + 1 not in (1, 4, 9, 16):
            raise InputError(f"GaussianModel.shN has shape {shn}, expected ({n}, K-1, 3) with K in 1, 4, 9, 16")

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_points(
        cls,
        points: np.ndarray | Tensor,
        colors: np.ndarray | Tensor,
        sh_degree: int = 0,
        init_opacity: float = 0.1,
        *,
        device: torch.device | str = "cpu",
    ) -> GaussianModel:
        """Initial Gaussians at SfM points (3DGS initialisation).

        Args:
            points: ``(M, 3)`` world positions. colors: ``(M, 3)`` RGB in ``[0, 1]``.
            sh_degree: highest SH band kept (0..3); higher bands start at zero.
            init_opacity: initial opacity of every Gaussian, in ``(0, 1)``.

        Isotropic scales are ``sqrt`` of the mean squared distance to the 3 nearest other points
        (``scipy.spatial.cKDTree``; 3DGS's ``distCUDA2``), floored at ``sqrt(1e-7)``; rotations are identity.
        """
        pts = np.asarray(points.detach().cpu() if isinstance(points, Tensor) else points, dtype=np.float64)
        cols = np.asarray(colors.detach().cpu() if isinstance(colors, Tensor) else colors, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] == 0:
            raise InputError(f"need a non-empty (M, 3) array of points to initialise Gaussians, got shape {pts.shape}")
        if cols.shape != pts.shape:
            raise InputError(f"point colours have shape {cols.shape}, expected {pts.shape}")
        if not np.isfinite(pts).all():
            raise InputError("the initial point cloud contains NaN/Inf coordinates")
        if not 0.0 < init_opacity < 1.0:
            raise InputError(f"init_opacity must be in (0, 1), got {init_opacity}")
        n_sh = num_sh_bases(sh_degree)
        m = pts.shape[0]
        if m > 1:
            k = min(4, m)  # the point itself + up to 3 neighbours
            # here, not at module level, where it would slow every stage's start (docs/measurements/settings.yaml)
            from scipy.spatial import cKDTree

            dist, _ = cKDTree(pts).query(pts, k=k)
            dist2 = (dist[:, 1:] ** 2).mean(axis=1)
        else:
            dist2 = np.ones(1)
        dist2 = np.maximum(dist2, 1e-7)
        f32 = dict(dtype=torch.float32, device=device)
        n = m
        quats = torch.zeros(n, 4, **f32)
        quats[:, 0] = 1.0
        return cls(
            means=torch.as_tensor(pts, **f32),
            quats=quats,
            log_scales=torch.as_tensor(np.log(np.sqrt(dist2)), **f32)[:, None].repeat(1, 3),
            opacity_logits=torch.full((n,), math.log(init_opacity / (1.0 - init_opacity)), **f32),
            sh0=rgb_to_sh0(torch.as_tensor(np.clip(cols, 0.0, 1.0), **f32))[:, None, :],
            shN=torch.zeros(n, n_sh - 1, 3, **f32),
        )

    # ------------------------------------------------------------------ properties
    @property
    def num_gaussians(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        """Highest SH band stored (0..3)."""
        return int(round(math.sqrt(self.shN.shape[1] + 1))) - 1

    @property
    def device(self) -> torch.device:
        return self.means.device

    @property
    def scales(self) -> Tensor:
        """``(N, 3)`` standard deviations in world units."""
        return torch.exp(self.log_scales)

    @property
    def opacities(self) -> Tensor:
        """``(N,)`` opacities in ``[0, 1]``."""
        return torch.sigmoid(self.opacity_logits)

    @property
    def rotations(self) -> Tensor:
        """``(N, 4)`` unit quaternions, wxyz."""
        return torch.nn.functional.normalize(self.quats, dim=-1)

    @property
    def sh(self) -> Tensor:
        """``(N, K, 3)`` all SH coefficients."""
        return torch.cat([self.sh0, self.shN], dim=1)

    def activated(self) -> dict[str, Tensor]:
        """Physical quantities: ``means, quats`` (unit), ``scales``, ``opacities``, ``sh``."""
        return {
            "means": self.means, "quats": self.rotations, "scales": self.scales,
            "opacities": self.opacities, "sh": self.sh,
        }

    def colors_or_sh(self, sh_degree: int | None = None, *, rgb_at_degree_0: bool = True,
                     ) -> tuple[Tensor | tuple[Tensor, Tensor], int | None]:
        """What :func:`abcgs.render.rasterize` takes as ``colors`` and ``sh_degree``.

        For an active degree of 0 and ``rgb_at_degree_0`` this is the plain RGB ``(N, 3)`` = ``max(C0·sh0 + 0.5, 0)``
        with ``None`` (identical to SH evaluation, and cheaper where SH is evaluated for every Gaussian); otherwise the
        coefficients as their two blocks ``(sh0, shN)`` (``(N, 1, 3)``, ``(N, K - 1, 3)``: no concatenated copy per
        render) and the degree. The CPU kernels evaluate SH inside the projection for the Gaussians in view only, so
        there the blocks cost less than the RGB's three passes over every Gaussian and their backward (:func:`render`).
        ``sh_degree`` limits the active band (3DGS raises it during training); default: all stored bands.
        """
        degree = self.sh_degree if sh_degree is None else min(int(sh_degree), self.sh_degree)
        if degree == 0 and rgb_at_degree_0:
            return sh0_to_rgb(self.sh0[:, 0, :]).clamp_min(0.0), None
        return (self.sh0, self.shN), degree

    # ------------------------------------------------------------------ tensor plumbing
    def items(self) -> Iterator[tuple[str, Tensor]]:
        """``(name, tensor)`` pairs in :data:`PARAM_NAMES` order."""
        for name in PARAM_NAMES:
            yield name, getattr(self, name)

    def params(self) -> dict[str, Tensor]:
        return dict(self.items())

    def map(self, fn) -> GaussianModel:
        """A new model with ``fn(tensor)`` applied to every parameter and every attribute."""
        return GaussianModel(**{name: fn(t) for name, t in self.items()},
                             attributes={name: fn(t) for name, t in self.attributes.items()})

    def detach(self) -> GaussianModel:
        """A copy of the values without autograd history (new storage)."""
        return self.map(lambda t: t.detach().clone())

    def released(self) -> GaussianModel:
        """The values without autograd history, sharing this model's storage: what an optimisation returns once its
        parameters are no longer used (no copy of the scene at the end of a pass)."""
        return self.map(lambda t: t.detach())

    def to(self, device: torch.device | str) -> GaussianModel:
        return self.map(lambda t: t.to(device))

    def as_parameters(self, trainable: Iterable[str] | None = None) -> GaussianModel:
        """A copy whose fields are leaf ``torch.nn.Parameter`` s (what the optimiser updates). With ``trainable``
        (field names), only those are copied into parameters; the others share this model's storage, detached
        and without gradients (a pass that trains the colours of 3 M Gaussians then copies 36 MB, not 700)."""
        names = set(PARAM_NAMES if trainable is None else trainable)
        return GaussianModel(**{
            name: torch.nn.Parameter(t.detach().clone().contiguous()) if name in names else t.detach()
            for name, t in self.items()
        }, attributes=dict(self.attributes))

    def index(self, mask_or_idx: Tensor) -> GaussianModel:
        """The Gaussians selected by a bool mask or index tensor (detached copies)."""
        return self.map(lambda t: t.detach()[mask_or_idx].clone())

    def invalid_rows(self) -> Tensor:
        """``(N,) bool``: the Gaussians that no renderer can draw, a NaN or infinite value in any parameter or a zero
        quaternion (what a corrupt or hostile file holds; a fit never makes one)."""
        with torch.no_grad():
            bad = torch.zeros(self.num_gaussians, dtype=torch.bool, device=self.means.device)
            for _, t in self.items():
                finite = torch.isfinite(t.detach())
                bad |= ~(finite.flatten(1).all(dim=1) if finite.dim() > 1 else finite)  # 0 rows: nothing to flag
            return bad | (self.quats.detach().abs().sum(dim=1) == 0)


def valid_gaussians(model: GaussianModel, source: str, *, drop: bool = False, setting: str = "splat_nonfinite"
                    ) -> GaussianModel:
    """``model`` when every Gaussian is valid (:meth:`GaussianModel.invalid_rows`); else an :class:`InputError` naming
    ``source`` and the count, or with ``drop`` the model without them and a warning with the count. ``setting``
    names the option that selects ``drop`` in the message."""
    bad = model.invalid_rows()
    k = int(bad.sum())
    if not k:
        return model
    what = f"{source}: {k} of {model.num_gaussians} Gaussians have a NaN or infinite value (or a zero quaternion)"
    if not drop:
        raise InputError(f"{what}; the file is corrupt: re-export it from its tool, or drop them with {setting}: drop")
    if k == model.num_gaussians:
        raise InputError(f"{what}: none is left to drop; the file is corrupt, re-export it from its tool")
    log.warning("%s; dropped them (%s: drop)", what, setting)
    return model.index(~bad)


assert tuple(f.name for f in fields(GaussianModel)) == (*PARAM_NAMES, "attributes")


def fitted_rows(model: GaussianModel) -> Tensor:
    """``(N,)`` int64: each Gaussian's row in the fitted scene, its :data:`FITTED_ROW` attribute; a model without one is
    the fitted scene itself (``arange(N)``)."""
    rows = model.attributes.get(FITTED_ROW)
    return torch.arange(model.num_gaussians, device=model.device) if rows is None else rows


def read_fitted_rows(path: Path, n_gaussians: int, n_fitted: int, fix: str = "") -> np.ndarray:
    """``(n_gaussians,)`` int64 from the ``.npy`` file ``path``: each Gaussian's row in a fitted scene of ``n_fitted``
    Gaussians (:data:`FITTED_ROW`, as the colour match and stylize stages write it), read through
    :func:`abcgs.io.guarded.load_npy`: a regular file (no FIFO, no link to ``/dev/zero``) of integers (no pickle),
    1-D, its row count read from the header and checked against ``n_gaussians`` before anything is allocated, the
    file's size exactly what the header states. Every row must lie in ``[0, n_fitted)``. Rows may repeat (a
    densifying re-fit's clones and split children keep their parent's row), but more than one Gaussian all on one
    row of a fitted scene of several is no re-fit's output (a zero-filled file) and is refused.
    :class:`~abcgs.errors.InputError` in one line naming the file, then ``fix`` (how to write it again)."""
    try:
        regular_file(path, "fitted rows")
    except InputError as exc:  # a FIFO, a device, a folder, a symlink loop: never opened
        raise InputError(f"{exc}; {fix}" if fix else str(exc)) from None
    end = f"it does not map {n_gaussians} Gaussians onto the {n_fitted} fitted ones" + (f"; {fix}" if fix else "")
    rows = load_npy(path, "fitted rows", kinds="iu", ndim=1, max_items=n_gaussians, tail=end)

    def refuse(reason: str) -> InputError:
        return InputError(f"fitted rows {path} {reason}; {end}")

    if len(rows) != n_gaussians:
        raise refuse(f"holds {len(rows)} rows for {n_gaussians} Gaussians")
    if n_gaussians:
        bad = np.flatnonzero((rows < 0) | (rows >= n_fitted))
        if len(bad):
            raise refuse(f"gives row {bad[0]} the fitted row {rows[bad[0]]}, outside 0 .. {n_fitted - 1} "
                         f"({len(bad)} of the {n_gaussians} rows outside it)")
        if n_gaussians > 1 and n_fitted > 1 and rows.min() == rows.max():
            raise refuse(f"puts all {n_gaussians} Gaussians on the one fitted row {rows[0]}: no colour match or "
                         "stylization leaves that (a zero-filled file?)")
    return rows.astype(np.int64)


_FROZEN_HOOK = "_abcgs_frozen_hook"  # set on a tensor that carries freeze_gaussians' gradient hook


def freeze_gaussians(model: GaussianModel, frozen: Tensor | None = None) -> None:
    """Zero every gradient of the frozen ``(N,)`` bool Gaussians of ``model`` (its fields that take gradients): Adam
    then leaves their values exactly as they are, whatever the loss. ``frozen`` defaults to the model's
    :data:`FROZEN` attribute; None or no frozen row freezes nothing. The hooks belong to the current tensors: after a
    densification step replaced some of them, call it again; a tensor that already has its hook gets no second one."""
    frozen = model.attributes.get(FROZEN) if frozen is None else frozen
    if frozen is None or not bool(frozen.any()):
        return
    keep = (~frozen).to(model.device)
    for _, t in model.items():
        if t.requires_grad and not getattr(t, _FROZEN_HOOK, False):
            mask = keep.view((-1,) + (1,) * (t.dim() - 1)).to(t.dtype)
            t.register_hook(lambda g, m=mask: g * m)
            setattr(t, _FROZEN_HOOK, True)


def render(
    model: GaussianModel,
    camera: Camera | Sequence[Camera],
    *,
    backend: Backend = "auto",
    sh_degree: int | None = None,
    background: Tensor | None = None,
    **kwargs,
) -> tuple[Tensor, Tensor, RenderMeta]:
    """Render ``model`` into ``camera``: image ``(H, W, 3)``, alpha ``(H, W, 1)``, :class:`RenderMeta`; into a list
    of C cameras of one size in one call: image ``(C, H, W, 3)``, alpha ``(C, H, W, 1)`` and a batched
    :class:`RenderMeta` (:func:`abcgs.render.rasterize` with ``viewmats`` ``(C, 4, 4)``).

    ``sh_degree`` caps the active SH band (default: all stored bands). ``background`` ``(3,)`` in
    ``[0, 1]`` is composited behind. Other keywords go to :func:`abcgs.render.rasterize`
    (e.g. ``render_mode="RGB+D"``). Differentiable in every model parameter. :func:`render_each` renders any
    number of cameras, of any sizes, in bounded batches.
    """
    device = model.device
    # the CPU kernels' SH path at degree 0, unless the higher bands train: there it would give them zero gradients,
    # where the RGB gives none (Adam counts a zero gradient as a step)
    colors, degree = model.colors_or_sh(
        sh_degree, rgb_at_degree_0=model.shN.requires_grad or select_backend(device, backend) != "cpu")
    if isinstance(camera, Camera):
        viewmats, Ks, width, height = camera.torch_viewmat(device), camera.torch_K(device), camera.width, camera.height
    else:
        cameras = list(camera)
        if not cameras:
            raise ValueError("render: the list of cameras is empty")
        sizes = sorted({(c.width, c.height) for c in cameras})
        if len(sizes) > 1:
            raise ValueError(f"render: a batch of cameras must share one size, got {sizes} (see render_each)")
        viewmats = torch.stack([c.torch_viewmat(device) for c in cameras])
        Ks = torch.stack([c.torch_K(device) for c in cameras])
        width, height = sizes[0]
    return rasterize(
        model.means, model.quats, model.scales, model.opacities, colors, viewmats, Ks, width, height,
        sh_degree=degree, background=background, backend=backend, **kwargs,
    )


RENDER_BATCH_ELEMENTS = 2**22
""":func:`render_each`'s bound on one batch: cameras × (Gaussians + pixels) (a 3 M-Gaussian scene: one view a call, the
memory of one view's projection and blending; the tiny scene: about 100)."""


def render_each(
    model: GaussianModel, cameras: Sequence[Camera], *, max_elements: int = RENDER_BATCH_ELEMENTS, **kwargs,
) -> Iterator[tuple[Tensor, Tensor, RenderMeta]]:
    """:func:`render` of every camera, yielded view by view in order as ``(image (H, W, 3), alpha (H, W, 1),
    meta)``, rendered in batches: consecutive cameras of one size, at most ``max_elements`` // (N + H·W) of them
    (at least one) per call, so that memory stays bounded for many views or many Gaussians. Keywords go to
    :func:`render`; each view equals its one-camera render exactly."""
    cameras = list(cameras)
    start = 0
    while start < len(cameras):
        size = (cameras[start].width, cameras[start].height)
        per_call = max(1, max_elements // (model.num_gaussians + size[0] * size[1]))
        stop = start + 1
        while stop < len(cameras) and stop - start < per_call and (cameras[stop].width, cameras[stop].height) == size:
            stop += 1
        image, alpha, meta = render(model, cameras[start:stop], **kwargs)
        for c in range(stop - start):
            yield image[c], alpha[c], meta.view(c)
        start = stop
