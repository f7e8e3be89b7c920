"""Image and label-map reading/writing with errors that say what is wrong.

Conventions: colour images are ``(H, W, 3) float32`` RGB in ``[0, 1]``; label maps are ``(H, W) int64``
small integers with 0 = background/unassigned.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from abcgs.errors import InputError
from abcgs.io.atomic import write_bytes
from abcgs.types import Background

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


def list_images(folder: str | os.PathLike) -> list[Path]:
    """Sorted image files directly inside ``folder``; a clear error when none exist."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"image folder {folder} does not exist; point params.yaml data.scenes at a folder with images/")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))
    if not files:
        raise InputError(f"no images ({', '.join(IMAGE_SUFFIXES)}) found in {folder}")
    return files


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read an RGB image as ``(H, W, 3) float32`` in ``[0, 1]``.

    Grey images are expanded to three channels and an alpha channel is dropped. A missing, empty or
    undecodable file raises :class:`InputError` naming the file.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"image {path} does not exist")
    if path.stat().st_size == 0:
        raise InputError(f"image {path} is empty (0 bytes); replace or remove it")
    data = np.fromfile(str(path), dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(f"image {path} could not be decoded (corrupt or not an image); replace or remove it")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 4:
        img = img[:, :, :3]
    img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    return (img.astype(np.float32) / scale).clip(0.0, 1.0)


def load_render(path: str | os.PathLike, background: Background) -> np.ndarray:
    """A render the pipeline wrote, ``(H, W, 3) float32``: as :func:`load_image`, except that a straight-alpha RGBA
    file of a transparent ``background`` is composited on black (the colour renders are made on)."""
    if not background.transparent:
        return load_image(path)
    raw = cv2.imdecode(np.fromfile(str(path), dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.ndim != 3 or raw.shape[2] != 4:
        raise InputError(f"render {path} is not an RGBA image, but the scene's background is transparent; re-run "
                         "the stylize stage")
    rgba = cv2.cvtColor(raw, cv2.COLOR_BGRA2RGBA).astype(np.float32) / (65535.0 if raw.dtype == np.uint16 else 255.0)
    return (rgba[..., :3] * rgba[..., 3:]).clip(0.0, 1.0)


def load_labels(path: str | os.PathLike, *, expect_hw: tuple[int, int] | None = None) -> np.ndarray:
    """Read a label PNG as ``(H, W) int64``.

    Single-channel 8/16-bit PNGs hold labels directly. ``expect_hw`` checks the size against the view
    it belongs to and raises :class:`InputError` with both sizes when they differ.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"label map {path} does not exist")
    img = cv2.imdecode(np.fromfile(str(path), dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(f"label map {path} could not be decoded; it must be a single-channel PNG of small integers")
    if img.ndim == 3:
        if not (np.all(img[..., 0] == img[..., 1]) and np.all(img[..., 1] == img[..., 2])):
            raise InputError(f"label map {path} has colour channels that differ; save labels as a single-channel PNG")
        img = img[..., 0]
    if expect_hw is not None and tuple(img.shape[:2]) != tuple(expect_hw):
        raise InputError(
            f"label map {path} is {img.shape[1]}x{img.shape[0]} but its image is {expect_hw[1]}x{expect_hw[0]}; "
            "masks must have the same size as the view they label"
        )
    return img.astype(np.int64)


def same_picture_scaled(map_hw: tuple[int, int], view_hw: tuple[int, int]) -> bool:
    """Whether a label map of ``map_hw`` ``(H, W)`` pixels is its view of ``view_hw`` at another (or the same) scale:
    the same aspect within a pixel of rounding either way (a 1080×1920 map of a 270×480 ``images_4`` view)."""
    (h, w), (vh, vw) = map_hw, view_hw
    return abs(h * vw / w - vh) <= 1.0 and abs(w * vh / h - vw) <= 1.0


def check_label_size(path: str | os.PathLike, map_hw: tuple[int, int], view_hw: tuple[int, int], view: str = "",
                     fix: str = "") -> None:
    """Refuse a label map whose size ``map_hw`` ``(H, W)`` is not its view's ``view_hw`` at some scale
    (:func:`same_picture_scaled`): :class:`InputError` naming the file, both sizes and the fix (``fix``, else the
    generic one). ``view``: the view's file, for the message."""
    if same_picture_scaled(map_hw, view_hw):
        return
    (h, w), (vh, vw) = map_hw, view_hw
    raise InputError(
        f"label map {path} is {w}×{h} but its view{' ' + view if view else ''} is {vw}×{vh}, another aspect, so it is "
        f"not that picture at another scale; save it at {vw}×{vh} (or any size of that aspect: it is scaled, nearest "
        f"label){', ' + fix if fix else ''}")


def labels_for_view(labels: np.ndarray, view_hw: tuple[int, int], path: str | os.PathLike = "",
                    view: str = "") -> np.ndarray:
    """A label map ``(h, w)`` at its view's size ``view_hw`` ``(H, W)``: as it is when the sizes agree, scaled with
    nearest neighbour when it is the same picture at another scale, else refused (:func:`check_label_size`).
    Returns ``(H, W) int64``."""
    if tuple(labels.shape[:2]) == tuple(view_hw):
        return labels
    check_label_size(path, labels.shape[:2], view_hw, view)
    src = labels.astype(np.uint16 if labels.max(initial=0) > 255 else np.uint8)
    return cv2.resize(src, (view_hw[1], view_hw[0]), interpolation=cv2.INTER_NEAREST).astype(np.int64)


def to_uint8(img: np.ndarray) -> np.ndarray:
    """``[0, 1]`` float image → uint8 with rounding."""
    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def save_image(path: str | os.PathLike, img: np.ndarray) -> None:
    """Write an RGB (or RGBA, straight alpha) float ``[0, 1]`` or uint8 image (PNG/JPEG by suffix), atomically."""
    path = Path(path)
    arr = img if img.dtype == np.uint8 else to_uint8(img)
    if arr.ndim == 3:
        arr = cv2.cvtColor(arr, cv2.COLOR_RGBA2BGRA if arr.shape[2] == 4 else cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(path.suffix or ".png", arr)
    if not ok:
        raise InputError(f"could not encode image for {path}")
    write_bytes(path, buf.tobytes())


def copy_as_png(src: str | os.PathLike, dst: str | os.PathLike) -> tuple[int, int]:
    """Rewrite the image ``src`` (any format OpenCV decodes) as the PNG ``dst`` with the same decoded pixels (bit
    depth and channels kept, so :func:`load_image` and :func:`load_labels` read the same array from either),
    atomically; returns its ``(width, height)``. An undecodable file raises :class:`InputError` naming it."""
    src = Path(src)
    if not src.is_file():
        raise InputError(f"image {src} does not exist")
    img = cv2.imdecode(np.fromfile(str(src), dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype not in (np.uint8, np.uint16):
        raise InputError(f"image {src} could not be decoded as an 8- or 16-bit image; save it as PNG or JPEG")
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise InputError(f"could not encode {src} as PNG for {dst}")
    write_bytes(dst, buf.tobytes())
    return int(img.shape[1]), int(img.shape[0])


def save_labels(path: str | os.PathLike, labels: np.ndarray) -> None:
    """Write an ``(H, W)`` integer label map as an 8-bit (or 16-bit if needed) PNG, atomically."""
    arr = labels.astype(np.uint16 if labels.max(initial=0) > 255 else np.uint8)
    ok, buf = cv2.imencode(".png", arr)
    if not ok:
        raise InputError(f"could not encode label map for {path}")
    write_bytes(path, buf.tobytes())
