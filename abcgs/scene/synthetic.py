"""The embedded default scene: a small forward-facing scene ray-cast in numpy.

A textured back wall, an oriented box and a sphere at different depths, seen from a gentle
forward-facing grid of cameras (LLFF-like). Everything is generated from a seed, so the same
:class:`TinySceneParams` always gives byte-identical files. Nothing is downloaded.

``layout: orbit`` makes the object-centred variant: the same box and sphere inside a textured dome
(label 1, the background), seen from a ring of cameras all around them (a turntable capture).

World frame (OpenCV-like): x right, y down, z forward (away from the cameras); units are arbitrary
"metres"; the cameras sit near ``z = 0`` and the wall at ``z = wall_depth``.

Written layout (see :func:`write_tiny_scene`)::

    images/000.png …       RGB views, width x height
    masks/000.png …        single-channel label maps (1 = wall, 2 = box, 3 = sphere, 0 = nothing)
    cameras.json           ground-truth K, viewmat (world→camera), width, height per view
    styles/paint.png       procedural "painting" (brush strokes, 3 colour regions)
    styles/paint_labels.png  its region labels 1..3 (for semantic transfer)
    styles/paint2.png      a second painting (for compositional transfer)
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.io.atomic import atomic_path, write_json
from abcgs.io.images import save_image, save_labels
from abcgs.scene.paintings import make_paintings
from abcgs.scene.params import TinySceneParams

LABEL_NAMES = {1: "wall", 2: "box", 3: "sphere"}
"""Content labels written to ``masks/``; 0 = no surface."""

_FAR = np.float32(1e9)


@dataclass
class TinyScene:
    """A generated scene held in memory.

    Attributes:
        images: per view ``(H, W, 3) float32`` RGB in ``[0, 1]``.
        labels: per view ``(H, W) int64`` content labels (see :data:`LABEL_NAMES`).
        cameras: ground-truth cameras, same order as ``images``.
        styles: style images by file stem (``paint``, ``paint2``), ``(Hs, Ws, 3) float32``.
        style_labels: label map of ``paint``, ``(Hs, Ws) int64`` with labels 1..3.
    """

    images: list[np.ndarray]
    labels: list[np.ndarray]
    cameras: list[Camera]
    styles: dict[str, np.ndarray]
    style_labels: np.ndarray


# ----------------------------------------------------------------------------------------------
# Textures
# ----------------------------------------------------------------------------------------------


def _value_noise(rng: np.random.Generator, h: int, w: int, octaves: int = 5) -> np.ndarray:
    """Multi-octave value noise ``(h, w, 3) float32`` roughly in ``[-1, 1]`` (not periodic)."""
    out = np.zeros((h, w, 3), np.float32)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        cells = 3 * 2**o
        grid = rng.uniform(-1.0, 1.0, size=(cells + 1, cells + 1, 3)).astype(np.float32)
        out += amp * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= 0.6
    return out / total


def make_texture(rng: np.random.Generator, h: int, w: int, base: tuple[float, float, float], n_shapes: int) -> np.ndarray:
    """A feature-rich texture ``(h, w, 3) float32`` in ``[0, 1]``.

    Coloured multi-octave noise around ``base`` (RGB) plus ``n_shapes`` random discs, rectangles
    and triangles of random size, lighter or darker than ``base``: plenty of blobs and corners for SIFT, and no periodic
    pattern that would confuse matching.
    """
    base_arr = np.asarray(base, np.float32)
    tex = base_arr + 0.3 * _value_noise(rng, h, w)
    canvas = np.clip(tex * 255.0, 0, 255).astype(np.uint8).copy()
    size = min(h, w)
    for _ in range(n_shapes):
        # Muted colours near the base hue with strong lightness changes: contrast for SIFT without
        # the saturated palette of the paintings.
        shade = base_arr * rng.uniform(0.2, 1.7) + rng.normal(0.0, 0.08, size=3)
        colour = tuple(int(c) for c in np.clip(shade * 255.0, 0, 255))
        cx, cy = int(rng.integers(0, w)), int(rng.integers(0, h))
        r = int(size * np.exp(rng.uniform(np.log(0.006), np.log(0.05))))
        kind = rng.integers(0, 3)
        if kind == 0:
            cv2.circle(canvas, (cx, cy), max(r, 2), colour, -1, cv2.LINE_AA)
        elif kind == 1:
            dx, dy = int(r * rng.uniform(0.5, 2.0)), int(r * rng.uniform(0.5, 2.0))
            cv2.rectangle(canvas, (cx - dx, cy - dy), (cx + dx, cy + dy), colour, -1, cv2.LINE_AA)
        else:
            pts = np.array([[cx, cy]]) + rng.integers(-2 * r - 2, 2 * r + 3, size=(3, 2))
            cv2.fillConvexPoly(canvas, pts.astype(np.int32), colour, cv2.LINE_AA)
    return canvas.astype(np.float32) / 255.0


# ----------------------------------------------------------------------------------------------
# Geometry and ray casting
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Wall:
    depth: float
    half_w: float
    half_h: float


@dataclass(frozen=True)
class _Box:
    """A cube (``half`` has equal entries; texture coords assume it)."""

    center: np.ndarray  # (3,)
    half: np.ndarray  # (3,) half extents along the box axes
    R: np.ndarray  # (3, 3) columns = box axes in world


@dataclass(frozen=True)
class _Sphere:
    center: np.ndarray  # (3,)
    radius: float


@dataclass(frozen=True)
class _Layout:
    wall: _Wall | None  # None: the object layout (nothing behind the objects)
    box: _Box
    sphere: _Sphere
    light: np.ndarray  # (3,) unit vector towards the light
    dome: _Sphere | None = None  # orbit layout: the background seen from inside (replaces the wall)


def _rot_y(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def _rot_x(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


def scene_layout(p: TinySceneParams) -> _Layout:
    """Object placement, scaled with the wall depth (box left of centre, sphere right and nearer)."""
    d = p.wall_depth
    wall = None if p.layout == "object" else _Wall(depth=d, half_w=d * 1.2, half_h=d * 0.9)
    box = _Box(center=np.array([-0.17 * d, 0.05 * d, 0.62 * d]), half=np.full(3, 0.085 * d), R=_rot_y(35.0) @ _rot_x(-20.0))
    sphere = _Sphere(center=np.array([0.14 * d, -0.02 * d, 0.45 * d]), radius=0.08 * d)
    light = np.array([-0.4, -0.6, -0.7])
    dome = _Sphere(center=orbit_center(p), radius=0.9 * d) if p.layout == "orbit" else None
    return _Layout(wall, box, sphere, light / np.linalg.norm(light), dome)


def orbit_center(p: TinySceneParams) -> np.ndarray:
    """The point the orbit cameras circle and look at: between the box and the sphere."""
    d = p.wall_depth
    return np.array([-0.015 * d, 0.015 * d, 0.535 * d])


def _rays(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Ray origin ``(3,)`` and unit directions ``(H*W, 3)`` through pixel centres, in world frame."""
    u, v = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    pix = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
    d_cam = pix @ np.linalg.inv(cam.K).T
    R = cam.viewmat[:3, :3]
    d = d_cam @ R  # R^T d_cam for each row
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return cam.center, d


def _hit_wall(o: np.ndarray, d: np.ndarray, w: _Wall) -> tuple[np.ndarray, np.ndarray]:
    """Distance ``(N,)`` (``_FAR`` on a miss) and texture coords ``(N, 2)`` in ``[0, 1]``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w.depth - o[2]) / d[:, 2]
    p = o + t[:, None] * d
    ok = (t > 0) & (np.abs(p[:, 0]) <= w.half_w) & (np.abs(p[:, 1]) <= w.half_h)
    uv = np.stack([(p[:, 0] + w.half_w) / (2 * w.half_w), (p[:, 1] + w.half_h) / (2 * w.half_h)], axis=1)
    return np.where(ok, t, _FAR), uv


def _hit_box(o: np.ndarray, d: np.ndarray, b: _Box) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slab test in box coordinates. Returns distance, atlas texture coords ``(N, 2)``, world normals ``(N, 3)``."""
    ol = (o - b.center) @ b.R
    dl = d @ b.R
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(np.abs(dl) < 1e-12, 1e-12, dl)
    t1, t2 = (-b.half - ol) * inv, (b.half - ol) * inv
    tmin, tmax = np.minimum(t1, t2).max(axis=1), np.maximum(t1, t2).min(axis=1)
    ok = (tmax >= tmin) & (tmin > 0)
    p = ol + tmin[:, None] * dl
    axis = np.argmax(np.minimum(t1, t2), axis=1)  # the slab entered last is the face hit
    sign = np.sign(np.take_along_axis(p, axis[:, None], axis=1))[:, 0]
    face = axis * 2 + (sign > 0)
    # In-face coordinates: the two other axes, normalised to [0, 1].
    a1, a2 = (axis + 1) % 3, (axis + 2) % 3
    s = np.take_along_axis(p, a1[:, None], axis=1)[:, 0] / (2 * b.half[0]) + 0.5
    r = np.take_along_axis(p, a2[:, None], axis=1)[:, 0] / (2 * b.half[0]) + 0.5
    uv = np.stack([(face % 3 + np.clip(s, 0, 1)) / 3.0, (face // 3 + np.clip(r, 0, 1)) / 2.0], axis=1)
    n_local = np.zeros_like(p)
    np.put_along_axis(n_local, axis[:, None], sign[:, None], axis=1)
    return np.where(ok, tmin, _FAR), uv, n_local @ b.R.T


def _hit_sphere(o: np.ndarray, d: np.ndarray, s: _Sphere) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance, longitude/latitude texture coords ``(N, 2)`` and normals ``(N, 3)``."""
    oc = o - s.center
    b = d @ oc
    disc = b**2 - (oc @ oc - s.radius**2)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    ok = (disc > 0) & (t > 0)
    n = (oc + t[:, None] * d) / s.radius
    uv = np.stack([np.arctan2(n[:, 0], -n[:, 2]) / (2 * np.pi) + 0.5, np.arccos(np.clip(n[:, 1], -1, 1)) / np.pi], axis=1)
    return np.where(ok, t, _FAR), uv, n


def _hit_dome(o: np.ndarray, d: np.ndarray, s: _Sphere) -> tuple[np.ndarray, np.ndarray]:
    """A sphere seen from inside (the far root): distance and longitude/latitude texture coords ``(N, 2)``."""
    oc = o - s.center
    b = d @ oc
    disc = b**2 - (oc @ oc - s.radius**2)
    t = -b + np.sqrt(np.maximum(disc, 0.0))
    ok = (disc > 0) & (t > 0)
    n = (oc + t[:, None] * d) / s.radius
    uv = np.stack([np.arctan2(n[:, 0], -n[:, 2]) / (2 * np.pi) + 0.5, np.arccos(np.clip(n[:, 1], -1, 1)) / np.pi], axis=1)
    return np.where(ok, t, _FAR), uv


def _sample(tex: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear texture lookup: ``tex (h, w, 3)``, ``uv (N, 2)`` in ``[0, 1]`` → ``(N, 3)``."""
    h, w = tex.shape[:2]
    n, row = uv.shape[0], 1024  # remap maps must be < 32767 on each side: lay the samples out in rows
    pad = (-n) % row
    mx = np.pad(uv[:, 0] * w - 0.5, (0, pad)).astype(np.float32).reshape(-1, row)
    my = np.pad(uv[:, 1] * h - 0.5, (0, pad)).astype(np.float32).reshape(-1, row)
    out = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return out.reshape(-1, 3)[:n]


def _cast(cam: Camera, lay: _Layout, tex: dict[int, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Render one camera: RGB ``(H, W, 3) float32`` and labels ``(H, W) int64``."""
    o, d = _rays(cam)
    if lay.dome is not None:
        t_wall, uv_wall = _hit_dome(o, d, lay.dome)
    elif lay.wall is not None:
        t_wall, uv_wall = _hit_wall(o, d, lay.wall)
    else:  # the object layout: nothing behind the objects
        t_wall, uv_wall = np.full(d.shape[0], _FAR), np.zeros((d.shape[0], 2))
    t_box, uv_box, n_box = _hit_box(o, d, lay.box)
    t_sph, uv_sph, n_sph = _hit_sphere(o, d, lay.sphere)
    ts = np.stack([np.full_like(t_wall, _FAR), t_wall, t_box, t_sph], axis=1)
    label = np.argmin(ts, axis=1)  # 0 wins only when everything misses
    rgb = np.zeros((d.shape[0], 3), np.float32)
    for lab, uv, n in ((1, uv_wall, None), (2, uv_box, n_box), (3, uv_sph, n_sph)):
        sel = label == lab
        if not sel.any():
            continue
        colour = _sample(tex[lab], uv[sel])
        if n is not None:  # Lambert + ambient; the wall is lit uniformly
            colour = colour * (0.55 + 0.45 * np.clip(n[sel] @ lay.light, 0, 1))[:, None]
        rgb[sel] = colour
    return rgb.reshape(cam.height, cam.width, 3), label.reshape(cam.height, cam.width).astype(np.int64)


# ----------------------------------------------------------------------------------------------
# Cameras
# ----------------------------------------------------------------------------------------------


def ring_cameras(p: TinySceneParams, rng: np.random.Generator) -> list[Camera]:
    """``n_views`` cameras on a full ring around :func:`orbit_center`, slightly above it, looking at it
    (consecutive views are neighbours); a small seeded jitter breaks the regularity."""
    c = orbit_center(p)
    radius, lift = 0.45 * p.wall_depth, 0.12 * p.wall_depth
    cams = []
    for i in range(p.n_views):
        a = 2 * math.pi * i / p.n_views
        eye = c + np.array([radius * math.sin(a), -lift, -radius * math.cos(a)]) + rng.normal(0.0, 0.01 * radius, size=3)
        width = p.width - (p.odd_view_width_delta if i % 2 else 0)
        K = intrinsics(p.focal_factor * p.width, width, p.height)
        cams.append(Camera(f"{i:03d}.png", K, look_at(eye, c, up=np.array([0.0, 1.0, 0.0])), width, p.height))
    return cams


def dome_cameras(p: TinySceneParams, rng: np.random.Generator) -> list[Camera]:
    """``n_views`` cameras on three rings around :func:`orbit_center` at 10°, 25° and 40° above it (world ``-y`` is
    up), each ring's azimuths offset from the one below, looking at it (an object captured from all round and above,
    as NeRF-synthetic's hemisphere of views); a small seeded jitter breaks the regularity."""
    c = orbit_center(p)
    radius = 0.85 * p.wall_depth  # the whole object in every view
    sizes = [p.n_views // 3 + (1 if r < p.n_views % 3 else 0) for r in range(3)]
    cams = []
    for r, (elev, n) in enumerate(zip((10.0, 25.0, 40.0), sizes)):
        e = math.radians(elev)
        for k in range(n):
            a = 2 * math.pi * (k + 0.5 * r) / n
            eye = c + radius * np.array([math.cos(e) * math.sin(a), -math.sin(e), -math.cos(e) * math.cos(a)])
            eye = eye + rng.normal(0.0, 0.01 * radius, size=3)
            K = intrinsics(p.focal_factor * p.width, p.width, p.height)
            cams.append(Camera(f"{len(cams):03d}.png", K, look_at(eye, c, up=np.array([0.0, 1.0, 0.0])), p.width,
                               p.height))
    return cams


def grid_cameras(p: TinySceneParams, rng: np.random.Generator) -> list[Camera]:
    """``n_views`` cameras on a serpentine grid in the plane ``z = 0`` (consecutive views are neighbours).

    Every camera looks at a point on the wall's axis at two thirds of the wall depth, so the arc is
    gently convergent like a hand-held LLFF capture; a small seeded jitter breaks the regularity.
    """
    cols = max(2, round(math.sqrt(p.n_views * 4 / 3)))
    rows = math.ceil(p.n_views / cols)
    xs = np.linspace(-0.5, 0.5, cols) * p.baseline
    ys = np.linspace(-0.5, 0.5, rows) * p.baseline * 0.75 if rows > 1 else np.zeros(1)
    focal = p.focal_factor * p.width
    target = np.array([0.0, 0.0, p.wall_depth * 0.66])
    cams = []
    for i in range(p.n_views):
        r, c = divmod(i, cols)
        c = c if r % 2 == 0 else cols - 1 - c
        jitter = rng.normal(0.0, 0.04 * p.baseline, size=3)
        eye = np.array([xs[c], ys[r], 0.0]) + jitter
        view = look_at(eye, target, up=np.array([0.0, 1.0, 0.0]))  # world y is down: camera y = world +y
        width = p.width - (p.odd_view_width_delta if i % 2 else 0)
        cams.append(Camera(f"{i:03d}.png", intrinsics(focal, width, p.height), view, width, p.height))
    return cams


# ----------------------------------------------------------------------------------------------
# Scene assembly and writing
# ----------------------------------------------------------------------------------------------


def _textures(rng: np.random.Generator, p: TinySceneParams) -> dict[int, np.ndarray]:
    """One texture per label; texel density is a few texels per pixel at the surfaces' depths."""
    density = p.focal_factor * p.width / p.wall_depth * 2.0  # texels per scene unit on the wall
    wh = int(2 * p.wall_depth * 0.9 * density)
    ww = int(2 * p.wall_depth * 1.2 * density)
    return {
        1: make_texture(rng, wh, ww, base=(0.55, 0.5, 0.45), n_shapes=int(ww * wh / 200)),
        2: make_texture(rng, 256, 384, base=(0.45, 0.55, 0.4), n_shapes=600),
        3: make_texture(rng, 256, 512, base=(0.6, 0.4, 0.35), n_shapes=800),
    }


def render_view(cam: Camera, layout: _Layout, textures: dict[int, np.ndarray], supersample: int) -> tuple[np.ndarray, np.ndarray]:
    """RGB ``(H, W, 3) float32`` averaged over ``supersample²`` rays per pixel, and labels ``(H, W) int64``
    of the ray through each pixel centre."""
    s = supersample
    rgb, labels = _cast(cam, layout, textures)
    if s > 1:
        hi, _ = _cast(cam.scaled(s), layout, textures)
        rgb = hi.reshape(cam.height, s, cam.width, s, 3).mean(axis=(1, 3))
    return rgb.astype(np.float32), labels


def generate_tiny_scene(p: TinySceneParams | None = None) -> TinyScene:
    """Generate the whole scene in memory (deterministic in ``p``; a few seconds on one core)."""
    p = p or TinySceneParams()
    rng = np.random.default_rng(p.seed)
    layout, textures = scene_layout(p), _textures(rng, p)
    cams = {"orbit": ring_cameras, "object": dome_cameras}.get(p.layout, grid_cameras)(p, rng)
    images, labels = [], []
    for cam in cams:
        rgb, lab = render_view(cam, layout, textures, p.supersample)
        images.append(rgb)
        labels.append(lab)
    styles, style_labels = make_paintings(rng, p.style_height)
    return TinyScene(images, labels, cams, styles, style_labels)


def render_rgba(cam: Camera, layout: _Layout, textures: dict[int, np.ndarray], supersample: int) -> np.ndarray:
    """Straight-alpha RGBA ``(H, W, 4) float32`` of the object layout: alpha is the share of the ``supersample²`` rays
    per pixel that hit an object, the colour their mean."""
    s = max(1, supersample)
    rgb, labels = _cast(cam.scaled(s) if s > 1 else cam, layout, textures)
    hit = (labels > 0).astype(np.float32)[..., None]
    alpha = hit.reshape(cam.height, s, cam.width, s, 1).mean(axis=(1, 3))
    premult = (rgb * hit).reshape(cam.height, s, cam.width, s, 3).mean(axis=(1, 3))
    color = np.where(alpha > 0, premult / np.maximum(alpha, 1e-6), 0.0)
    return np.concatenate([color, alpha], axis=-1).astype(np.float32)


OPENGL_AXES = np.diag([1.0, -1.0, -1.0, 1.0])
"""OpenCV camera axes → OpenGL/Blender ones (y up, z backwards)."""


def write_object_dataset(out_dir: str | os.PathLike, params: TinySceneParams | None = None) -> Path:
    """The object layout (``params.layout`` is set to ``object``) as a NeRF-synthetic dataset, atomically:
    ``train/NNN.png`` straight-alpha RGBA views, ``transforms_train.json`` (``camera_angle_x``, OpenGL
    camera-to-world matrices) and the paintings in ``styles/``. The object is the tiny scene's box and sphere on
    nothing, seen from three rings of views around and above it."""
    p = (params or TinySceneParams()).model_copy(update={"layout": "object"})
    rng = np.random.default_rng(p.seed)
    layout, textures = scene_layout(p), _textures(rng, p)
    cams = dome_cameras(p, rng)
    styles, style_labels = make_paintings(rng, p.style_height)
    with atomic_path(out_dir, is_dir=True) as tmp:
        frames = []
        for cam in cams:
            stem = Path(cam.name).stem
            save_image(tmp / "train" / f"{stem}.png", render_rgba(cam, layout, textures, p.supersample))
            frames.append({"file_path": f"./train/{stem}", "rotation": 0.0,
                           "transform_matrix": (np.linalg.inv(cam.viewmat) @ OPENGL_AXES).tolist()})
        angle = 2 * math.atan(p.width / (2 * p.focal_factor * p.width))
        write_json(tmp / "transforms_train.json", {"camera_angle_x": angle, "frames": frames})
        for name, img in styles.items():
            save_image(tmp / "styles" / f"{name}.png", img)
        save_labels(tmp / "styles" / "paint_labels.png", style_labels)
    return Path(out_dir)


def cameras_to_json(cams: list[Camera]) -> dict:
    """``{"views": [{"name", "K", "viewmat", "width", "height"}, ...]}`` (row-major nested lists)."""
    return {
        "convention": "viewmat: world->camera, OpenCV axes (x right, y down, z forward); K pixel centres at +0.5",
        "views": [
            {"name": c.name, "K": c.K.tolist(), "viewmat": c.viewmat.tolist(), "width": c.width, "height": c.height} for c in cams
        ],
    }


def cameras_from_json(data: dict) -> list[Camera]:
    """Inverse of :func:`cameras_to_json`."""
    return [
        Camera(v["name"], np.asarray(v["K"], float), np.asarray(v["viewmat"], float), int(v["width"]), int(v["height"]))
        for v in data["views"]
    ]


def write_tiny_scene(scene: TinyScene, out_dir: str | os.PathLike, params: TinySceneParams) -> None:
    """Write ``scene`` into ``out_dir`` (the layout in the module docstring). Not atomic by itself."""
    out = Path(out_dir)
    for i, (cam, rgb, lab) in enumerate(zip(scene.cameras, scene.images, scene.labels)):
        stem = Path(cam.name).stem
        save_image(out / "images" / f"{stem}.png", rgb)
        if params.mask_views == 0 or i < params.mask_views:
            save_labels(out / "masks" / f"{stem}.png", lab)
    for name, img in scene.styles.items():
        save_image(out / "styles" / f"{name}.png", img)
    save_labels(out / "styles" / "paint_labels.png", scene.style_labels)
    data = cameras_to_json(scene.cameras)
    data["labels"] = {str(k): v for k, v in LABEL_NAMES.items()}
    data["params"] = params.model_dump()
    write_json(out / "cameras.json", data)


def make_tiny_scene(out_dir: str | os.PathLike, params: TinySceneParams | None = None) -> Path:
    """Generate the scene and write it to ``out_dir`` atomically (the folder appears complete or not at all)."""
    params = params or TinySceneParams()
    scene = generate_tiny_scene(params)
    with atomic_path(out_dir, is_dir=True) as tmp:
        write_tiny_scene(scene, tmp, params)
    return Path(out_dir)
