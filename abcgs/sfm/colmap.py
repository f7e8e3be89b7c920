"""Structure from motion with pycolmap (:func:`reconstruct`); the result is read back by :mod:`abcgs.sfm.model`.

:func:`reconstruct` runs SIFT extraction → matching (exhaustive or sequential) → incremental mapping
(largest model kept) → undistortion to PINHOLE, and writes::

    out_dir/sparse/{cameras,images,points3D}.bin   undistorted COLMAP model (binary)
    out_dir/images/                                undistorted images (registered views only)
    out_dir/masks/                                 undistorted label maps (only when masks are given)
    out_dir/metrics.json                           {registered, total, points, mean_reprojection_error_px,
                                                    unregistered: [names]} (no wall time: the folder is a
                                                    dependency of every later stage, its hash must not vary)

Determinism: COLMAP's RANSAC, mapper and triangulator are seeded with ``params.seed``. With
``num_threads = 1`` (the default) repeated runs give identical models. More threads are faster, but
feature/match ordering and multi-threaded bundle adjustment then vary run to run (camera centres
differ at the 1e-3 level). Tested with pycolmap 4.2 (CPU).
"""

from __future__ import annotations

import functools
import logging
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import cv2  # before pycolmap: see abcgs/sfm/__init__.py
import numpy as np
import pycolmap

from abcgs.errors import InputError, ReconstructionError
from abcgs.io.atomic import atomic_path, write_json
from abcgs.io.images import (
    labels_for_view,
    list_images,
    load_image,
    load_labels,
    save_labels,
    stroke_map_path,
    strokes_for_view,
)
from abcgs.sfm.params import EXHAUSTIVE_MAX_IMAGES, ReconstructParams

log = logging.getLogger(__name__)


MIN_IMAGES = 3


@dataclass
class ReconstructionReport:
    """What :func:`reconstruct` did; ``metrics()`` is what goes into ``metrics.json``."""

    registered: int
    total: int
    points: int
    mean_reprojection_error_px: float
    seconds: float
    unregistered: list[str] = field(default_factory=list)
    out_dir: Path | None = None

    def metrics(self, *, seconds: bool = True) -> dict:
        """The record; ``seconds=False`` leaves out the wall time (for the model folder, whose bytes are a dep)."""
        data = asdict(self)
        data.pop("out_dir")
        if not seconds:
            data.pop("seconds")
        return data

    def summary(self) -> str:
        """One log line: registered views, points, mean reprojection error (px), wall time (s)."""
        return (f"{self.registered}/{self.total} registered, {self.points} points, reprojection error "
                f"{self.mean_reprojection_error_px:.3f} px, {self.seconds:.1f} s")


def set_colmap_log_level(level: Literal["info", "warning", "error"]) -> None:
    """How much COLMAP itself prints to stderr (its glog output; abcgs's own messages use :mod:`logging`)."""
    pycolmap.logging.minloglevel = {"info": 0, "warning": 1, "error": 2}[level]


# ----------------------------------------------------------------------------------------------
# Input validation
# ----------------------------------------------------------------------------------------------


def validate_images(images_dir: str | os.PathLike) -> tuple[list[Path], dict[str, tuple[int, int]]]:
    """Check the input folder before COLMAP sees it.

    Returns the sorted image paths and each image's ``(width, height)`` by file name. Raises
    :class:`InputError` for fewer than :data:`MIN_IMAGES` images or any unreadable image (named).
    """
    files = list_images(images_dir)
    if len(files) < MIN_IMAGES:
        raise InputError(
            f"{images_dir} holds {len(files)} image(s); structure from motion needs at least {MIN_IMAGES} "
            "overlapping photos of the scene (LLFF-style captures have 20-60)"
        )
    sizes = {}
    for f in files:
        img = load_image(f)  # raises InputError naming the file
        sizes[f.name] = (img.shape[1], img.shape[0])
    return files, sizes


def resolve_single_camera(params: ReconstructParams, sizes: dict[str, tuple[int, int]]) -> bool:
    """Whether all images share one camera; an error when that is forced but sizes differ."""
    distinct = sorted(set(sizes.values()))
    if params.single_camera == "auto":
        return len(distinct) == 1
    if params.single_camera and len(distinct) > 1:
        examples = ", ".join(f"{n} is {w}x{h}" for n, (w, h) in list(sizes.items()) if (w, h) in distinct[:2])
        raise InputError(
            f"reconstruct.single_camera is true but the images have {len(distinct)} different sizes "
            f"({', '.join(f'{w}x{h}' for w, h in distinct)}; e.g. {examples}); resize them to one size "
            "or set reconstruct.single_camera to auto/false"
        )
    return bool(params.single_camera)


# ----------------------------------------------------------------------------------------------
# COLMAP steps
# ----------------------------------------------------------------------------------------------


def extract_features(db: Path, images_dir: Path, names: list[str], params: ReconstructParams, single: bool) -> None:
    """SIFT features of ``names`` (in ``images_dir``) into the database ``db``; one shared camera when ``single``."""
    opts = pycolmap.FeatureExtractionOptions(num_threads=params.num_threads, max_image_size=params.max_image_size)
    opts.sift.peak_threshold = params.sift_peak_threshold
    opts.sift.domain_size_pooling = params.sift_domain_size_pooling
    pycolmap.extract_features(
        db,
        images_dir,
        image_names=names,
        camera_mode=pycolmap.CameraMode.SINGLE if single else pycolmap.CameraMode.PER_IMAGE,
        reader_options=pycolmap.ImageReaderOptions(camera_model=params.camera_model),
        extraction_options=opts,
        device=pycolmap.Device.cpu,
    )


def choose_matcher(params: ReconstructParams, n_images: int) -> str:
    """``exhaustive`` or ``sequential`` (``auto``: exhaustive up to :data:`EXHAUSTIVE_MAX_IMAGES` images)."""
    if params.matcher != "auto":
        return params.matcher
    return "exhaustive" if n_images <= EXHAUSTIVE_MAX_IMAGES else "sequential"


def match_features(db: Path, params: ReconstructParams, matcher: str) -> None:
    """Match the features in ``db`` (``exhaustive`` or ``sequential``) and verify each pair's two-view geometry."""
    matching = pycolmap.FeatureMatchingOptions(num_threads=params.num_threads)
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = params.seed
    if matcher == "exhaustive":
        pycolmap.match_exhaustive(db, matching_options=matching, verification_options=verification, device=pycolmap.Device.cpu)
    else:
        pairing = pycolmap.SequentialPairingOptions(overlap=params.sequential_overlap, num_threads=params.num_threads)
        pycolmap.match_sequential(
            db, matching_options=matching, pairing_options=pairing, verification_options=verification, device=pycolmap.Device.cpu
        )


def _map(db: Path, images_dir: Path, sparse_dir: Path, params: ReconstructParams) -> pycolmap.Reconstruction | None:
    """Incremental mapping; the model with the most registered images (ties: most points), or None."""
    opts = pycolmap.IncrementalPipelineOptions(num_threads=params.num_threads, random_seed=params.seed, min_model_size=MIN_IMAGES)
    opts.mapper.random_seed = params.seed
    opts.mapper.abs_pose_min_num_inliers = params.mapper_abs_pose_min_inliers
    opts.mapper.init_min_tri_angle = params.mapper_init_min_tri_angle
    opts.triangulation.random_seed = params.seed
    sparse_dir.mkdir(parents=True, exist_ok=True)
    models = pycolmap.incremental_mapping(db, images_dir, sparse_dir, options=opts)
    if not models:
        return None
    return max(models.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))


def check_registration(rec: pycolmap.Reconstruction | None, names: list[str], params: ReconstructParams,
                       images_dir: Path | None = None) -> list[str]:
    """The unregistered image names; :class:`ReconstructionError` when too few images registered."""
    registered = {im.name for im in rec.images.values() if im.has_pose} if rec is not None else set()
    missing = [n for n in names if n not in registered]
    frac = len(registered) / len(names)
    shown = ", ".join(missing[:20]) + (f" ... (+{len(missing) - 20} more)" if len(missing) > 20 else "")
    if frac < params.min_registered_fraction:
        hint = ("Try photos with more overlap between neighbouring views and more texture (avoid blank walls, motion "
                "blur, reflections), remove unrelated photos, or lower reconstruct.min_registered_fraction to keep the "
                "partial model.")
        if images_dir is not None and not registered and views_are_identical(images_dir, names):
            hint = ("The photos are (nearly) identical: the camera never moved. Structure from motion needs views "
                    "from different positions (parallax); photograph the scene while moving around it.")
        raise ReconstructionError(
            f"structure from motion registered only {len(registered)} of {len(names)} images "
            f"({frac:.0%} < reconstruct.min_registered_fraction = {params.min_registered_fraction:.0%}). "
            f"Unregistered: {shown or 'none'}. {hint}"
        )
    if missing:
        log.warning("reconstruct: %d of %d views did not register and are left out of the scene: %s", len(missing),
                    len(names), shown)
    return missing


def views_are_identical(images_dir: Path, names: list[str], tolerance: float = 2.0) -> bool:
    """Whether every view equals the first one to within ``tolerance`` grey levels (mean absolute difference of
    64 × 64 thumbnails, 0–255)."""
    thumbs = [cv2.resize(cv2.imread(str(Path(images_dir) / n), cv2.IMREAD_GRAYSCALE), (64, 64),
                         interpolation=cv2.INTER_AREA).astype(np.float32) for n in names]
    return all(float(np.abs(t - thumbs[0]).mean()) <= tolerance for t in thumbs[1:])


def undistort_labels(labels: np.ndarray, distorted: pycolmap.Camera, undistorted: pycolmap.Camera) -> np.ndarray:
    """Warp a label map ``(H, W)`` of a distorted view onto its undistorted PINHOLE view.

    Same pixel mapping as COLMAP's image undistorter but nearest-neighbour, so labels stay labels.
    Returns ``(H', W') int64`` at the undistorted camera's size; pixels that map outside get 0.
    """
    w, h = undistorted.width, undistorted.height
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = undistorted.cam_from_img(np.stack([u.ravel(), v.ravel()], axis=1))
    pix = distorted.img_from_cam(np.concatenate([rays, np.ones((rays.shape[0], 1))], axis=1)) - 0.5
    mx = pix[:, 0].astype(np.float32).reshape(h, w)
    my = pix[:, 1].astype(np.float32).reshape(h, w)
    src = labels.astype(np.uint16 if labels.max(initial=0) > 255 else np.uint8)
    out = cv2.remap(src, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.astype(np.int64)


@dataclass(frozen=True)
class ViewLabels:
    """One view whose label map goes into the layout, and how it gets there (:func:`write_view_labels`)."""

    name: str
    """The view's image name (its label map is ``<stem>.png``)."""
    size: tuple[int, int]
    """``(H, W)`` of the view as the source has it (before undistortion): maps of another scale are scaled to it."""
    warp: Callable[[np.ndarray], np.ndarray] | None = None
    """The view's undistortion of a label map (:func:`undistort_labels`); None: the view is written as it is."""
    keep_mask: Path | None = None
    """The source's keep mask of the view (non-zero = kept → label 1, else 2), used where it has no label map."""


def write_view_labels(views: list[ViewLabels], masks_dir: Path | None, out: Path) -> int:
    """The label maps of ``views`` written into ``out`` (the layout's ``masks/``), the one way a label map reaches
    the layout: each view's ``masks_dir/<stem>.png``, else its keep mask, scaled to the view, through its warp; the
    strokes the masks page saved beside a label map come along (:func:`carry_strokes`). Returns the count."""
    count = 0
    for view in views:
        stem = Path(view.name).stem
        user = masks_dir / f"{stem}.png" if masks_dir is not None else None
        given = user is not None and (user.exists() or user.is_symlink())  # not a regular file: refused, not skipped
        if given:
            labels = labels_for_view(load_labels(user), view.size, user, view.name)
        elif view.keep_mask is not None:
            keep = labels_for_view(load_labels(view.keep_mask), view.size, view.keep_mask, view.name)
            labels = np.where(keep > 0, 1, 2)
        else:
            continue
        save_labels(out / f"{stem}.png", labels if view.warp is None else view.warp(labels))
        if given:
            carry_strokes(masks_dir, stem, view.size, out, view.warp)
        count += 1
    return count


def _undistort_masks(masks_dir: Path, rec: pycolmap.Reconstruction, und: pycolmap.Reconstruction, out: Path) -> int:
    """Write undistorted copies of ``masks_dir/<stem>.png`` for every registered image; returns the count."""
    registered = {Path(im.name).stem for im in rec.images.values()}
    for mask_path in sorted(masks_dir.glob("*.png")):
        if mask_path.stem not in registered:
            log.warning("mask %s has no registered image with that stem; skipped", mask_path.name)
    views = []
    for im in sorted(rec.images.values(), key=lambda im: im.name):
        cam, und_cam = rec.cameras[im.camera_id], und.cameras[und.find_image_with_name(im.name).camera_id]
        views.append(ViewLabels(im.name, (cam.height, cam.width),
                                functools.partial(undistort_labels, distorted=cam, undistorted=und_cam)))
    return write_view_labels(views, masks_dir, out)


def carry_strokes(masks_dir: Path, stem: str, view_hw: tuple[int, int], out: Path,
                  warp: Callable[[np.ndarray], np.ndarray] | None = None) -> bool:
    """Copy the strokes the masks page saved for view ``stem`` (:func:`abcgs.io.images.stroke_map_path` under
    ``masks_dir``), if any, into ``out/strokes/`` through ``warp`` (``(H, W) int64 → (H', W') int64``, the view's
    undistortion, None: as it is; its empty pixels, 0, are no stroke). A stroke map painted at another scale of the
    view (the photo's full size, the views a quarter of it) is scaled to ``view_hw`` first
    (:func:`abcgs.io.images.strokes_for_view`). Returns whether there was one; one that is no regular file (a FIFO, a
    device, a link loop) is refused in one line, not skipped (:func:`abcgs.io.guarded.regular_file`)."""
    src = stroke_map_path(masks_dir, stem)
    if not src.exists() and not src.is_symlink():
        return False
    raw = strokes_for_view(load_labels(src), view_hw, src, stem)
    save_labels(stroke_map_path(out, stem), raw if warp is None else warp(raw))
    return True


def undistort_model(model_dir: Path, images_dir: Path, work: Path, out: Path, params: ReconstructParams) -> None:
    """COLMAP undistortion of ``model_dir`` into ``out/sparse`` and ``out/images`` (other outputs dropped)."""
    und = work / "undistorted"
    pycolmap.undistort_images(und, model_dir, images_dir, output_type="COLMAP", num_threads=params.num_threads)
    shutil.move(str(und / "sparse"), str(out / "sparse"))
    shutil.move(str(und / "images"), str(out / "images"))


# ----------------------------------------------------------------------------------------------
# Public entry points
# ----------------------------------------------------------------------------------------------


def reconstruct(
    images_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    params: ReconstructParams | None = None,
    masks_dir: str | os.PathLike | None = None,
) -> ReconstructionReport:
    """Run SfM on every image in ``images_dir`` and write ``out_dir`` atomically (layout: module docstring).

    ``masks_dir`` (optional): label PNGs named like the images; they are undistorted alongside.
    Raises :class:`InputError` for bad input and :class:`ReconstructionError` when fewer than
    ``params.min_registered_fraction`` of the images register.
    """
    params = params or ReconstructParams()
    images_dir = Path(images_dir)
    t0 = time.perf_counter()
    files, sizes = validate_images(images_dir)
    single = resolve_single_camera(params, sizes)
    names = [f.name for f in files]
    matcher = choose_matcher(params, len(names))
    pycolmap.set_random_seed(params.seed)
    with tempfile.TemporaryDirectory(prefix="abcgs-sfm-") as scratch:
        work = Path(scratch)
        db = work / "database.db"
        log.info("reconstruct: %d images, %s camera(s), %s matching", len(names), "one shared" if single else "per-image", matcher)
        extract_features(db, images_dir, names, params, single)
        log.info("reconstruct: features extracted (%.1f s)", time.perf_counter() - t0)
        match_features(db, params, matcher)
        log.info("reconstruct: features matched (%.1f s)", time.perf_counter() - t0)
        rec = _map(db, images_dir, work / "sparse", params)
        unregistered = check_registration(rec, names, params, images_dir)
        assert rec is not None
        log.info("reconstruct: %d/%d images registered (%.1f s)", rec.num_reg_images(), len(names), time.perf_counter() - t0)
        model_dir = work / "model"
        model_dir.mkdir()
        rec.write_binary(str(model_dir))
        with atomic_path(out_dir, is_dir=True) as tmp:
            undistort_model(model_dir, images_dir, work, tmp, params)
            if masks_dir is not None and Path(masks_dir).is_dir():
                und = pycolmap.Reconstruction(str(tmp / "sparse"))
                n = _undistort_masks(Path(masks_dir), rec, und, tmp / "masks")
                log.info("reconstruct: %d label maps undistorted", n)
            report = ReconstructionReport(
                registered=rec.num_reg_images(),
                total=len(names),
                points=rec.num_points3D(),
                mean_reprojection_error_px=float(rec.compute_mean_reprojection_error()),
                seconds=round(time.perf_counter() - t0, 3),
                unregistered=unregistered,
                out_dir=Path(out_dir),
            )
            write_json(tmp / "metrics.json", report.metrics(seconds=False))
    log.info("reconstruct: done in %.1f s -> %s", report.seconds, out_dir)
    return report
