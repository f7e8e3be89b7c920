"""Style isolation (paper Sec. "Style Isolation"): style features of one region, free of other regions.

For a style image ``(H, W, 3)`` and a boolean region mask ``(H, W)`` the region's pixels are kept and
every other pixel is completed **only from the region's own pixels**, so no VGG receptive field sees
another region:

- ``mirror`` (default): each outside pixel ``p`` takes the reflection ``2q − p`` of itself about its
  nearest inside pixel ``q`` (OpenCV ``distanceTransformWithLabels``) when that lands inside the region,
  else ``q`` itself — texture is mirrored across the region boundary.
- ``translate``: the region's bounding-box crop (its non-region holes first completed by ``mirror``
  within the crop) is tiled periodically over the image, anchored at the region's position.
- ``fill``: the region's mean colour.

The authors' code fills with black (not offered: it injects a colour that is not in the region).
Output depends only on ``(mask, image[mask])``: changing pixels outside the region changes nothing.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from abcgs.errors import InputError
from abcgs.features.params import IsolationMethod
from abcgs.features.vgg import VGG16Features, extract_features


def _check_inputs(img: np.ndarray, mask: np.ndarray, label: object) -> tuple[np.ndarray, np.ndarray]:
    img = np.asarray(img)
    mask = np.asarray(mask)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"style image must be (H, W, 3) RGB, got shape {img.shape}")
    if mask.shape != img.shape[:2]:
        raise InputError(
            f"style mask{_lab(label)} is {mask.shape[1]}x{mask.shape[0]} but the style image is "
            f"{img.shape[1]}x{img.shape[0]}; masks must match their image"
        )
    if mask.dtype != np.bool_:
        raise InputError(f"style mask{_lab(label)} must be boolean, got dtype {mask.dtype}")
    return img, mask


def _lab(label: object) -> str:
    return f" for label {label}" if label is not None else ""


def erode_mask(mask: np.ndarray, erode_px: int, label: object = None) -> np.ndarray:
    """Erode a boolean ``(H, W)`` mask by a disc of radius ``erode_px`` pixels (image borders don't erode).

    Raises :class:`InputError` naming ``label`` when the region is empty before or after erosion.
    """
    if erode_px < 0:
        raise InputError(f"erosion must be >= 0 pixels, got {erode_px}")
    if not mask.any():
        raise InputError(f"style region{_lab(label)} is empty: the style mask has no pixel with that label")
    if erode_px == 0:
        return mask
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * erode_px + 1, 2 * erode_px + 1))
    out = cv2.erode(mask.astype(np.uint8), kernel).astype(bool)
    if not out.any():
        raise InputError(
            f"style region{_lab(label)} ({int(mask.sum())} px) vanishes after eroding by {erode_px} px; "
            "use a smaller erosion"
        )
    return out


def _nearest_inside(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every pixel, coordinates ``(qy, qx)`` ``(H, W)`` of an (approximately) nearest inside pixel."""
    h, w = mask.shape
    _, labels = cv2.distanceTransformWithLabels(
        (~mask).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    ys, xs = np.nonzero(mask)
    lut = np.full(int(labels.max()) + 1, -1, dtype=np.int64)
    lut[labels[ys, xs]] = ys.astype(np.int64) * w + xs
    flat = lut[labels]
    if (flat < 0).any():  # cannot happen with OpenCV's pixel labels; guard against a leak anyway
        raise RuntimeError("distanceTransformWithLabels returned a label with no inside pixel")
    return flat // w, flat % w


def _mirror(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    h, w = mask.shape
    qy, qx = _nearest_inside(mask)
    yy, xx = np.mgrid[0:h, 0:w]
    ry, rx = 2 * qy - yy, 2 * qx - xx
    ok = (ry >= 0) & (ry < h) & (rx >= 0) & (rx < w)
    ok[ok] = mask[ry[ok], rx[ok]]
    sy = np.where(ok, ry, qy)
    sx = np.where(ok, rx, qx)
    out = img[sy, sx]
    out[mask] = img[mask]
    return out


def _translate(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    tile = _mirror(img[y0:y1, x0:x1], mask[y0:y1, x0:x1])
    th, tw = y1 - y0, x1 - x0
    iy = (np.arange(h) - y0) % th
    ix = (np.arange(w) - x0) % tw
    out = tile[iy[:, None], ix[None, :]]
    out[mask] = img[mask]
    return out


def _fill(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    out = np.empty_like(img)
    out[...] = img[mask].astype(np.float64).mean(axis=0).astype(img.dtype)
    out[mask] = img[mask]
    return out


def isolate_region(
    img: np.ndarray,
    mask: np.ndarray,
    method: IsolationMethod = "mirror",
    *,
    erode_px: int = 0,
    label: object = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Isolate one style region.

    ``img`` ``(H, W, 3)`` (any dtype), ``mask`` ``(H, W)`` bool. Returns ``(isolated (H, W, 3) same dtype,
    region (H, W) bool)`` where ``region`` is the (optionally eroded) mask actually kept. ``label`` only
    names the region in errors.
    """
    img, mask = _check_inputs(img, mask, label)
    region = erode_mask(mask, erode_px, label)
    if method == "mirror":
        out = _mirror(img, region)
    elif method == "translate":
        out = _translate(img, region)
    elif method == "fill":
        out = _fill(img, region)
    else:
        raise InputError(f"unknown style isolation method {method!r}; choose mirror, translate or fill")
    return np.ascontiguousarray(out), region


def downsample_mask(mask: np.ndarray | torch.Tensor, hw: tuple[int, int], threshold: float = 0.5) -> torch.Tensor:
    """Boolean ``(H, W)`` mask → ``(h, w)`` bool at feature resolution: cells whose area coverage ≥ ``threshold``.

    If no cell reaches ``threshold`` (a region thinner than a feature cell), cells with any coverage are
    used instead, so a non-empty mask never yields an empty set.
    """
    m = torch.as_tensor(np.asarray(mask) if not isinstance(mask, torch.Tensor) else mask)
    if m.ndim != 2:
        raise InputError(f"mask must be (H, W), got shape {tuple(m.shape)}")
    cov = F.interpolate(m.float()[None, None], size=tuple(hw), mode="area")[0, 0]
    sel = cov >= threshold - 1e-6
    if not bool(sel.any()):
        sel = cov > 0
    return sel


def masked_features(feats: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """``(C, h, w)`` or ``(1, C, h, w)`` features and ``(h, w)`` bool mask → ``(C, N)`` selected columns."""
    if feats.ndim == 4:
        if feats.shape[0] != 1:
            raise InputError(f"masked_features takes one image, got batch {feats.shape[0]}")
        feats = feats[0]
    if feats.ndim != 3 or tuple(mask.shape) != tuple(feats.shape[1:]):
        raise InputError(f"features {tuple(feats.shape)} and mask {tuple(mask.shape)} do not match")
    return feats[:, mask.to(feats.device)]


def region_features(
    vgg: VGG16Features,
    img: np.ndarray,
    mask: np.ndarray,
    method: IsolationMethod = "mirror",
    *,
    erode_px: int = 0,
    label: object = None,
    layers: Sequence[str] | None = None,
    threshold: float = 0.5,
) -> torch.Tensor:
    """Style features ``F_s^z`` ``(C, N_s)`` of one region: VGG features of the isolated image, restricted
    to the region downsampled to feature resolution (:func:`downsample_mask`). ``img`` RGB in [0, 1].
    """
    iso, region = isolate_region(img, mask, method, erode_px=erode_px, label=label)
    device = vgg.device
    x = torch.from_numpy(iso.astype(np.float32, copy=False)).permute(2, 0, 1)[None].to(device)
    with torch.no_grad():
        f = extract_features(vgg, x, layers)
    return masked_features(f, downsample_mask(region, tuple(f.shape[-2:]), threshold))
