"""Pictures people look at: side-by-side grids with captions, and videos."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from abcgs.io.atomic import atomic_path
from abcgs.io.images import to_uint8

LABEL_COLOURS = np.array(
    [[0, 0, 0], [230, 25, 75], [60, 180, 75], [255, 225, 25], [0, 130, 200], [245, 130, 48], [145, 30, 180],
     [70, 240, 240], [240, 50, 230], [210, 245, 60], [250, 190, 212], [0, 128, 128], [220, 190, 255],
     [170, 110, 40], [255, 250, 200], [128, 0, 0], [170, 255, 195]], np.uint8)
"""RGB of content labels 0 (black: unassigned), 1, 2, … in masks, grids and the drawing page; labels past the end
take the colours from 1 on again."""


def colorize_labels(labels: np.ndarray) -> np.ndarray:
    """``(H, W)`` labels → ``(H, W, 3) uint8`` in :data:`LABEL_COLOURS`."""
    lab = np.asarray(labels).astype(np.int64)
    return LABEL_COLOURS[np.where(lab > 0, (lab - 1) % (len(LABEL_COLOURS) - 1) + 1, 0)]


def _fit(img: np.ndarray, height: int) -> np.ndarray:
    img = img if img.dtype == np.uint8 else to_uint8(img)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.shape[0] != height:
        w = max(1, round(img.shape[1] * height / img.shape[0]))
        img = cv2.resize(img, (w, height), interpolation=cv2.INTER_AREA)
    return img


def image_grid(rows: list[list[np.ndarray]], captions: list[str] | None = None, height: int = 160, pad: int = 4) -> np.ndarray:
    """Rows of images (float [0, 1] or uint8, any sizes) → one ``uint8`` RGB grid, each cell ``height`` px high.

    ``captions`` label the columns (drawn above the first row).
    """
    cells = [[_fit(im, height) for im in row] for row in rows]
    n_cols = max(len(r) for r in cells)
    col_w = [max(r[c].shape[1] for r in cells if c < len(r)) for c in range(n_cols)]
    top = 18 if captions else 0
    H = top + len(cells) * (height + pad) + pad
    W = sum(col_w) + pad * (n_cols + 1)
    grid = np.full((H, W, 3), 255, np.uint8)
    y = top + pad
    for row in cells:
        x = pad
        for c, im in enumerate(row):
            grid[y : y + height, x : x + im.shape[1]] = im
            x += col_w[c] + pad
        y += height + pad
    if captions:
        x = pad
        for c, text in enumerate(captions[:n_cols]):
            cv2.putText(grid, text, (x + 2, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
            x += col_w[c] + pad
    return grid


def style_legend(entries: list[tuple[np.ndarray | None, np.ndarray, np.ndarray | None]], height: int = 160) -> np.ndarray:
    """One panel pairing each content label's colour with its painting: ``entries`` = ``[(rgb (3,) uint8 or None,
    painting (H, W, 3), region (H, W) bool or None), …]``. A region dims the painting outside it (semantic
    transfer: the part of one painting bound to that label); ``rgb`` None draws no swatch (single transfer).
    Stacked top to bottom, ``uint8`` ``(height, w, 3)``.
    """
    if not entries:
        raise ValueError("style_legend: no entries")
    n = len(entries)
    pad = 2
    cell_h = max(8, (height - pad * (n - 1)) // n)
    tiles = []
    for rgb, painting, region in entries:
        img = painting if painting.dtype == np.uint8 else to_uint8(painting)
        if region is not None:
            dim = (img.astype(np.float32) * 0.25 + 191).astype(np.uint8)
            img = np.where(region[..., None], img, dim)
        img = _fit(img, cell_h)
        if rgb is None:
            tiles.append(img)
            continue
        swatch = np.empty((cell_h, max(8, cell_h // 3), 3), np.uint8)
        swatch[:] = np.asarray(rgb, np.uint8)
        tiles.append(np.concatenate([swatch, np.full((cell_h, pad, 3), 255, np.uint8), img], axis=1))
    width = max(t.shape[1] for t in tiles)
    panel = np.full((height, width, 3), 255, np.uint8)
    y = 0
    for t in tiles:
        panel[y:y + cell_h, :t.shape[1]] = t
        y += cell_h + pad
    return panel


def write_video(path: str | os.PathLike, frames: list[np.ndarray], fps: int = 24) -> None:
    """Write RGB frames as an mp4 (H.264 via imageio-ffmpeg; MJPEG .avi via OpenCV if that is missing), atomically."""
    path = Path(path)
    frames = [f if f.dtype == np.uint8 else to_uint8(f) for f in frames]
    # even sizes for yuv420p
    h, w = frames[0].shape[:2]
    frames = [f[: h - h % 2, : w - w % 2] for f in frames]
    with atomic_path(path) as tmp:
        try:
            import imageio.v2 as imageio

            with imageio.get_writer(str(tmp), format="FFMPEG", fps=fps, codec="libx264", quality=8,
                                    pixelformat="yuv420p", macro_block_size=1) as writer:
                for f in frames:
                    writer.append_data(f)
        except Exception:  # no ffmpeg binary: OpenCV's own encoder
            fourcc = cv2.VideoWriter_fourcc(*"mp4v")
            vw = cv2.VideoWriter(str(tmp), fourcc, fps, (frames[0].shape[1], frames[0].shape[0]))
            for f in frames:
                vw.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
            vw.release()
