"""Matching groups Ω^z = {style features, content label, Gaussians} for the three transfer types.

- ``single``: one style image for the whole scene (one group covering every pixel).
- ``compositional``: several style images, each bound to a content label (``styles: {label: style}``).
- ``semantic``: regions of one painting (its label map) bound to content labels (``binding: {content: style}``,
  or ``"auto"``: content label j ↔ style label j).

Style regions are isolated (:mod:`abcgs.features.isolation`) before VGG so that no receptive field sees
another region.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from abcgs.errors import InputError
from abcgs.features.isolation import region_features
from abcgs.features.params import ALL_PIXELS, IsolationParams, TransferSpec
from abcgs.features.vgg import VGG16Features, extract_features
from abcgs.io.images import load_image, load_labels
from abcgs.types import MatchingGroup


def resize_to_height(img: np.ndarray, height: int) -> np.ndarray:
    """``(H, W, 3)`` → height ``height``, aspect kept (area filter when shrinking, as the authors' cv2.INTER_AREA)."""
    if height <= 0 or img.shape[0] == height:
        return img
    width = max(8, round(img.shape[1] * height / img.shape[0]))
    return cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA if img.shape[0] > height else cv2.INTER_CUBIC)


def load_style(path: str, height: int) -> np.ndarray:
    """A style image resized to ``height`` (aspect kept); a 1×1 or unreadable image is an error."""
    img = load_image(path)
    if min(img.shape[:2]) < 8:
        raise InputError(f"style image {path} is {img.shape[1]}x{img.shape[0]}; it must be at least 8x8 pixels")
    return resize_to_height(img, height)


def build_groups(
    exp: TransferSpec,
    style_paths: dict[str, str],
    style_mask_paths: dict[str, str],
    content_labels: set[int],
    vgg: VGG16Features,
    *,
    style_height: int = 256,
    isolation: IsolationParams | None = None,
    layers: list[str] | None = None,
) -> list[MatchingGroup]:
    """Resolve a transfer (scene × type × painting(s)) into matching groups, with clear errors for unknown
    styles/labels."""
    isolation = isolation or IsolationParams()
    for key in exp.style_keys():
        if key not in style_paths:
            raise InputError(f"style {key!r} is not in data.styles (known: {', '.join(sorted(style_paths)) or 'none'})")

    def whole(key: str, label: int) -> MatchingGroup:
        img = load_style(style_paths[key], style_height)
        x = torch.from_numpy(img).permute(2, 0, 1)[None].to(vgg.device)
        with torch.no_grad():
            f = extract_features(vgg, x, layers)[0]
        return MatchingGroup(label, key, img.reshape(-1, 3), f.reshape(f.shape[0], -1), img)

    if exp.transfer == "single":
        return [whole(exp.style, ALL_PIXELS)]
    if exp.transfer == "compositional":
        unknown = sorted(set(exp.styles) - content_labels)
        if unknown:
            raise InputError(
                f"compositional binding names content label(s) {unknown} that no Gaussian carries "
                f"(labels present: {sorted(content_labels)})"
            )
        return [whole(key, label) for label, key in sorted(exp.styles.items())]
    # semantic
    key = exp.style
    if key not in style_mask_paths:
        raise InputError(f"semantic transfer needs a label map of style {key!r} in data.style_masks")
    img = load_style(style_paths[key], style_height)
    raw = load_labels(style_mask_paths[key])
    labels = cv2.resize(raw.astype(np.int32), (img.shape[1], img.shape[0]), interpolation=cv2.INTER_NEAREST)
    style_labels = sorted(int(v) for v in np.unique(labels) if v != 0)
    if exp.binding == "auto":
        unbound = sorted(j for j in content_labels if j not in style_labels)
        if unbound:
            raise InputError(
                f"semantic transfer with binding auto pairs content label j with painting label j, but the painting's "
                f"label map {style_mask_paths[key]} has no region for content label(s) {unbound} (its labels: "
                f"{style_labels}), which would stay unstylized. Give an explicit binding, e.g. binding: "
                f"{{{', '.join(f'{j}: {style_labels[0]}' for j in unbound)}}} plus the labels that do match, or paint "
                "those regions into the label map")
        binding = {j: j for j in sorted(content_labels)}
    else:
        binding = dict(exp.binding)
    if not binding:
        raise InputError(f"semantic transfer: no content label ({sorted(content_labels)}) matches a style label ({style_labels})")
    groups = []
    for c_label, s_label in sorted(binding.items()):
        if c_label not in content_labels:
            raise InputError(f"binding names content label {c_label}, which no Gaussian carries (present: {sorted(content_labels)})")
        region = labels == s_label
        if not region.any():
            raise InputError(f"style label {s_label} of {style_mask_paths[key]} has no pixels (labels present: {style_labels})")
        feats = region_features(
            vgg, img, region, isolation.method, erode_px=isolation.erode_px, label=s_label, layers=layers
        )
        groups.append(MatchingGroup(c_label, f"{key}:{s_label}", img[region], feats, img, region))
    return groups
