"""The stylized scene in 3-D: a self-contained web page around the Spark splat viewer.

The page works from ``file://`` with no network: the bundled viewer (``static/abcgs-viewer.js.gz``, built from
``viewer/`` with esbuild: three.js + Spark, WASM inlined) and every splat (``.spz``, base64) are inline.
Per experiment it holds up to three layers over the same Gaussians — ``original`` (the fitted scene),
``stylized`` and ``labels`` (the stylized geometry coloured by lifted content label) — and the training
cameras in three.js convention, so the viewer can step through them and orbit.

A page holds at most ``max_gaussians`` per layer: the most visible Gaussians (opacity × largest footprint)
are kept, the same ones in every layer; the page says so, and the full PLY/SPZ stays the artifact.
"""

from __future__ import annotations

import base64
import gzip
import html
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from abcgs.camera_paths import camera_path, capture_layout
from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.render import rgb_to_sh0
from abcgs.splats.formats.spz import encode_spz
from abcgs.types import FRAME_FILLING, Background, PathKind

BUNDLE = Path(__file__).resolve().parent / "static" / "abcgs-viewer.js.gz"
"""The viewer bundle, gzip-compressed (``make viewer`` builds it; 1.0 MB instead of 2.9 MB in git)."""
LAYERS = ("original", "stylized", "labels")
LABEL_PALETTE = np.array(
    [[0.55, 0.55, 0.55], [0.90, 0.30, 0.25], [0.25, 0.60, 0.90], [0.35, 0.80, 0.35], [0.95, 0.75, 0.20],
     [0.70, 0.40, 0.85], [0.20, 0.80, 0.80], [0.95, 0.55, 0.75], [0.60, 0.45, 0.25], [0.15, 0.25, 0.55]],
    np.float32,
)
"""RGB of content labels 0, 1, … (cycled) in the ``labels`` layer."""


@dataclass
class ViewerExperiment:
    """One experiment as the page shows it: layers (already subsampled) and cameras."""

    name: str
    layers: dict[str, GaussianModel]
    cameras: list[Camera]
    n_gaussians_full: int
    full_artifact: str = "the PLY beside the experiment"
    target: np.ndarray | None = None
    path: list[Camera] = field(default_factory=list)
    path_kind: str = ""
    spz_bytes: dict[str, int] = field(default_factory=dict)
    background: Background = FRAME_FILLING
    """The scene's: an object scene shows on its colour, or over the page when transparent."""
    notes: list[str] = field(default_factory=list)
    """What the page leaves out and why (a labels layer whose rows file is refused), one line each: printed by
    ``python -m abcgs.view``, shown above the viewer (:func:`viewer_fragment`)."""


def visibility_order(model: GaussianModel) -> torch.Tensor:
    """Gaussian indices, most visible first: opacity × (largest scale)², a footprint proxy. ``(N,)`` int64."""
    with torch.no_grad():
        score = torch.sigmoid(model.opacity_logits) * torch.exp(2 * model.log_scales.max(dim=1).values)
        return torch.argsort(score, descending=True, stable=True)


def subsample_indices(model: GaussianModel, max_gaussians: int) -> torch.Tensor:
    """The ``max_gaussians`` most visible Gaussians (all of them if fewer), in their original order."""
    if model.num_gaussians <= max_gaussians:
        return torch.arange(model.num_gaussians)
    return torch.sort(visibility_order(model)[:max_gaussians]).values


def label_colored(model: GaussianModel, labels: np.ndarray | torch.Tensor) -> GaussianModel:
    """``model`` with each Gaussian's colour set to its content label's palette colour (no view dependence)."""
    labels = np.asarray(labels).reshape(-1)
    if labels.shape[0] != model.num_gaussians:
        raise InputError(f"labels: {labels.shape[0]} labels for {model.num_gaussians} Gaussians")
    rgb = torch.from_numpy(LABEL_PALETTE[np.mod(labels.astype(np.int64), len(LABEL_PALETTE))])
    out = model.detach()
    out.sh0 = rgb_to_sh0(rgb)[:, None, :].contiguous()
    out.shN = torch.zeros_like(out.shN)
    return out


def three_camera(cam: Camera) -> dict:
    """A COLMAP/OpenCV camera (x right, y down, looking down +z) as a three.js camera (y up, looking down −z).

    Returns ``position`` (world), ``quaternion`` (xyzw of the camera→world rotation with the y/z axes flipped),
    ``fov_y_deg``, ``aspect`` and the image size. The principal point is taken at the centre.
    """
    R = cam.viewmat[:3, :3]
    c2w = R.T @ np.diag([1.0, -1.0, -1.0])
    w, x, y, z = _matrix_to_quat_wxyz(c2w)
    fy = float(cam.K[1, 1])
    return {
        "name": cam.name, "position": [float(v) for v in cam.center], "quaternion": [x, y, z, w],
        "fov_y_deg": float(np.degrees(2 * np.arctan(cam.height / (2 * fy)))),
        "aspect": cam.width / cam.height, "width": cam.width, "height": cam.height,
    }


def _matrix_to_quat_wxyz(m: np.ndarray) -> tuple[float, float, float, float]:
    """Rotation matrix ``(3, 3)`` → unit quaternion (w, x, y, z), w ≥ 0 (Shepperd's method)."""
    t = np.trace(m)
    if t > 0:
        s = 2.0 * np.sqrt(1.0 + t)
        q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        v = [0.0, 0.0, 0.0]
        v[i] = 0.25 * s
        v[j] = (m[j, i] + m[i, j]) / s
        v[k] = (m[k, i] + m[i, k]) / s
        q = ((m[k, j] - m[j, k]) / s, *v)
    q = np.array(q, float)
    q /= np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    return tuple(float(v) for v in q)


def orbit_target(model: GaussianModel, cam: Camera) -> np.ndarray:
    """A point to orbit about: on ``cam``'s viewing axis at the median depth of the Gaussians in front of it."""
    with torch.no_grad():
        pts = model.means.detach().cpu().double().numpy()
    cam_pts = pts @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
    depth = cam_pts[:, 2][cam_pts[:, 2] > 1e-6]
    d = float(np.median(depth)) if depth.size else 1.0
    forward = cam.viewmat[2, :3]  # camera +z in world
    return cam.center + d * forward


def prepare_experiment(
    name: str,
    stylized: GaussianModel,
    cameras: list[Camera],
    *,
    original: GaussianModel | None = None,
    labels: np.ndarray | None = None,
    max_gaussians: int = 150_000,
    full_artifact: str = "the PLY beside the experiment",
    path_kind: PathKind = "auto",
    path_frames: int = 48,
    background: Background = FRAME_FILLING,
) -> ViewerExperiment:
    """Subsample (the same Gaussians in every layer) and build the layers of one experiment.

    The camera path is :func:`abcgs.camera_paths.camera_path` (the turntable video's); the orbit target is
    the capture's look-at point for an orbit, else a point on the first camera's axis (:func:`orbit_target`).

    ``original`` and ``labels`` share the stylized scene's Gaussians when they have as many; otherwise the
    original layer is subsampled on its own and the labels layer is left out (with a reason in the log).
    """
    if not cameras:
        raise InputError(f"viewer: experiment {name!r} has no cameras")
    idx = subsample_indices(stylized, max_gaussians)
    layers = {"stylized": stylized.index(idx)}
    if original is not None:
        same = original.num_gaussians == stylized.num_gaussians
        layers["original"] = original.index(idx if same else subsample_indices(original, max_gaussians))
    if labels is not None and len(labels) == stylized.num_gaussians:
        layers["labels"] = label_colored(layers["stylized"], np.asarray(labels)[idx.numpy()])
    path, used = camera_path(list(cameras), path_kind, path_frames) if len(cameras) > 1 else ([], "")
    target = capture_layout(list(cameras)).center if used == "orbit" else orbit_target(layers["stylized"], cameras[0])
    return ViewerExperiment(name, layers, list(cameras), stylized.num_gaussians, full_artifact, target, path, used,
                            background=background)


_SCRIPT_ESCAPES = str.maketrans({"<": "\\u003c", ">": "\\u003e", "&": "\\u0026"})


def script_json(data) -> str:
    """``data`` as JSON to place inside a ``<script>`` element: ``<``, ``>`` and ``&`` as ``\\uXXXX`` escapes
    (they occur only inside JSON strings, which read them back unchanged; ``json.dumps`` already escapes every
    non-ASCII character), so no string in it (a run folder named ``<!--`` or ``</script>``) can end or change the
    element."""
    return json.dumps(data).translate(_SCRIPT_ESCAPES)


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


def viewer_fragment(experiments: list[ViewerExperiment], *, max_width: int = 960, bundle: Path = BUNDLE) -> str:
    """HTML (container, inline data, inline bundle) to place in a page's ``<body>``."""
    if not bundle.is_file():
        raise InputError(f"the viewer bundle {bundle} is missing; rebuild it with `make viewer` (needs npm)")
    data, blobs = {"experiments": []}, []
    for i, exp in enumerate(experiments):
        ids = {}
        for layer in LAYERS:
            if layer not in exp.layers:
                continue
            spz = encode_spz(exp.layers[layer])
            exp.spz_bytes[layer] = len(spz)
            ids[layer] = f"abcgs-splat-{i}-{layer}"
            blobs.append(f'<script type="application/octet-stream" id="{ids[layer]}">{_b64(spz)}</script>')
        data["experiments"].append({
            "name": exp.name, "layers": ids, "cameras": [three_camera(c) for c in exp.cameras],
            "target": [float(v) for v in exp.target],
            "path": [three_camera(c) for c in exp.path], "path_kind": exp.path_kind,
            "n_gaussians_page": exp.layers["stylized"].num_gaussians,
            "n_gaussians_full": exp.n_gaussians_full, "full_artifact": exp.full_artifact, "max_width": max_width,
            "background": exp.background.to_json() if exp.background.object else None,
        })
    payload = script_json(data)
    notes = [f'<p class="abcgs-viewer-note">{html.escape(exp.name)}: {html.escape(note)}</p>'
             for exp in experiments for note in exp.notes]
    js = gzip.decompress(bundle.read_bytes()).decode("utf-8").replace("</script", "<\\/script")
    return "\n".join([
        "<style>#abcgs-viewer .abcgs-bar{display:flex;flex-wrap:wrap;gap:6px;align-items:center;margin:6px 0}"
        "#abcgs-viewer button.active{background:#333;color:#fff}#abcgs-viewer .abcgs-note{color:#555;font-size:90%}"
        "#abcgs-viewer .abcgs-error{color:#a00;background:#fee;border:1px solid #a00;padding:8px;margin:6px 0}"
        "#abcgs-canvas{display:block;border:1px solid #ccc}</style>",
        *notes,
        '<div id="abcgs-viewer"></div>',
        f'<script type="application/json" id="abcgs-viewer-data">{payload}</script>',
        *blobs,
        f"<script>{js}</script>",
    ])


def viewer_page(experiments: list[ViewerExperiment], title: str = "abcgs viewer", **kw) -> str:
    """A complete single-page viewer."""
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title></head>"
            f"<body style='font-family:sans-serif;margin:16px'><h1>{html.escape(title)}</h1>"
            f"{viewer_fragment(experiments, **kw)}</body></html>")
