"""What the readers share about images and lenses: image sizes, fitting a camera to the image it is used with, and
COLMAP camera models (:class:`abcgs.cameras.Distortion`) as pycolmap cameras.

A dataset may calibrate its cameras at one resolution and ship images at another (LLFF's full-size model beside
``images_8``, Mip-NeRF 360's ``images_2/4/8``, nerfstudio's downscaled folders). :func:`fit_to_image` scales the
intrinsics (focal lengths and principal point; distortion coefficients are dimensionless) to the image's size when
the two are the same picture at another scale, and refuses otherwise.
"""

from __future__ import annotations

import os

import numpy as np
import pycolmap

from abcgs.cameras import Camera, Distortion
from abcgs.errors import InputError
from abcgs.io.images import image_header

PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """``(width, height)`` of an image file from its header (nothing decoded); :class:`InputError` naming the file
    when it is missing, not a regular file, not an image or an image bomb (:func:`abcgs.io.images.image_header`)."""
    return image_header(path)[:2]


def consistent_scale(model_size: tuple[int, int], image_size: tuple[int, int]) -> bool:
    """Whether an image of ``image_size`` is a picture of ``model_size`` at another scale: both axes scale alike
    to within a pixel of rounding."""
    (wm, hm), (wi, hi) = model_size, image_size
    sx, sy = wi / wm, hi / hm
    return abs(wm * sy - wi) <= 1.0 + 1e-6 and abs(hm * sx - hi) <= 1.0 + 1e-6


def colmap_camera(distortion: Distortion, size: tuple[int, int]) -> pycolmap.Camera:
    """A pycolmap camera of ``distortion``'s model and parameters for images of ``size = (width, height)``."""
    cam = pycolmap.Camera(model=distortion.model, width=int(size[0]), height=int(size[1]),
                          params=np.asarray(distortion.params, np.float64))
    return cam


def fit_to_image(camera: Camera, distortion: Distortion | None, size: tuple[int, int], what: str
                 ) -> tuple[Camera, Distortion | None]:
    """``camera`` (and its lens) calibrated at ``(camera.width, camera.height)``, rescaled to an image of ``size``.

    Identity when the sizes agree. Raises :class:`InputError` naming ``what`` (the calibration's file and the
    image) when the image is not the calibrated picture at another scale (a different aspect ratio)."""
    w, h = size
    if (w, h) == (camera.width, camera.height):
        return camera, distortion
    if not consistent_scale((camera.width, camera.height), (w, h)):
        raise InputError(
            f"{what}: the camera is calibrated for {camera.width}x{camera.height} but the image is {w}x{h}, which is "
            f"not the same picture at another scale (x {w / camera.width:.4f}, y {h / camera.height:.4f}); use the "
            "image folder the cameras were made for (scene entry `images:`, e.g. images, images_2, images_4, "
            "images_8) or images downscaled from it")
    sx, sy = w / camera.width, h / camera.height
    K = camera.K.copy()
    K[0] *= sx
    K[1] *= sy
    scaled = Camera(camera.name, K, camera.viewmat.copy(), int(w), int(h), dict(camera.meta))
    if distortion is None:
        return scaled, None
    cam = colmap_camera(distortion, (camera.width, camera.height))
    params = np.asarray(cam.params, np.float64).copy()
    focal, pp = list(cam.focal_length_idxs()), list(cam.principal_point_idxs())
    if len(focal) == 1:
        params[focal[0]] *= 0.5 * (sx + sy)
    else:
        params[focal[0]] *= sx
        params[focal[1]] *= sy
    params[pp[0]] *= sx
    params[pp[1]] *= sy
    return scaled, Distortion(distortion.model, tuple(float(p) for p in params))


def pinhole_and_lens(model: str, params: np.ndarray, width: int, height: int) -> tuple[np.ndarray, Distortion | None]:
    """``(K, lens)`` of a COLMAP camera: ``K`` from its focal length(s) and principal point, ``lens`` ``None`` for a
    pinhole model or a radial/tangential model whose coefficients are all zero (a fisheye model stays a lens: its
    projection is not a pinhole one even without coefficients)."""
    cam = pycolmap.Camera(model=model, width=int(width), height=int(height), params=np.asarray(params, np.float64))
    K = np.asarray(cam.calibration_matrix(), np.float64)
    extra = [i for i in range(len(cam.params)) if i not in set(cam.focal_length_idxs()) | set(cam.principal_point_idxs())]
    if model in PINHOLE_MODELS or ("FISHEYE" not in model and not any(abs(float(cam.params[i])) > 0 for i in extra)):
        return K, None
    return K, Distortion(model, tuple(float(p) for p in cam.params))
