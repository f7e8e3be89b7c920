"""The fuzzing targets of the files just outside the scene readers (:mod:`eval.bench.fuzz`): images by their header,
gsplat checkpoints, INRIA ``cameras.json``, splatfacto ``dataparser_transforms.json``, ``params.yaml``, a stylized
scene's ``fitted_rows.npy``, and special
files (a FIFO, ``/dev/zero``, a symlink loop, a folder) named as a scene's files. Each maker writes a small valid
input under ``folder`` and returns ``(files, read)``: the files a mutation may change and the reader that reads
them as the pipeline does; the mutations of their own kind are here too (:data:`OWN_MUTATIONS`)."""

from __future__ import annotations

import io
import json
import os
import struct
import zlib
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch
import yaml

from abcgs.errors import ParamsError

PARAMS = {"data": {"scenes": {"s": {"path": "scene"}}, "styles": {"p": "p.png"}},
          "fit": {"iterations": 300, "sh_degree": 1},
          "colormatches": {"c": {"scene": "s", "transfer": "single", "style": "p"}},
          "experiments": {"e": {"scene": "s", "colormatch": "c"}}}
"""A small params file that validates (its files are not read: the schema is the target)."""


def png_bytes(width: int, height: int, rows: Callable[[int], bytes] | None = None) -> bytes:
    """A one-bit grey PNG of ``width × height`` pixels, all black unless ``rows(y)`` gives a row's packed bits; built
    in a stream (a 60 000 × 60 000 one takes 436 KB and a few seconds, never its 450 MB of rows at once)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    stride = (width + 7) // 8
    comp = zlib.compressobj(9)
    parts, black, batch = [], b"\0" * (stride + 1), max(1, (8 << 20) // (stride + 1))
    for y0 in range(0, height, batch):
        n = min(batch, height - y0)
        block = black * n if rows is None else b"".join(b"\0" + rows(y) for y in range(y0, y0 + n))
        parts.append(comp.compress(block))
    parts.append(comp.flush())
    ihdr = struct.pack(">IIBBBBB", width, height, 1, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", b"".join(parts)) + chunk(b"IEND", b"")


def png_with_size(data: bytes, width: int, height: int) -> bytes:
    """A PNG's bytes with the size in its header replaced (its CRC made right): what a hostile header claims."""
    ihdr = bytearray(data[12:29])
    ihdr[4:12] = struct.pack(">II", width, height)
    return data[:12] + bytes(ihdr) + struct.pack(">I", zlib.crc32(bytes(ihdr)) & 0xFFFFFFFF) + data[33:]


def make_image(folder: Path) -> tuple[list[Path], Callable[[], object]]:
    """A 32 × 24 photo; read by :func:`abcgs.io.images.load_image` (its header checked first)."""
    from abcgs.io.images import load_image, save_image

    p = folder / "view.png"
    folder.mkdir(parents=True, exist_ok=True)
    save_image(p, np.random.default_rng(0).random((24, 32, 3)).astype(np.float32))
    return [p], lambda: load_image(p)


def make_gsplat_ckpt(folder: Path, model, cameras, points) -> tuple[list[Path], Callable[[], object]]:
    """A gsplat checkpoint of ``model``; read by :func:`abcgs.splats.registry.read_splat` into a scene of ``cameras``
    and ``points`` (gsplat's frame is computed from them)."""
    from abcgs.splats.formats.gsplat_ckpt import write_gsplat_ckpt
    from abcgs.splats.registry import read_splat

    p = folder / "ckpt_299_rank0.pt"
    folder.mkdir(parents=True, exist_ok=True)
    write_gsplat_ckpt(p, model, step=299)
    scene = SimpleNamespace(cameras=cameras, points=points)
    return [p], lambda: read_splat(p, "gsplat_ckpt", scene=scene)


def make_inria_cameras(folder: Path, cameras) -> tuple[list[Path], Callable[[], object]]:
    """An INRIA ``cameras.json`` of ``cameras`` (centres and camera-to-world rotations); read and aligned to them
    (:func:`abcgs.splats.formats.inria.frame_from_cameras`)."""
    from abcgs.io.guarded import read_text
    from abcgs.splats.formats.inria import MAX_SIDE_FILE_BYTES, frame_from_cameras, inria_camera_centres

    views = []
    for i, c in enumerate(cameras):
        c2w = np.linalg.inv(c.viewmat)
        views.append({"id": i, "img_name": Path(c.name).stem, "width": c.width, "height": c.height,
                      "position": c2w[:3, 3].tolist(), "rotation": c2w[:3, :3].tolist(), "fx": c.K[0, 0],
                      "fy": c.K[1, 1]})
    p = folder / "cameras.json"
    folder.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(views))

    def read():
        text = read_text(p, "INRIA cameras.json", MAX_SIDE_FILE_BYTES)  # as read_inria_folder reads it
        return frame_from_cameras(inria_camera_centres(text, source=str(p)), cameras, source=str(p))
    return [p], read


def make_splatfacto_transforms(folder: Path) -> tuple[list[Path], Callable[[], object]]:
    """A splatfacto ``dataparser_transforms.json``; read by :func:`abcgs.splats.frames.nerfstudio_similarity`."""
    from abcgs.splats.frames import nerfstudio_similarity

    p = folder / "dataparser_transforms.json"
    folder.mkdir(parents=True, exist_ok=True)
    t = np.eye(4)[:3].copy()
    t[:, 3] = [0.1, -0.2, 0.3]
    p.write_text(json.dumps({"transform": t.tolist(), "scale": 0.25}, indent=4))
    return [p], lambda: nerfstudio_similarity(p)


def make_params(folder: Path) -> tuple[list[Path], Callable[[], object]]:
    """A ``params.yaml`` (:data:`PARAMS`); read by :func:`abcgs.sections.read_params_file` (which must refuse in one
    line) and validated by the schema, whose listing of problems (several lines by design) counts as a refusal by its
    first line."""
    from abcgs.params import validate_params
    from abcgs.sections import read_params_file

    p = folder / "params.yaml"
    folder.mkdir(parents=True, exist_ok=True)
    p.write_text(yaml.safe_dump(PARAMS, sort_keys=False))

    def read():
        raw = read_params_file(p)
        try:
            return validate_params(raw, str(p))
        except ParamsError as exc:
            lines = str(exc).splitlines()
            raise ParamsError(" ".join(line.strip() for line in lines[:2])) from None
    return [p], read


def make_fitted_rows(folder: Path, n: int = 200, n_fitted: int = 150) -> tuple[list[Path], Callable[[], object]]:
    """A stylized scene's ``fitted_rows.npy`` (:data:`abcgs.gaussians.FITTED_ROW`): ``n`` Gaussians, each on a row of
    a fitted scene of ``n_fitted`` (a densified re-fit's clones repeat rows), read as stylize and the viewer read it
    (:func:`abcgs.gaussians.read_fitted_rows`)."""
    from abcgs.gaussians import read_fitted_rows

    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "fitted_rows.npy"
    rows = np.concatenate([np.arange(n_fitted), np.random.default_rng(0).integers(0, n_fitted, n - n_fitted)])
    np.save(path, rows.astype(np.int64), allow_pickle=False)
    return [path], lambda: read_fitted_rows(path, n, n_fitted)


def make_scene_record(folder: Path, cameras) -> tuple[list[Path], Callable[[], object]]:
    """A reconstructed scene's ``scene.json`` (:func:`abcgs.sfm.model.write_scene`: the views' images, a label map, a
    frame and a depth range), read by :func:`abcgs.sfm.model.read_scene` as every stage after ``reconstruct`` reads
    it."""
    from abcgs.cameras import Cameras
    from abcgs.io.images import save_image, save_labels
    from abcgs.sfm.model import read_scene, write_scene
    from abcgs.types import CalibratedScene

    rng = np.random.default_rng(0)
    images = []
    for cam in cameras:
        images.append(folder / "images" / cam.name)
        save_image(images[-1], rng.random((cam.height, cam.width, 3)).astype(np.float32))
    first = cameras[0]
    save_labels(folder / "masks" / first.name, rng.integers(0, 3, (first.height, first.width)))
    frame = np.eye(4)
    frame[:3, :3] *= 0.5
    scene = CalibratedScene(Cameras.from_list(list(cameras)), tuple(images), rng.normal(size=(20, 3)).astype(np.float32),
                            rng.random((20, 3)).astype(np.float32),
                            label_paths=(folder / "masks" / first.name, *([None] * (len(cameras) - 1))),
                            frame=frame, depth_range=(0.5, 10.0))
    return [write_scene(scene, folder)], lambda: read_scene(folder)


def make_special(folder: Path, cameras, transforms: Callable[[Path, list], Path],
                 images: Callable[[Path, list], None]) -> tuple[list[Path], Callable[[], object]]:
    """A nerfstudio scene whose ``transforms.json`` or a view a mutation replaces by a special file
    (:func:`special`); read by :func:`abcgs.sources.read.read_source` and each view by
    :func:`abcgs.io.images.load_image`."""
    from abcgs.io.images import load_image
    from abcgs.sources.read import read_source

    images(folder / "images", cameras)
    p = transforms(folder, cameras)

    def read():
        scene = read_source(folder, "nerfstudio")
        return [load_image(v) for v in scene.image_paths]
    return [p, *sorted((folder / "images").iterdir())], read


def clear(p: Path) -> None:
    """Remove whatever ``p`` is (a file, a link, a FIFO, a folder), so that its original can be written back."""
    if p.is_symlink() or (p.exists() and not p.is_dir()):
        p.unlink()
    elif p.is_dir():
        p.rmdir()


# ------------------------------------------------------------------------------------------ own mutations


def _png_size(data: bytes, rng: np.random.Generator) -> bytes:
    """The PNG's header claims another size: 10⁹ × 10⁹, 0, one huge side, or just past PIL's limit."""
    w, h = [(10**9, 10**9), (0, 24), (1 << 31, 1), (60_000, 60_000), (9_460, 9_460), (1, 2**31 - 1)][
        int(rng.integers(6))]
    return png_with_size(data, w, h) if data.startswith(b"\x89PNG") and len(data) > 33 else data


def _ckpt_edit(data: bytes, rng: np.random.Generator) -> bytes:
    """A field of the checkpoint replaced: a 0-d tensor, a list, a complex tensor, no rows, a string or infinite step."""
    ckpt = torch.load(io.BytesIO(data), weights_only=True)
    splats = ckpt["splats"]
    key = ["means", "quats", "scales", "opacities", "sh0", "shN"][int(rng.integers(6))]
    op = int(rng.integers(7))
    if op == 0:
        splats[key] = torch.tensor(1.0)
    elif op == 1:
        splats[key] = splats[key].tolist()
    elif op == 2:
        splats[key] = splats[key].to(torch.complex64)
    elif op == 3:
        splats = {k: v[:0] for k, v in splats.items()}
    elif op == 4:
        ckpt["step"] = ["x", float("inf"), float("nan"), -5, 10**30][int(rng.integers(5))]
    elif op == 5:
        splats[key] = splats[key][: int(rng.integers(1, len(splats[key])))]
    else:
        splats[key] = splats[key].to(torch.int64 if rng.random() < 0.5 else torch.bool)
    ckpt["splats"] = splats
    buf = io.BytesIO()
    torch.save(ckpt, buf)
    return buf.getvalue()


def _alias_bomb(data: bytes, rng: np.random.Generator) -> bytes:
    """A value of the YAML replaced by a billion-laughs alias (10 levels of 10), under a typed key or a new one."""
    lines = data.decode("utf-8", "replace").split("\n")
    anchors = "".join(f"x{i}: &x{i} [{', '.join([f'*x{i - 1}' if i else '1'] * 10)}]\n" for i in range(10))
    keyed = [i for i, line in enumerate(lines) if line.rstrip().endswith(":") is False and ": " in line]
    if keyed and rng.random() < 0.7:
        i = keyed[int(rng.integers(len(keyed)))]
        lines[i] = lines[i].split(": ", 1)[0] + ": *x9"
    else:
        lines.append("bomb: *x9")
    return (anchors + "\n".join(lines)).encode()


def _yaml_value(data: bytes, rng: np.random.Generator) -> bytes:
    """A scalar of the YAML replaced by a 5000-digit integer, ``.nan``, ``.inf``, a nested flow list or a tag."""
    lines = data.decode("utf-8", "replace").split("\n")
    keyed = [i for i, line in enumerate(lines) if ": " in line]
    value = ["5" * 5000, ".nan", "-.inf", "[" * 50_000 + "]" * 50_000, "!!python/object:os.system x", "*nowhere",
             "&a [*a]", "{a: 1, a: 2}", "0x" + "f" * 200][int(rng.integers(9))]
    if keyed:
        i = keyed[int(rng.integers(len(keyed)))]
        lines[i] = lines[i].split(": ", 1)[0] + ": " + value
    return "\n".join(lines).encode()


def special(path: Path, rng: np.random.Generator) -> str:
    """``path`` replaced by a special file: a FIFO, a link to ``/dev/zero``, a symlink loop, a folder, a dangling
    link or an empty file. Returns the kind."""
    kind = ["fifo", "dev_zero", "loop", "folder", "dangling", "empty"][int(rng.integers(6))]
    clear(path)
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "dev_zero":
        path.symlink_to("/dev/zero")
    elif kind == "loop":
        path.symlink_to(path.name)
    elif kind == "folder":
        path.mkdir()
    elif kind == "dangling":
        path.symlink_to(path.parent / "nowhere")
    else:
        path.write_bytes(b"")
    return kind


OWN_MUTATIONS = {"png": (_png_size,), "ckpt": (_ckpt_edit,), "yaml": (_alias_bomb, _yaml_value)}
"""Per kind of input, the mutations of its own that :mod:`eval.bench.fuzz` adds to the generic ones."""
REFUSALS: dict[str, type[Exception]] = {"params": ParamsError}
"""The refusal of a format whose reader raises something else than :class:`~abcgs.errors.InputError`."""
