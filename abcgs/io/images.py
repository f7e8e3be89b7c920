"""Image and label-map reading/writing with errors that say what is wrong.

Conventions: colour images are ``(H, W, 3) float32`` RGB in ``[0, 1]``; label maps are ``(H, W) int64``
small integers with 0 = background/unassigned.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from abcgs.errors import InputError
from abcgs.io.atomic import write_bytes
from abcgs.io.guarded import read_bounded, regular_file
from abcgs.types import Background

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS or 89_478_485
"""Largest image read (pixels, width × height): PIL's own limit (89 478 485, a 0.25 GiB RGBA image; a 100 MP photo
resized by half fits). Checked from the file's header before anything decodes it."""
MAX_IMAGE_SLACK = 64 << 20
"""Bytes an image file may hold beyond 8 bytes a pixel (16-bit RGBA, uncompressed): metadata, thumbnails."""
MAX_LABEL = 254
"""Largest label value of a numbered label map (1 … 254; 0 is no label, 255 a pixel left undecided): the masks
stage's memory grows with the largest label, so a 16-bit map of label 60 000 is refused before any work."""


def image_header(path: str | os.PathLike, what: str = "image") -> tuple[int, int, str]:
    """``(width, height, PIL mode)`` of an image file from its header, nothing decoded. :class:`InputError` naming
    ``what`` and the file when it is not a regular file (:func:`abcgs.io.guarded.regular_file`), not an image PIL
    can identify, or larger than :data:`MAX_IMAGE_PIXELS` (an image bomb: a 60 000 × 60 000 one-bit PNG is 436 KB)."""
    regular_file(path, what)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # the size is checked below
            with Image.open(path) as im:
                (w, h), mode = im.size, im.mode
    except Image.DecompressionBombError as exc:
        raise InputError(f"{what} {path} is larger than the {MAX_IMAGE_PIXELS} pixels abcgs reads ({exc}); resize "
                         "it") from None
    except Exception as exc:  # noqa: BLE001 (PIL raises OSError, SyntaxError, struct.error … for a broken header)
        raise InputError(f"{what} {path} is not a readable image: it could not be decoded ({type(exc).__name__}: "
                         f"{str(exc)[:120]}); replace or remove it") from None
    if w < 1 or h < 1 or w * h > MAX_IMAGE_PIXELS:
        amount = "no pixels" if w * h < 1 else f"more than the {MAX_IMAGE_PIXELS} pixels abcgs reads"
        raise InputError(f"{what} {path} is {w}×{h} pixels by its header, {amount}; resize it (or replace it)")
    return int(w), int(h), str(mode)


def decode_image(path: str | os.PathLike, what: str = "image", flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray:
    """The image file decoded by OpenCV (``flags``), after :func:`image_header` has checked its header and the file's
    bytes are bounded by its pixels; :class:`InputError` naming ``what`` and the file when it does not decode."""
    w, h, _ = image_header(path, what)
    data = np.frombuffer(read_bounded(path, what, 8 * w * h + MAX_IMAGE_SLACK), np.uint8)
    if data.size == 0:
        raise InputError(f"{what} {path} is empty (0 bytes); replace or remove it")
    try:
        img = cv2.imdecode(data, flags)
    except cv2.error as exc:
        raise InputError(f"{what} {path} could not be decoded ({str(exc).strip().splitlines()[-1][:120]}); replace "
                         "or remove it") from None
    if img is None or img.size == 0:
        raise InputError(f"{what} {path} could not be decoded (corrupt or not an image); replace or remove it")
    return img


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
    img = decode_image(path)
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
    raw = decode_image(path, "render")
    if raw.ndim != 3 or raw.shape[2] != 4:
        raise InputError(f"render {path} is not an RGBA image, but the scene's background is transparent; re-run "
                         "the stylize stage")
    rgba = cv2.cvtColor(raw, cv2.COLOR_BGRA2RGBA).astype(np.float32) / (65535.0 if raw.dtype == np.uint16 else 255.0)
    return (rgba[..., :3] * rgba[..., 3:]).clip(0.0, 1.0)


def load_labels(path: str | os.PathLike, *, expect_hw: tuple[int, int] | None = None) -> np.ndarray:
    """Read a label PNG as ``(H, W) int64``.

    Single-channel 8/16-bit PNGs hold labels directly; a value above 255 (:data:`MAX_LABEL`, and 255 for a pixel
    left undecided) is refused. ``expect_hw`` checks the size against the view it belongs to and raises
    :class:`InputError` with both sizes when they differ.
    """
    img = decode_image(path, "label map")
    if img.ndim == 3:
        if not (np.all(img[..., 0] == img[..., 1]) and np.all(img[..., 1] == img[..., 2])):
            raise InputError(f"label map {path} has colour channels that differ; save labels as a single-channel PNG")
        img = img[..., 0]
    if expect_hw is not None and tuple(img.shape[:2]) != tuple(expect_hw):
        raise InputError(
            f"label map {path} is {img.shape[1]}x{img.shape[0]} but its image is {expect_hw[1]}x{expect_hw[0]}; "
            "masks must have the same size as the view they label"
        )
    check_label_values(path, img)
    return img.astype(np.int64)


def check_label_values(path: str | os.PathLike, labels: np.ndarray) -> None:
    """Refuse a numbered label map ``(H, W)`` holding a value above 255 (labels 1 … :data:`MAX_LABEL`, 255 a pixel
    left undecided): :class:`InputError` naming the file, the value and the bound."""
    top = int(labels.max(initial=0))
    if top > MAX_LABEL + 1:
        raise InputError(f"label map {path} holds the label {top}, more than the {MAX_LABEL} labels abcgs lifts (1 … "
                         f"{MAX_LABEL}; 0 is no label, 255 a pixel left undecided); number its regions 1, 2, 3 …")


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


def resized_labels(labels: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """A label map ``(h, w) int`` (negative values, e.g. an undecided -1, kept) at the size ``hw`` ``(H, W)``, nearest
    label; as it is when it has that size. Returns ``(H, W) int64``."""
    if tuple(labels.shape[:2]) == tuple(hw):
        return np.asarray(labels, np.int64)
    out = cv2.resize(np.asarray(labels, np.int32), (hw[1], hw[0]), interpolation=cv2.INTER_NEAREST)
    return out.astype(np.int64)


def labels_for_view(labels: np.ndarray, view_hw: tuple[int, int], path: str | os.PathLike = "",
                    view: str = "") -> np.ndarray:
    """A label map ``(h, w)`` at its view's size ``view_hw`` ``(H, W)``: as it is when the sizes agree, scaled with
    nearest neighbour when it is the same picture at another scale, else refused (:func:`check_label_size`).
    Returns ``(H, W) int64``."""
    if tuple(labels.shape[:2]) == tuple(view_hw):
        return labels
    check_label_size(path, labels.shape[:2], view_hw, view)
    return resized_labels(labels, view_hw)


def strokes_for_view(raw: np.ndarray, view_hw: tuple[int, int], path: str | os.PathLike = "",
                     view: str = "") -> np.ndarray:
    """A saved stroke map (:func:`save_stroke_map`'s values: 0 no stroke, ``seed + 1`` a stroke) ``(h, w)`` at its
    view's size ``view_hw`` ``(H, W)``: as it is when the sizes agree, else scaled when it is the same picture at
    another scale (:func:`check_label_size` refuses another aspect). A pixel of the scaled map takes the stroke that
    covers most of it, so a thin stroke painted at the photo's size survives on a view four times smaller (nearest
    neighbour would drop three rows in four). Returns ``(H, W) int64``."""
    if tuple(raw.shape[:2]) == tuple(view_hw):
        return raw.astype(np.int64)
    check_label_size(path, raw.shape[:2], view_hw, view)
    values = [int(v) for v in np.unique(raw) if v > 0]
    size = (view_hw[1], view_hw[0])
    if not values:
        return np.zeros(view_hw, np.int64)
    shrink = view_hw[0] < raw.shape[0]
    cover = np.stack([cv2.resize((raw == v).astype(np.float32), size,
                                 interpolation=cv2.INTER_AREA if shrink else cv2.INTER_NEAREST) for v in values])
    best = cover.argmax(0)
    return np.where(cover.max(0) > 0, np.asarray(values, np.int64)[best], 0)


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
    img = decode_image(src)
    if img.dtype not in (np.uint8, np.uint16):
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


STROKES_DIR = "strokes"
"""Sub-folder of a scene's ``masks/`` where the masks page saves each painted view's strokes
(:func:`save_stroke_map`), beside the view's cut ``masks/<stem>.png``; the ``reconstruct`` stage carries it into the
scene's layout as it does the cuts (undistorted alike)."""


def stroke_map_path(masks_dir: str | os.PathLike, stem: str) -> Path:
    """Where the strokes of view ``stem`` are saved: ``<masks_dir>/strokes/<stem>.png``."""
    return Path(masks_dir) / STROKES_DIR / f"{stem}.png"


def save_stroke_map(path: str | os.PathLike, seeds: np.ndarray) -> None:
    """Save a stroke seed map ``(H, W) int`` (-1 no stroke, 0 the background brush, k label k) as a label PNG of
    value ``seed + 1`` (0: no stroke, so that pixels an undistortion leaves empty are no stroke), atomically."""
    save_labels(path, np.asarray(seeds, np.int64) + 1)


def load_stroke_map(path: str | os.PathLike, hw: tuple[int, int]) -> np.ndarray:
    """The seed map ``(H, W) int64`` (-1 no stroke, 0..L) :func:`save_stroke_map` saved; its size must be ``hw``."""
    return load_labels(path, expect_hw=hw) - 1
