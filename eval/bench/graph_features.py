"""What each affinity of the labels' 3-D step adds: colour, normals, and VGG-16 features lifted onto the Gaussians.

    python -m eval run graph_features --scene miku --work W --json docs/measurements/miku_graph_features.json

On the scripted user's scene (:mod:`eval.bench.scripted_user`: ``eval/data/<scene>/``, the fit under ``--work``), the
front view's test strokes are cut and Segmented once as the page does, with the 3-D step's graph
(:func:`abcgs.masks.graph.gaussian_graph`) built with each setting in turn; the labels of the six reference views are
scored (mean IoU over the (view, label) pairs, the stage's maps). The settings: distance alone, + colour, + normals
(the default), and the default + part features at ``--feature-weights``: the relu3_1 activations of VGG-16 (the
style loss's network, :func:`abcgs.features.weights.resolve_vgg16`) on every ``--every``-th view at half size,
reduced to ``--dims`` principal components and lifted onto the Gaussians (:func:`lift_features`: each Gaussian's
blending-weighted mean over the views that see it, each channel then of unit variance).
"""

from __future__ import annotations

import time
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs.cameras import Camera
from abcgs.gaussians import GaussianModel
from abcgs.io.images import load_image
from abcgs.masks.graph import gaussian_graph
from abcgs.masks.lifting import blend_votes
from abcgs.masks.params import FieldParams
from eval.bench.scripted_user import ScriptedUser
from eval.bench.strokes import DATA, load_case, view_strokes
from eval.labels import score_labels
from eval.record import bench_parser, write_record


def lift_features(model: GaussianModel, cameras: list[Camera], images: list[Path], layer: str = "relu3_1",
                  dims: int = 8, scale: float = 0.5, seed: int = 0) -> np.ndarray:
    """``(N, dims) float64`` per-Gaussian features: VGG-16's ``layer`` on each image (at ``scale``), projected on
    the ``dims`` principal components of a sample of its pixels, upsampled to the view and lifted (each Gaussian's
    blending-weighted mean, :func:`abcgs.masks.lifting.blend_votes`); each channel standardised over the Gaussians
    some view sees (0 for the others)."""
    from abcgs.features.vgg import VGG16Features
    from abcgs.features.weights import resolve_vgg16

    sd, info = resolve_vgg16()
    vgg = VGG16Features(sd, (layer,), feature_scale=info.feature_scale)
    g = torch.Generator().manual_seed(seed)
    maps = []
    with torch.no_grad():
        for path in images:
            img = torch.from_numpy(load_image(path)).permute(2, 0, 1)[None].float()
            maps.append(vgg(torch.nn.functional.interpolate(img, scale_factor=scale, mode="area"))[layer][0])
    sample = torch.cat([m.flatten(1)[:, torch.randperm(m[0].numel(), generator=g)[:2000]] for m in maps], 1).T
    mean = sample.mean(0)
    _, _, basis = torch.pca_lowrank(sample - mean, q=dims, center=False)
    acc = torch.zeros(model.num_gaussians, dims + 1)
    for cam, m in zip(cameras, maps):
        proj = ((m.flatten(1).T - mean) @ basis).T.reshape(dims, *m.shape[1:])
        full = torch.nn.functional.interpolate(proj[None], size=(cam.height, cam.width), mode="bilinear")[0]
        pixels = torch.cat([full, torch.ones(1, cam.height, cam.width)]).permute(1, 2, 0).contiguous()
        acc += blend_votes(model, cam, pixels)
    seen = (acc[:, dims] > 1e-3).numpy()
    feats = (acc[:, :dims] / acc[:, dims:].clamp_min(1e-6)).double().numpy()
    feats[seen] = (feats[seen] - feats[seen].mean(0)) / feats[seen].std(0).clip(1e-12)
    feats[~seen] = 0.0
    return feats


def main(argv: list[str] | None = None) -> int:
    ap = bench_parser(__doc__)
    ap.add_argument("--scene", default="miku", help="eval/data/<scene>/ (strokes.json, reference/)")
    ap.add_argument("--work", type=Path, required=True, help="where eval.bench.fit left the fitted scene")
    ap.add_argument("--every", type=int, default=2, help="lift the features from every k-th view")
    ap.add_argument("--dims", type=int, default=8, help="principal components of the features kept")
    ap.add_argument("--feature-weights", default="0.5,2,10", help="λ_f of the part affinity, comma-separated")
    args = ap.parse_args(argv)
    case = load_case(DATA / args.scene, args.scene, args.work)
    spec, scene, model, by_stem, refs = case.spec, case.scene, case.model, case.by_stem, case.refs
    front = by_stem[spec["test"]["view"]]
    t0 = time.perf_counter()
    idx = list(range(0, len(scene.cameras), args.every))
    feats = lift_features(model, [scene.cameras[i] for i in idx], [scene.image_paths[i] for i in idx], dims=args.dims)
    lift_seconds = time.perf_counter() - t0
    print(f"VGG-16 relu3_1 of {len(idx)} views lifted onto {model.num_gaussians} Gaussians in {lift_seconds:.1f} s")
    default = FieldParams()
    settings = {"distance": dict(colour_sigma=float("inf"), normal_weight=0.0),
                "+ colour": dict(colour_sigma=default.colour_sigma, normal_weight=0.0),
                "+ normals (default)": dict(colour_sigma=default.colour_sigma, normal_weight=default.normal_weight)}
    for w in (float(v) for v in args.feature_weights.split(",")):
        settings[f"+ VGG features, λ_f {w:g}"] = dict(colour_sigma=default.colour_sigma,
                                                      normal_weight=default.normal_weight, features=feats,
                                                      feature_weight=w)
    rows = {}
    for name, kw in settings.items():
        user = ScriptedUser(model, scene, refs, by_stem, default)
        user.session.field.use_graph(gaussian_graph(model, default.k, **kw))
        user.strokes[front] = list(view_strokes(spec["test"]["strokes"], spec, scene.cameras[front]))
        user.segment(front)
        s = score_labels(user.maps(), refs, len(spec["labels"]))
        rows[name] = {"mean_iou": s.mean_iou, "view_mean": s.view_mean}
        print(f"{name:28s} mean IoU {s.mean_iou:.4f}  " + "  ".join(f"{v[-4:]} {m:.3f}" for v, m in
                                                                    s.view_mean.items()), flush=True)
    if args.json:
        write_record(args.json, {"scene": spec["title"], "n_gaussians": model.num_gaussians, "feature_views": len(idx),
                                 "dims": args.dims, "lift_seconds": lift_seconds, "settings": rows}, argv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
