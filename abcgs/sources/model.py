"""What the ``reconstruct`` stage writes for a scene that comes with cameras: the same layout as structure from
motion (:mod:`abcgs.sfm.colmap`), so every later stage reads it alike::

    out_dir/sparse/{cameras,images,points3D}.bin   undistorted PINHOLE model, the dataset's poses, in its frame
    out_dir/images/                                the views (undistorted; RGBA composited on the background)
    out_dir/masks/                                 label maps (the scene's masks/, or nerfstudio's mask_path)
    out_dir/alpha/                                 an object's alpha maps (its views came with alpha)
    out_dir/scene.json                             format, frame, background, splat, notes (:func:`write_scene`)
    out_dir/metrics.json                           the record (:class:`SourceReport`, no wall time)

Initial points, in order of preference:

1. ``dataset``: the dataset's own sparse points (a COLMAP model, nerfstudio's ``ply_file_path``).
2. ``triangulated``: SIFT features matched between the views (pose-independent two-view verification), then
   triangulated with the given cameras held fixed (``pycolmap.triangulate_points``). Before that, the verified
   matches are checked against the given cameras: when their median Sampson distance to the epipolar lines the
   poses predict exceeds :func:`epipolar_tolerance`, the poses do not fit the images (a wrong axis convention,
   images paired with the wrong poses): an error. Consistent captures measure well below it (the tiny scene
   0.05 px, LLFF fern's own poses 0.24 px at 504 × 378).
3. ``random``: where fewer than :data:`MIN_POINTS` triangulate (textureless views), :data:`RANDOM_POINTS` points
   inside the cameras' view frustums between the near and far depths (LLFF's bounds, else around where the optical
   axes meet), coloured by the pixel they were cast through.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import pycolmap

from abcgs.cameras import Cameras, Distortion
from abcgs.errors import InputError
from abcgs.io.atomic import atomic_path, write_json
from abcgs.io.colmap import read_model, write_model
from abcgs.io.images import decode_image, load_image, load_labels, save_image
from abcgs.sfm.colmap import (
    ViewLabels,
    choose_matcher,
    extract_features,
    match_features,
    undistort_labels,
    undistort_model,
    write_view_labels,
)
from abcgs.sfm.model import layout_scene, write_scene
from abcgs.sfm.params import ReconstructParams
from abcgs.sources.lens import colmap_camera
from abcgs.sources.validate import axes_meeting_point
from abcgs.types import Background, SourceScene, View

log = logging.getLogger(__name__)

MIN_POINTS = 100
"""Fewer triangulated points than this: random points instead."""
RANDOM_POINTS = 20_000
"""How many random points the fallback casts."""
POSE_CHECK_MIN_MATCHES = 500
"""Verified feature matches from which the views clearly match each other (and the poses can be judged)."""

PointsMethod = Literal["dataset", "triangulated", "random"]


@dataclass
class SourceReport:
    """What :func:`write_source_model` did; :meth:`metrics` goes into ``metrics.json`` and ``reconstruct.json``."""

    format: str
    registered: int
    total: int
    points: int
    points_method: PointsMethod
    verified_matches: int = 0
    median_epipolar_error_px: float | None = None
    mean_reprojection_error_px: float | None = None
    undistorted: bool = False
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0

    def metrics(self, *, seconds: bool = True) -> dict:
        data = asdict(self)
        if not seconds:
            data.pop("seconds")
        return data

    def summary(self) -> str:
        """One log line: views, points and how they were made, wall time (s)."""
        return (f"{self.total} views with the dataset's cameras, {self.points} points ({self.points_method}), "
                f"{self.seconds:.1f} s")


def _stage_image(view: View, dst: Path, background: tuple[float, float, float] | None) -> np.ndarray | None:
    """Copy the view's image to ``dst``, or composite an RGBA image on ``background`` (written as PNG); returns the
    RGBA image's alpha ``(H, W)`` float32, else None. A view with a mask (nerfstudio's ``mask_path``, non-zero = the
    object) is composited on ``background`` by that mask when a background is given."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if background is None:
        shutil.copyfile(view.image_path, dst)
        return None
    if view.mask_path is not None:
        img = load_image(view.image_path)
        keep = (load_labels(view.mask_path, expect_hw=img.shape[:2]) > 0).astype(np.float32)
        save_image(dst, img * keep[..., None] + np.asarray(background, np.float32) * (1.0 - keep[..., None]))
        return keep
    raw = decode_image(view.image_path)
    if raw.ndim == 3 and raw.shape[2] == 4:
        scale = 65535.0 if raw.dtype == np.uint16 else 255.0
        rgba = cv2.cvtColor(raw, cv2.COLOR_BGRA2RGBA).astype(np.float32) / scale
        alpha = rgba[..., 3:4]
        save_image(dst, rgba[..., :3] * alpha + np.asarray(background, np.float32) * (1.0 - alpha))
        return alpha[..., 0]
    save_image(dst, load_image(view.image_path))
    return None


def write_posed(views: list[View], model_dir: Path, ids: dict[str, tuple[int, int]] | None = None) -> Path:
    """Write a COLMAP model of the views' cameras, lenses and poses, no points, into ``model_dir`` (the input of
    COLMAP's undistorter and triangulator); ``ids``: name → (camera_id, image_id) to use (a feature database's), else
    1 … N in the views' order."""
    write_model(model_dir, Cameras.from_list([v.camera for v in views], [v.distortion for v in views]),
                ids=[ids[v.name] for v in views] if ids is not None else None)
    return model_dir


def _skew(t: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def epipolar_errors(database: pycolmap.Database, views: list[View]) -> np.ndarray:
    """Sampson distances (px) of every verified feature match to the epipolar geometry the views' cameras predict,
    ``(M,)``."""
    names = {im.image_id: im.name for im in database.read_all_images()}
    cams = {v.name: v.camera for v in views}
    keypoints = {i: database.read_keypoints(i)[:, :2].astype(np.float64) for i in names}
    out = []
    for pair, geometry in zip(*database.read_two_view_geometries()):
        m = geometry.inlier_matches
        if len(m) == 0:
            continue
        i, j = pycolmap.pair_id_to_image_pair(pair)
        ci, cj = cams[names[i]], cams[names[j]]
        rel = cj.viewmat @ np.linalg.inv(ci.viewmat)
        F = np.linalg.inv(cj.K).T @ _skew(rel[:3, 3]) @ rel[:3, :3] @ np.linalg.inv(ci.K)
        x1 = np.c_[keypoints[i][m[:, 0]], np.ones(len(m))]
        x2 = np.c_[keypoints[j][m[:, 1]], np.ones(len(m))]
        Fx1, Ftx2 = x1 @ F.T, x2 @ F
        den = Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2
        out.append(np.abs(np.sum(x2 * Fx1, axis=1)) / np.sqrt(np.maximum(den, 1e-30)))
    return np.concatenate(out) if out else np.zeros(0)


def epipolar_tolerance(views: list[View]) -> float:
    """The median Sampson distance (px) above which the poses do not fit the images: 0.5 % of the median image
    diagonal, at least 1 px."""
    diag = float(np.median([math.hypot(v.camera.width, v.camera.height) for v in views]))
    return max(1.0, 0.005 * diag)


def triangulate(views: list[View], images_dir: Path, work: Path, params: ReconstructParams
                ) -> tuple[pycolmap.Reconstruction, int, float | None]:
    """SIFT + matching on the (undistorted) views, the matches checked against the cameras (module docstring), then
    their points triangulated with the cameras fixed. Returns pycolmap's model, the number of verified matches and
    their median epipolar error (px; ``None`` without matches)."""
    db = work / "features.db"
    names = [v.name for v in views]
    extract_features(db, images_dir, names, params.model_copy(update={"camera_model": "PINHOLE"}), single=False)
    match_features(db, params, choose_matcher(params, len(names)))
    database = pycolmap.Database.open(str(db))
    try:
        ids = {im.name: (im.camera_id, im.image_id) for im in database.read_all_images()}
        errors = epipolar_errors(database, views)
    finally:
        database.close()
    median = float(np.median(errors)) if len(errors) else None
    tolerance = epipolar_tolerance(views)
    if len(errors) >= POSE_CHECK_MIN_MATCHES and median > tolerance:
        raise InputError(
            f"the views match each other ({len(errors)} verified feature matches), but the matches lie {median:.2f} px "
            f"(median) off the epipolar lines the dataset's cameras predict (a consistent capture: well under "
            f"{tolerance:.1f} px): the poses do not fit the images (a wrong axis convention, OpenGL vs OpenCV, or images "
            "paired with the wrong poses); check the dataset's format (`format:` in its scene entry) and image order")
    rec = pycolmap.Reconstruction(str(write_posed(views, work / "posed", ids)))
    out = work / "triangulated"
    out.mkdir()
    opts = pycolmap.IncrementalPipelineOptions(num_threads=params.num_threads, random_seed=params.seed)
    opts.triangulation.random_seed = params.seed
    tri = pycolmap.triangulate_points(rec, db, images_dir, out, clear_points=True, options=opts)
    return tri, len(errors), median


def depth_range(source_views: list[View], stated: tuple[float, float] | None) -> tuple[float, float]:
    """``(near, far)`` for random points: the dataset's bounds, else around where the optical axes meet (half to one
    and a half times the cameras' distance to it), else from the spread of the camera centres."""
    if stated is not None:
        return stated
    meet = axes_meeting_point([v.camera for v in source_views])
    centres = np.array([v.camera.center for v in source_views])
    if meet is not None:
        dist = np.linalg.norm(centres - meet, axis=1)
        return 0.5 * float(dist.min()), 1.5 * float(dist.max())
    spread = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) or 1.0
    return 0.5 * spread, 10.0 * spread


def random_points(views: list[View], near_far: tuple[float, float], n: int, seed: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points cast through random pixels of random views at depths uniform in ``near_far`` (the views' frustums),
    coloured by those pixels: ``(n, 3) float32`` positions and colours in ``[0, 1]``."""
    rng = np.random.default_rng(seed)
    which = rng.integers(0, len(views), n)
    xyz = np.zeros((n, 3))
    rgb = np.zeros((n, 3), np.float32)
    near, far = near_far
    for i, view in enumerate(views):
        sel = np.flatnonzero(which == i)
        if not len(sel):
            continue
        cam = view.camera
        img = load_image(view.image_path)
        u, v = rng.uniform(0, cam.width, len(sel)), rng.uniform(0, cam.height, len(sel))
        z = rng.uniform(near, far, len(sel))
        rays = np.stack([u, v, np.ones_like(u)], 1) @ np.linalg.inv(cam.K).T
        p_cam = rays * z[:, None]
        R, t = cam.viewmat[:3, :3], cam.viewmat[:3, 3]
        xyz[sel] = (p_cam - t) @ R
        rgb[sel] = img[np.minimum(v.astype(int), cam.height - 1), np.minimum(u.astype(int), cam.width - 1)]
    return xyz.astype(np.float32), rgb


def points_by_id(rec: pycolmap.Reconstruction) -> tuple[np.ndarray, np.ndarray]:
    """A pycolmap model's 3-D points in the canonical order (by point id): ``(M, 3)`` positions and ``(M, 3)`` RGB in
    ``[0, 1]``."""
    ids = sorted(rec.points3D)
    xyz = np.array([rec.points3D[i].xyz for i in ids], np.float64).reshape(-1, 3)
    rgb = np.array([rec.points3D[i].color for i in ids], np.float64).reshape(-1, 3) / 255.0
    return xyz, rgb


def _masks(source: SourceScene, masks_dir: Path | None, dist: dict[str, pycolmap.Camera], und: Cameras, out: Path
           ) -> int:
    """Label maps for the views: the scene's ``masks/<stem>.png`` (labels), else the view's ``mask_path`` (non-zero =
    kept → 1, else 2); undistorted like the views (:func:`abcgs.sfm.colmap.write_view_labels`). Returns the count."""
    views = []
    for view in source.views:
        warp = None
        if view.name in dist:
            i = und.names.index(view.name)
            und_cam = colmap_camera(Distortion("PINHOLE", tuple(float(v) for v in und.intrinsics[i])),
                                    tuple(int(v) for v in und.sizes[i]))
            warp = functools.partial(undistort_labels, distorted=dist[view.name], undistorted=und_cam)
        views.append(ViewLabels(view.name, (view.camera.height, view.camera.width), warp, view.mask_path))
    return write_view_labels(views, masks_dir, out)


def write_source_model(source: SourceScene, out_dir: str | os.PathLike, params: ReconstructParams,
                       masks_dir: str | os.PathLike | None = None, background: Background | None = None) -> SourceReport:
    """Write ``out_dir`` (module docstring) atomically for ``source``; ``masks_dir``: the scene's label PNGs;
    ``background``: the scene's (default: a frame-filling scene on black), recorded with the source's format,
    frame, depth range, notes, metadata and splat in ``scene.json`` (:func:`abcgs.sfm.model.write_scene`; the
    stages read it all back with :func:`abcgs.sfm.model.read_scene`)."""
    t0 = time.perf_counter()
    views = list(source.views)
    masks_dir = Path(masks_dir) if masks_dir is not None and Path(masks_dir).is_dir() else None
    distorted = {v.name: colmap_camera(v.distortion, (v.camera.width, v.camera.height))
                 for v in views if v.distortion is not None}
    pycolmap.set_random_seed(params.seed)
    with tempfile.TemporaryDirectory(prefix="abcgs-source-") as scratch, atomic_path(out_dir, is_dir=True) as tmp:
        work = Path(scratch)
        staged = work / "images"
        behind = source.background.color if source.background is not None else None
        if behind is None and background is not None and background.object:  # e.g. nerfstudio masks: cut out by them
            behind = background.color
        alphas = {v.name: _stage_image(v, staged / v.name, behind) for v in views}
        if background is not None and background.object and not distorted and all(
                a is not None for a in alphas.values()):  # an object's RGBA views: their alpha supervises the fit
            for name, a in alphas.items():
                save_image(tmp / "alpha" / name, a)
        if distorted:  # COLMAP's undistorter: the images into the layout, its model (no points) in the scratch
            (work / "undistorted_model").mkdir()
            undistort_model(write_posed(views, work / "model"), staged, work, work / "undistorted_model", params)
            shutil.move(str(work / "undistorted_model" / "images"), str(tmp / "images"))
            posed = work / "undistorted_model" / "sparse"
        else:
            posed = write_posed(views, work / "posed")
            shutil.copytree(staged, tmp / "images")
        und = read_model(posed).cameras()  # sparse/ is written once, with its points, below
        und_views = [View(cam.name, tmp / "images" / cam.name, cam) for cam in und]
        verified, error, epipolar = 0, None, None
        if source.points is not None and len(source.points):
            method: PointsMethod = "dataset"
            xyz, rgb = source.points, source.colors
        else:
            tri, verified, epipolar = triangulate(und_views, tmp / "images", work, params)
            n = tri.num_points3D()
            log.info("reconstruct: %d points triangulated from %d verified matches", n, verified)
            if n >= MIN_POINTS:
                method = "triangulated"
                xyz, rgb = points_by_id(tri)
                error = float(tri.compute_mean_reprojection_error())
            else:
                method = "random"
                xyz, rgb = random_points(und_views, depth_range(und_views, source.depth_range), RANDOM_POINTS,
                                         params.seed)
                log.warning("reconstruct: only %d points triangulated; starting from %d random points inside the "
                            "cameras' frustums", n, RANDOM_POINTS)
        write_model(tmp / "sparse", und, xyz, rgb)
        n_masks = _masks(source, masks_dir, distorted, und, tmp / "masks")
        if n_masks:
            log.info("reconstruct: %d label maps", n_masks)
        write_scene(layout_scene(tmp, format=source.format, frame=source.frame, background=background,
                                 depth_range=source.depth_range, notes=source.notes, metadata=source.metadata,
                                 splat=source.splat), tmp)
        report = SourceReport(format=source.format, registered=len(views), total=len(views),
                              points=len(xyz), points_method=method, verified_matches=verified,
                              median_epipolar_error_px=epipolar,
                              mean_reprojection_error_px=error, undistorted=bool(distorted), notes=list(source.notes))
        write_json(tmp / "metrics.json", report.metrics(seconds=False))
    report.seconds = round(time.perf_counter() - t0, 3)
    return report
