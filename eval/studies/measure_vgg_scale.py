"""Measure VGG-16 relu3_x activation statistics of the resolved weights on natural images.

Documents (and lets anyone re-check) the number behind ``abcgs.features.weights.KERAS_FEATURE_SCALE``.
Images: every ``*.jpg`` under ``--data`` (default ``/work/shared/data``: the fern photos and the style
paintings), resized to long side ``--long-side`` and then ×0.5 (the renders' pre-VGG downsampling).

    python -m eval run measure_vgg_scale [--data DIR] [--long-side 512]

Prints, per layer, mean and RMS of the raw activations (feature_scale = 1) and after the source's
feature scale.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import cv2
import torch

from abcgs.features.params import VggWeightsParams
from abcgs.features.vgg import DEFAULT_LAYERS, VGG16Features, downsample_half
from abcgs.features.weights import resolve_vgg16
from abcgs.io.images import load_image


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default="/work/shared/data")
    ap.add_argument("--long-side", type=int, default=512)
    args = ap.parse_args()
    torch.set_num_threads(2)
    sd, info = resolve_vgg16(VggWeightsParams(allow_download=False))
    vgg = VGG16Features(sd, DEFAULT_LAYERS, feature_scale=1.0)
    files = sorted(Path(args.data).rglob("*.jpg"))
    if not files:
        raise SystemExit(f"no *.jpg under {args.data}")
    sums = {n: [0.0, 0.0, 0] for n in DEFAULT_LAYERS}
    with torch.no_grad():
        for f in files:
            img = load_image(f)
            s = args.long_side / max(img.shape[:2])
            img = cv2.resize(img, (round(img.shape[1] * s), round(img.shape[0] * s)), interpolation=cv2.INTER_AREA)
            x = downsample_half(torch.from_numpy(img).permute(2, 0, 1)[None])
            for n, t in vgg(x).items():
                sums[n][0] += float(t.sum())
                sums[n][1] += float((t.double() ** 2).sum())
                sums[n][2] += t.numel()
    print(f"weights: {info.source} ({info.path}); feature_scale = {info.feature_scale:.6g}; {len(files)} images")
    for n, (s1, s2, cnt) in sums.items():
        mean, rms = s1 / cnt, (s2 / cnt) ** 0.5
        print(
            f"{n}: raw mean {mean:8.3f} rms {rms:8.3f} | scaled mean {mean * info.feature_scale:7.3f} "
            f"rms {rms * info.feature_scale:7.3f}"
        )


if __name__ == "__main__":
    main()
