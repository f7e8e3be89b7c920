"""Does an imported splat show the scene? Render its views, compare with the photos, and name the likely cause when
they disagree.

    check = check_splat(model, scene, min_psnr=16.0)   # raises InputError below 16 dB, naming the cause

A splat trained on these photos renders them at 20–35 dB; the same splat in another frame, axis convention or scale
renders them at the level of an unrelated image (~8–13 dB). When the check fails it renders cheap alternatives — the
world's y/z axes reversed (OpenGL vs OpenCV), the ``f_rest`` coefficients read coefficient-major instead of INRIA's
channel-major, gsplat's and OpenSplat's normalised worlds, and the Gaussians' robust bounds moved onto the scene's sparse points
(another scale or offset) — and names the one that renders clearly better, with its PSNR.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np
import torch

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.fit import metrics as M
from abcgs.gaussians import GaussianModel, render_each
from abcgs.io.images import load_image
from abcgs.sfm.align import Similarity
from abcgs.splats import frames
from abcgs.types import Backend

MAX_CHECK_WIDTH = 320
"""Views are compared at most this wide (cheap; the PSNR of a misaligned scene does not depend on resolution)."""
BETTER_BY_DB = 3.0
"""An alternative is named as the likely cause when it renders the photos this much better than the file as read."""

CAUSES = {
    "axis_flip": "axis convention: the splat's world has y and z reversed (OpenGL/Blender y-up against COLMAP/OpenCV "
                 "y-down); export it in the dataset's COLMAP frame, or apply a 180° turn about x",
    "sh_layout": "SH layout: the f_rest_* properties are coefficient-major, not INRIA's channel-major (all R "
                 "coefficients, then G, then B); re-export the PLY in the INRIA layout",
    "gsplat_frame": "frame: the splat is in gsplat's normalised world (simple_trainer's normalize_world_space); set "
                    "splat_format: gsplat_ply (or import the checkpoint .pt)",
    "opensplat_frame": "frame: the splat is in OpenSplat's centred and scaled world (trained without --keep-crs); set "
                       "splat_format: opensplat",
    "scale_offset": "scale/frame: the splat's Gaussians sit at another scale or place than the scene's sparse points "
                    "(another reconstruction, or a tool's own normalisation, e.g. a nerfstudio export without its "
                    "dataparser_transforms.json); import the splat trained on this scene's COLMAP model with its frame file",
}


@dataclass
class SplatCheck:
    """Renders of a splat against the scene's photos.

    Attributes:
        psnr: mean PSNR over the checked views (dB). per_view: view name → PSNR.
        min_psnr: the threshold. passed: ``psnr >= min_psnr``. width: the width the views were compared at (px).
        alternatives: alternative reading → its mean PSNR (only computed when the check fails).
        cause: the key of :data:`CAUSES` judged likely, ``None`` when none helped or the check passed.
    """

    psnr: float
    per_view: dict[str, float]
    min_psnr: float
    passed: bool
    width: int
    alternatives: dict[str, float] = field(default_factory=dict)
    cause: str | None = None

    def to_dict(self) -> dict:
        return asdict(self)


def check_views(scene, max_views: int = 8) -> list[int]:
    """Up to ``max_views`` view indices spread evenly over the scene."""
    n = len(scene.cameras)
    if n == 0:
        raise InputError("the scene has no views to check the splat against")
    return sorted({int(round(i)) for i in np.linspace(0, n - 1, min(n, max_views))})


def _views(scene, idx: Sequence[int]) -> tuple[list[Camera], list[torch.Tensor]]:
    cams, imgs = [], []
    for i in idx:
        cam = scene.cameras[i]
        img = load_image(scene.image_paths[i])
        if img.shape[:2] != (cam.height, cam.width):
            raise InputError(f"image {scene.image_paths[i]} is {img.shape[1]}x{img.shape[0]} but its camera is "
                             f"{cam.width}x{cam.height}")
        if cam.width > MAX_CHECK_WIDTH:
            cam = cam.scaled(MAX_CHECK_WIDTH / cam.width)
            img = cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
        cams.append(cam)
        imgs.append(torch.from_numpy(np.ascontiguousarray(img, dtype=np.float32)))
    return cams, imgs


@torch.no_grad()
def _score(model: GaussianModel, cams: list[Camera], imgs: list[torch.Tensor], backend: Backend) -> dict[str, float]:
    out = {}
    for cam, gt, (img, _, _) in zip(cams, imgs, render_each(model, cams, backend=backend)):
        out[cam.name] = M.psnr(img.clamp(0, 1), gt.to(img.device))
    return out


def robust_bounds(model: GaussianModel, quantile: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """``(centre (3,), half-extent (3,))`` of the Gaussians' means from opacity-weighted quantiles ``q`` and ``1-q``
    (floaters and far background do not stretch it)."""
    with torch.no_grad():
        x = model.means.double().cpu().numpy()
        w = model.opacities.double().cpu().numpy() + 1e-6
    lo, hi, mid = (np.array([_weighted_quantile(x[:, a], w, q) for a in range(3)]) for q in (quantile, 1 - quantile, 0.5))
    return mid, np.maximum((hi - lo) / 2, 1e-9)


def _weighted_quantile(v: np.ndarray, w: np.ndarray, q: float) -> float:
    order = np.argsort(v)
    cw = np.cumsum(w[order])
    return float(v[order][min(np.searchsorted(cw, q * cw[-1]), len(v) - 1)])


def _alternatives(model: GaussianModel, scene) -> dict[str, Callable[[], GaussianModel]]:
    alts: dict[str, Callable[[], GaussianModel]] = {"axis_flip": lambda: frames.transform_model(model, frames.AXIS_FLIP)}
    if model.sh_degree:
        def transposed() -> GaussianModel:
            n, k1 = model.num_gaussians, model.shN.shape[1]
            flat = model.shN.transpose(1, 2).reshape(n, -1)  # the f_rest_* values in file order
            return GaussianModel(model.means, model.quats, model.log_scales, model.opacity_logits, model.sh0,
                                 flat.reshape(n, k1, 3).contiguous())
        alts["sh_layout"] = transposed
    if len(scene.cameras) >= 2:
        alts["opensplat_frame"] = lambda: frames.transform_model(
            model, frames.inverse(frames.opensplat_similarity(scene.cameras)))
    points = np.asarray(getattr(scene, "points", np.zeros((0, 3))))
    if len(points) >= 4:
        alts["gsplat_frame"] = lambda: frames.transform_model(
            model, frames.inverse(frames.gsplat_similarity(scene.cameras, points)))

        def rescaled() -> GaussianModel:
            c, h = robust_bounds(model)
            pc = np.median(points, axis=0)
            ph = np.maximum((np.quantile(points, 0.95, axis=0) - np.quantile(points, 0.05, axis=0)) / 2, 1e-9)
            s = float(np.exp(np.mean(np.log(ph / h))))
            return frames.transform_model(model, Similarity(s, np.eye(3), pc - s * c))
        alts["scale_offset"] = rescaled
    return alts


def check_splat(model: GaussianModel, scene, *, min_psnr: float, max_views: int = 8, backend: Backend = "auto",
                source: str = "the splat") -> SplatCheck:
    """Render ``model`` into up to ``max_views`` of ``scene``'s views (``cameras``, ``image_paths``; at most
    :data:`MAX_CHECK_WIDTH` px wide) and compare with the photos.

    Returns the :class:`SplatCheck` when the mean PSNR reaches ``min_psnr``; otherwise tries the alternatives of the
    module docstring and raises :class:`InputError` naming ``source``, the PSNR, and the likely cause with its fix.
    """
    cams, imgs = _views(scene, check_views(scene, max_views))
    per_view = _score(model, cams, imgs, backend)
    psnr = float(np.mean(list(per_view.values())))
    check = SplatCheck(psnr, per_view, float(min_psnr), psnr >= min_psnr, cams[0].width)
    if check.passed:
        return check
    for name, make in _alternatives(model, scene).items():
        check.alternatives[name] = float(np.mean(list(_score(make(), cams, imgs, backend).values())))
    best = max(check.alternatives.items(), key=lambda kv: kv[1], default=None)
    if best is not None and best[1] >= psnr + BETTER_BY_DB:
        check.cause = best[0]
        why = f"likely cause: {CAUSES[best[0]]} (read that way it renders at {best[1]:.1f} dB)"
    else:
        tried = ", ".join(f"{k} {v:.1f} dB" for k, v in check.alternatives.items())
        why = ("no frame, axis, scale or SH-layout alternative renders better"
               + (f" ({tried})" if tried else "")
               + ": the splat was trained on other photos or poses than this scene's (import the one trained on this "
               "scene's images, in its COLMAP frame), or it is too coarse to match them (accept it with a lower "
               "fit.import_min_psnr)")
    raise InputError(f"{source}: its renders match the scene's photos at {psnr:.1f} dB over {len(cams)} views, below "
                     f"fit.import_min_psnr = {min_psnr:g} dB, so it would stylize a misaligned scene; {why}")
