"""Files from strangers just outside the scene readers: image bombs and special files named as views, YAML alias bombs
and deep or huge values in params.yaml, label maps of huge labels, gsplat checkpoints and INRIA / splatfacto camera
files of the wrong values, and malformed requests to the masks page. Each is refused in one line naming the file,
without a traceback, by the first command a user would run on it; the ones that used to take gigabytes or hang run
that command in a process of its own, bounded in time and measured for memory (docs/INPUTS.md lists the checks)."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import yaml
from conftest import REPO_ROOT

from abcgs.errors import InputError, ParamsError
from abcgs.gaussians.ply import write_ply
from abcgs.io.images import MAX_IMAGE_PIXELS, load_labels, save_image, save_labels
from abcgs.sections import read_params_file
from abcgs.sources.read import read_source
from abcgs.splats.formats.gsplat_ckpt import write_gsplat_ckpt
from abcgs.splats.formats.inria import frame_from_cameras, inria_camera_centres
from abcgs.splats.frames import nerfstudio_similarity
from abcgs.splats.registry import read_splat
from eval.bench.fuzz import make_targets, sample_cameras, sample_model, sample_points
from eval.bench.fuzz_inputs import PARAMS, png_bytes, png_with_size

SECONDS, GIB = 20.0, 1.5
"""Every refusal here comes within these bounds (the command's imports included)."""
MEASURE = ("import resource, subprocess, sys; resource.setrlimit(resource.RLIMIT_AS, (6 << 30, 6 << 30)); "
           "r = subprocess.run([sys.executable, *sys.argv[1:]], stdin=subprocess.DEVNULL, timeout=60); "
           "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); sys.exit(r.returncode)")
"""Runs a command in a child and prints the child's peak memory (KiB) last on stderr; an address-space cap keeps a
regression from taking the machine (an intermediate process: RUSAGE_CHILDREN of the test would include every
child the session ran before)."""


def refused_by_command(*argv: str, cwd: Path = REPO_ROOT) -> str:
    """``python argv…`` in a process of its own: it must exit 2 with one line on stderr (no traceback) within
    :data:`SECONDS` and :data:`GIB`; returns that line."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", MEASURE, *argv], capture_output=True, text=True, timeout=120,
                          cwd=cwd)
    seconds = time.perf_counter() - t0
    *lines, peak_kib = proc.stderr.splitlines()
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert seconds < SECONDS and int(peak_kib) / 2**20 < GIB, (seconds, int(peak_kib) / 2**20, lines)
    return lines[0]


def one_line(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert "\n" not in text, text
    return text


def _photos(folder: Path, n: int = 3) -> Path:
    rng = np.random.default_rng(0)
    for k in range(n):
        save_image(folder / "images" / f"{k:03d}.png", rng.random((24, 32, 3)).astype(np.float32))
    return folder


def _params(tmp_path: Path, scene: Path | None = None, text: str | None = None) -> Path:
    p = tmp_path / "params.yaml"
    p.write_text(text if text is not None else yaml.safe_dump(
        {"data": {"scenes": {"evil": {"path": str(scene)}}}}))
    return p


# ------------------------------------------------------------------------------------------ params.yaml

BOMB = "".join(f"l{i}: &l{i} [{', '.join([f'*l{i - 1}' if i else '1'] * 10)}]\n" for i in range(10))
"""Ten levels of ten aliases: 10^10 nodes in 400 bytes."""


@pytest.mark.parametrize("where", ["fit.iterations", "data.scenes.s.path"])
def test_an_alias_bomb_under_a_typed_key_is_refused_by_preflight_and_add_scene(tmp_path: Path, where: str) -> None:
    doc = yaml.safe_dump(PARAMS, sort_keys=False)
    key = where.rsplit(".", 1)[1]
    line = next(ln for ln in doc.splitlines() if ln.strip().startswith(f"{key}:"))
    p = _params(tmp_path, text=BOMB + doc.replace(line, line.split(":")[0] + ": *l9"))
    err = refused_by_command("-m", "abcgs.preflight", str(p))
    assert "aliases expand to more than" in err and str(p) in err, err
    _photos(tmp_path / "s")
    err = refused_by_command("-m", "abcgs", "add-scene", "s2", str(tmp_path / "s"), "--params", str(p), "--dry-run")
    assert "aliases expand to more than" in err, err


@pytest.mark.parametrize("text, message", [
    ("fit: " + "[" * 50_000 + "]" * 50_000 + "\n", "nests deeper than 64 levels"),
    ("fit:\n  iterations: " + "5" * 5000 + "\n", "5000 characters, more than 100"),
    ("fit: &a [*a]\n", "contains itself through an alias"),
    ("fit: {iterations: 3\n", "is not valid YAML: .* at line 2"),
])
def test_params_beyond_the_readers_bounds_are_one_line(tmp_path: Path, text: str, message: str) -> None:
    p = _params(tmp_path, text=text)
    with pytest.raises(ParamsError, match=message) as exc:
        read_params_file(p)
    one_line(exc)


def test_deep_params_are_refused_by_preflight_in_one_line(tmp_path: Path) -> None:
    p = _params(tmp_path, text="fit: " + "[" * 50_000 + "]" * 50_000 + "\n")
    assert "nests deeper than" in refused_by_command("-m", "abcgs.preflight", str(p))


# ------------------------------------------------------------------------------------------ images


def test_a_60000_pixel_square_png_among_the_photos_is_refused_by_add_scene_and_preflight(tmp_path: Path) -> None:
    scene = _photos(tmp_path / "scene")
    bomb = png_bytes(60_000, 60_000)
    assert len(bomb) < 600_000  # 436 KB that a decoder would turn into 3.6 G pixels
    (scene / "images" / "016.png").write_bytes(bomb)
    err = refused_by_command("-m", "abcgs", "add-scene", "new", str(scene), "--params",
                             str(_params(tmp_path, scene)), "--dry-run")
    assert "016.png" in err and str(MAX_IMAGE_PIXELS) in err, err
    err = refused_by_command("-m", "abcgs.preflight", str(_params(tmp_path, scene)))
    assert "016.png" in err and str(MAX_IMAGE_PIXELS) in err, err


def test_add_style_refuses_a_gigapixel_painting_before_decoding_it(tmp_path: Path) -> None:
    (tmp_path / "big.png").write_bytes(png_bytes(32_000, 32_000))  # 1.02 G pixels
    err = refused_by_command("-m", "abcgs", "add-style", "big", str(tmp_path / "big.png"), "--params",
                             str(_params(tmp_path, text=yaml.safe_dump(PARAMS))), "--dry-run")
    assert f"big.png is larger than the {MAX_IMAGE_PIXELS} pixels abcgs reads" in err, err


def test_a_fifo_named_as_a_view_is_refused_without_opening_it(tmp_path: Path) -> None:
    scene = _photos(tmp_path / "scene")
    os.mkfifo(scene / "images" / "016.png")
    for argv in (("-m", "abcgs", "add-scene", "new", str(scene), "--params", str(_params(tmp_path, scene)),
                  "--dry-run"), ("-m", "abcgs.preflight", str(_params(tmp_path, scene)))):
        err = refused_by_command(*argv)
        assert "016.png is a FIFO (named pipe), not a regular file" in err, err


@pytest.mark.parametrize("kind, message", [
    ("header", "is 1000000000×1000000000 pixels by its header|larger than the"),
    ("text", "is not a readable image"),
    ("loop", "is a symlink loop"),
    ("dev_zero", "is a character device, not a regular file"),
])
def test_a_hostile_view_in_a_photos_scene_is_one_line(tmp_path: Path, capsys, kind: str, message: str) -> None:
    from abcgs.preflight import main

    scene = _photos(tmp_path / "scene")
    view = scene / "images" / "016.png"
    if kind == "header":
        view.write_bytes(png_with_size((scene / "images" / "000.png").read_bytes(), 10**9, 10**9))
    elif kind == "text":
        view.write_text("not a picture\n")
    elif kind == "loop":
        view.symlink_to(view.name)
    else:
        view.symlink_to("/dev/zero")
    assert main([str(_params(tmp_path, scene))]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "016.png" in err, err
    assert any(m in err for m in message.split("|")), err


@pytest.mark.parametrize("fmt", ["transforms", "colmap_bin"])
def test_a_gigapixel_header_as_a_view_of_a_dataset_is_refused(tmp_path: Path, fmt: str) -> None:
    t = make_targets(tmp_path / "d", (fmt,))[fmt]
    folder = t.files[0].parent if fmt == "transforms" else t.files[0].parents[2]
    view = folder / "images" / "view01.png"
    view.write_bytes(png_with_size(view.read_bytes(), 10**9, 10**9))
    with pytest.raises(InputError, match=r"view01\.png is larger than the \d+ pixels") as exc:
        read_source(folder, "nerfstudio" if fmt == "transforms" else "colmap")
    one_line(exc)


def test_a_gigapixel_header_as_a_mask_is_refused(tmp_path: Path, capsys) -> None:
    from abcgs.preflight import main

    scene = _photos(tmp_path / "scene")
    (scene / "masks").mkdir()
    save_labels(scene / "masks" / "000.png", np.ones((24, 32), np.int64))
    (scene / "masks" / "001.png").write_bytes(png_with_size((scene / "masks" / "000.png").read_bytes(), 10**9, 10**9))
    assert main([str(_params(tmp_path, scene))]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "001.png" in err and "larger than the" in err, err


# ------------------------------------------------------------------------------------------ labels


def test_a_label_map_of_label_60000_is_refused_before_the_masks_stage(tmp_path: Path) -> None:
    scene = _photos(tmp_path / "scene")
    labels = np.zeros((24, 32), np.int64)
    labels[4:10, 4:10], labels[12:20, 12:30] = 1, 60_000
    (scene / "masks").mkdir()
    save_labels(scene / "masks" / "000.png", labels)
    with pytest.raises(InputError, match="holds the label 60000, more than the 254 labels") as exc:
        load_labels(scene / "masks" / "000.png")  # what the masks stage reads them with
    one_line(exc)
    params = {"data": {"scenes": {"evil": {"path": str(scene)}}, "styles": {"p": str(tmp_path / "p.png")}},
              "colormatches": {"c": {"scene": "evil", "transfer": "compositional", "styles": {60000: "p"}}}}
    save_image(tmp_path / "p.png", np.random.default_rng(1).random((64, 64, 3)).astype(np.float32))
    p = _params(tmp_path, text=yaml.safe_dump(params))
    for argv in (("-m", "abcgs.preflight", str(p)),
                 ("-m", "abcgs", "add-scene", "evil2", str(scene), "--params", str(p), "--dry-run")):
        err = refused_by_command(*argv)
        assert "000.png holds the label 60000" in err, err


# ------------------------------------------------------------------------------------------ special files


def test_transforms_json_linked_to_dev_zero_is_refused_by_add_scene(tmp_path: Path) -> None:
    t = make_targets(tmp_path / "d", ("transforms",))["transforms"]
    t.files[0].unlink()
    t.files[0].symlink_to("/dev/zero")
    err = refused_by_command("-m", "abcgs", "add-scene", "z", str(t.files[0].parent), "--params",
                             str(_params(tmp_path, text=yaml.safe_dump(PARAMS))), "--dry-run")
    assert "transforms.json is a character device, not a regular file" in err, err



@pytest.mark.parametrize("role", ["scene", "splat", "painting"])
def test_a_symlink_loop_given_as_a_path_is_one_line(tmp_path: Path, role: str) -> None:
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    params = str(_params(tmp_path, text=yaml.safe_dump(PARAMS)))
    argv = {"scene": ("add-scene", "loop", str(tmp_path / "a")),
            "splat": ("add-scene", "loop", str(_photos(tmp_path / "photos")), "--splat", str(tmp_path / "a")),
            "painting": ("add-style", "looped", str(tmp_path / "a"))}[role]
    err = refused_by_command("-m", "abcgs", *argv, "--params", params, "--dry-run")
    assert "cannot be resolved" in err and "symlink loop" in err, err

# ------------------------------------------------------------------------------------------ splats


def _ckpt(tmp_path: Path, edit) -> Path:
    p = tmp_path / "ckpt_9_rank0.pt"
    write_gsplat_ckpt(p, sample_model(16), step=9)
    ckpt = torch.load(p, weights_only=True)
    edit(ckpt)
    torch.save(ckpt, p)
    return p


@pytest.mark.parametrize("edit, message", [
    (lambda c: c["splats"].update(means=torch.tensor(1.0)), r"splats\['means'\] is a 0-d"),
    (lambda c: c["splats"].update(means=c["splats"]["means"].tolist()), r"splats\['means'\] is a list, not a tensor"),
    (lambda c: c["splats"].update(quats=c["splats"]["quats"].to(torch.complex64)), r"complex64 tensor; gsplat saves real"),
    (lambda c: c.update(step="x"), "step is 'x', not an iteration count"),
    (lambda c: c.update(step=float("inf")), "step is 'inf', not an iteration count"),
    (lambda c: c.update(splats={k: v[:0] for k, v in c["splats"].items()}), "holds 0 Gaussians"),
    (lambda c: c["splats"].update(scales=c["splats"]["scales"][:5]), r"has shape \(5, 3\), expected \(16, 3\)"),
])
def test_gsplat_checkpoint_values_are_checked(tmp_path: Path, edit, message: str) -> None:
    scene = SimpleNamespace(cameras=sample_cameras(), points=sample_points())
    with pytest.raises(InputError, match=message) as exc:
        read_splat(_ckpt(tmp_path, edit), "gsplat_ckpt", scene=scene)
    one_line(exc)


def test_a_ply_of_0_gaussians_is_refused(tmp_path: Path) -> None:
    write_ply(tmp_path / "empty.ply", sample_model(16).index(torch.zeros(16, dtype=torch.bool)))
    with pytest.raises(InputError, match="empty.ply holds 0 Gaussians") as exc:
        read_splat(tmp_path / "empty.ply")
    one_line(exc)


def _inria(cams, edit=None) -> str:
    views = [{"img_name": Path(c.name).stem, "position": np.linalg.inv(c.viewmat)[:3, 3].tolist()} for c in cams]
    if edit:
        edit(views)
    return json.dumps(views)


@pytest.mark.parametrize("text, message", [
    (lambda cams: _inria(cams, lambda v: v[1].update(position=[float("nan"), 0, 0])), "view 1 .* has the position"),
    (lambda cams: _inria(cams, lambda v: v[1].update(position=[1e308, 0, 0])), r"three finite numbers within ±1e\+09"),
    (lambda cams: _inria(cams, lambda v: v[2].update(position=[1, 2])), "view 2 .* has the position"),
    (lambda cams: "[" * 200_000 + "]" * 200_000, "nested too deeply"),
    (lambda cams: _inria(cams, lambda v: [x.update(position=[1, 1, 1]) for x in v]), "cameras.json: its camera "
     "centres do not fix a similarity .* all identical"),
])
def test_inria_cameras_json_values_are_checked(text, message: str) -> None:
    cams = sample_cameras()
    with pytest.raises(InputError, match=message) as exc:
        frame_from_cameras(inria_camera_centres(text(cams), source="out/cameras.json"), cams,
                           source="out/cameras.json")
    one_line(exc)


def test_a_deep_dataparser_transforms_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "dataparser_transforms.json"
    p.write_text("[" * 200_000 + "]" * 200_000)
    with pytest.raises(InputError, match="nested too deeply") as exc:
        nerfstudio_similarity(p)
    one_line(exc)


def test_a_tiny_applied_scale_is_refused(tmp_path: Path) -> None:
    t = make_targets(tmp_path / "d", ("transforms",))["transforms"]
    folder = t.files[0].parent
    meta = json.loads(t.files[0].read_text())
    meta["applied_scale"] = 1e-300
    t.files[0].write_text(json.dumps(meta))
    with pytest.raises(InputError, match="applied_scale is 1e-300; a scale between 1e-12 and 1e12") as exc:
        read_source(folder, "nerfstudio")
    one_line(exc)


# ------------------------------------------------------------------------------------------ the masks page


@pytest.fixture
def page(tmp_path: Path):
    from abcgs.masks.page.server import make_server
    from abcgs.masks.page.session import PaintSession

    scene = _photos(tmp_path / "scene", 1)
    server = make_server(PaintSession.for_scene(scene), timeout=1.0)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield server
    server.shutdown()
    server.server_close()


def _raw(server, head: bytes, body: bytes, wait: float = 10.0) -> tuple[int, dict, float]:
    port = server.server_port
    t0 = time.perf_counter()
    with socket.create_connection(("127.0.0.1", port), timeout=wait) as s:
        s.sendall(head + body)
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    status = int(data.split(b" ", 2)[1])
    return status, json.loads(data.split(b"\r\n\r\n", 1)[1] or b"{}"), time.perf_counter() - t0


def _post(server, lengths: list[str]) -> bytes:
    port = server.server_port
    lines = [b"POST /api/strokes/0 HTTP/1.1", f"Host: 127.0.0.1:{port}".encode(),
             f"Cookie: abcgs_paint_{port}={server.token}".encode(), b"Content-Type: application/json",
             b"Connection: close", *[f"Content-Length: {n}".encode() for n in lengths]]
    return b"\r\n".join(lines) + b"\r\n\r\n"


@pytest.mark.parametrize("where", ["headers", "body"])
def test_a_client_that_drips_bytes_is_cut_off_at_the_deadline_while_another_is_served(tmp_path: Path, where) -> None:
    """One byte every 0.3 s meets every read's timeout (1 s) but not the request's deadline (2 s here; 60 s by
    default, abcgs.masks.page.requests.REQUEST_DEADLINE_S): the connection is closed by then, and a second client is
    answered while the first drips."""
    from abcgs.masks.page.server import make_server
    from abcgs.masks.page.session import PaintSession

    server = make_server(PaintSession.for_scene(_photos(tmp_path / "scene", 1)), timeout=1.0, deadline=2.0)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        body = b'{"strokes": []}'
        head = _post(server, [str(len(body) + 1000)])
        first, drip = (b"", head + body) if where == "headers" else (head, body + b" " * 1000)
        t0 = time.perf_counter()
        with socket.create_connection(("127.0.0.1", server.server_port), timeout=10) as s:
            s.sendall(first)
            other = None
            closed_at = None
            for i, byte in enumerate(drip):
                if i == 2:  # meanwhile another client is served
                    other = _raw(server, _post(server, [str(len(b'{"strokes": []}'))]), b'{"strokes": []}')
                try:
                    s.sendall(bytes([byte]))
                except OSError:
                    closed_at = time.perf_counter() - t0
                    break
                time.sleep(0.3)
                if time.perf_counter() - t0 > 8:
                    break
            if closed_at is None:
                s.settimeout(5)
                try:
                    rest = s.recv(65536)
                except OSError:
                    rest = b""
                assert rest == b"" or not rest.startswith(b"HTTP/1.0 200"), rest
                closed_at = time.perf_counter() - t0
        assert closed_at < 8.0, closed_at
        assert other is not None and other[0] == 200, other
    finally:
        server.shutdown()
        server.server_close()


def test_the_masks_page_refuses_two_content_lengths_and_times_out_a_short_body(page) -> None:
    body = b'{"strokes": []}'
    status, answer, _ = _raw(page, _post(page, [str(len(body)), "5"]), body)
    assert status == 400 and "2 different Content-Length headers" in answer["error"], answer
    status, answer, seconds = _raw(page, _post(page, ["1000"]), body)  # 15 of 1000 bytes, then the client waits
    assert status == 408 and "did not arrive in time" in answer["error"] and seconds < 5, (status, answer, seconds)
    status, _, _ = _raw(page, _post(page, [str(len(body)), str(len(body))]), body)  # the same one twice is one
    assert status == 200


# ------------------------------------------------------------------------------------------ params.yaml


def test_a_key_given_twice_in_params_yaml_is_refused_by_preflight_and_every_add_command(tmp_path: Path,
                                                                                        capsys) -> None:
    """PyYAML keeps the second of two equal keys silently, DVC refuses the file and ruamel.yaml raised a traceback:
    preflight and add-scene, add-style and add-experiment (--dry-run too) refuse it in one line naming the key and
    its two lines."""
    import shutil

    from abcgs.__main__ import main as abcgs_main
    from abcgs.preflight import main as preflight_main

    repo = tmp_path / "repo"
    repo.mkdir()
    for name in ("params.yaml", "dvc.yaml"):
        shutil.copy(Path(__file__).resolve().parents[1] / name, repo / name)
    params = repo / "params.yaml"
    text = params.read_text()
    params.write_text(text + "\nruntime:\n  device: cpu\n")
    first = 1 + text.splitlines().index("runtime:")
    last = len(text.splitlines()) + 2
    scene = _photos(tmp_path / "scene")
    painting = tmp_path / "p.png"
    save_image(painting, np.zeros((64, 64, 3), np.float32))
    calls = [(preflight_main, [str(params)]),
             (abcgs_main, ["add-scene", "s", str(scene), "--params", str(params)]),
             (abcgs_main, ["add-style", "p", str(painting), "--params", str(params)]),
             (abcgs_main, ["add-experiment", "e", "--scene", "tiny", "--style", "tiny_paint", "--dry-run",
                           "--params", str(params)])]
    for command, argv in calls:
        t0 = time.perf_counter()
        assert command(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err, err
        assert f"gives the key 'runtime' at lines {first} and {last} of one mapping; keep one" in err, err
        assert time.perf_counter() - t0 < 20
    assert params.read_text() == text + "\nruntime:\n  device: cpu\n"  # nothing written


# ------------------------------------------------------------------------------------------ fitted_rows.npy


def _header_claiming(rows: int) -> bytes:
    """A valid ``.npy`` header of ``rows`` int64 rows, followed by 6 rows only."""
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<i8", "fortran_order": False, "shape": (rows,)})
    return buf.getvalue() + np.arange(6, dtype="<i8").tobytes()


def _write_rows(path: Path, kind: str) -> None:
    """A colour match's ``fitted_rows.npy`` for 6 Gaussians of a fitted scene of 4, made hostile as ``kind``."""
    if kind == "zeros":
        np.save(path, np.zeros(6, np.int64))
    elif kind == "pickle":
        np.save(path, np.array([0, 1, 2, None, 3, 1], dtype=object), allow_pickle=True)
    elif kind == "negative":
        np.save(path, np.array([0, 1, 2, 3, -7, 1]))
    elif kind == "short":
        np.save(path, np.array([0, 1, 2, 3, 3]))
    elif kind == "truncated":
        np.save(path, np.array([0, 1, 2, 3, 3, 1]))
        path.write_bytes(path.read_bytes()[:-3])
    elif kind == "oversized":
        np.save(path, np.array([0, 1, 2, 3, 3, 1]))
        path.write_bytes(path.read_bytes() + bytes(1 << 20))
    elif kind == "header_1e10":
        path.write_bytes(_header_claiming(10**10))
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "dev_zero":
        path.symlink_to("/dev/zero")
    elif kind == "float":
        np.save(path, np.zeros(6, np.float32))
    elif kind == "open_header":  # a header dict never closed: numpy's parser ends in tokenize's TokenError
        np.save(path, np.array([0, 1, 2, 3, 3, 1]))
        data = bytearray(path.read_bytes())
        data[data.index(b"}")] = ord(" ")
        path.write_bytes(bytes(data))
    else:
        raise AssertionError(kind)


ROWS_REFUSALS = {
    "zeros": "puts all 6 Gaussians on the one fitted row 0",
    "pickle": "holds Python objects, which numpy stores as a pickle; abcgs never loads a pickle",
    "negative": "gives row 4 the fitted row -7, outside 0 .. 3",
    "short": "holds 5 rows for 6 Gaussians",
    "truncated": "is truncated: it is 173 bytes, its header states 6 values of 8 bytes, 176 bytes in all",
    "oversized": "has 1048576 bytes after its data",
    "header_1e10": "states 10000000000 values in its header, more than the 6 it can hold here",
    "fifo": "is a FIFO (named pipe), not a regular file",
    "dev_zero": "is a character device, not a regular file",
    "float": "holds float32 values, not integers",
    "open_header": "is not a .npy array file",
}


@pytest.mark.parametrize("kind", list(ROWS_REFUSALS))
def test_a_hostile_fitted_rows_file_is_refused_by_stylize_in_one_line(tmp_path: Path, kind: str) -> None:
    """The stylize stage reads its colour match's rows through the guarded reader: one line naming the file, the
    reason and the fix, in well under a second and without reading a FIFO, /dev/zero or a header's 10^10 rows."""
    import tracemalloc

    from abcgs.layout import ColorMatchDir
    from abcgs.stylize.experiment import read_colormatch

    d = ColorMatchDir(tmp_path / "m")
    d.root.mkdir()
    write_ply(d.ply, sample_model(6))
    _write_rows(d.fitted_rows, kind)
    t0 = time.perf_counter()
    tracemalloc.start()
    try:
        with pytest.raises(InputError) as exc:
            read_colormatch(d.root, "m", 4)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    text = one_line(exc)
    assert time.perf_counter() - t0 < 5 and peak < 16 << 20, (time.perf_counter() - t0, peak)
    assert f"fitted rows {d.fitted_rows} {ROWS_REFUSALS[kind]}" in text, text
    assert text.endswith("re-run the colour match (dvc repro colormatch@m)"), text


def test_rows_that_repeat_as_a_densifying_re_fit_leaves_them_are_read(tmp_path: Path) -> None:
    """Clones and split children keep their parent's row: repeats are no fault, one row for all of them is."""
    from abcgs.gaussians import read_fitted_rows

    path = tmp_path / "fitted_rows.npy"
    np.save(path, np.array([0, 3, 3, 1, 1, 1], dtype=">i4"))  # another byte order and width: integers still
    assert read_fitted_rows(path, 6, 4).tolist() == [0, 3, 3, 1, 1, 1]
    np.save(path, np.zeros(1, np.int64))
    assert read_fitted_rows(path, 1, 4).tolist() == [0]  # one Gaussian has one row
    np.save(path, np.zeros(3, np.int64))
    assert read_fitted_rows(path, 3, 1).tolist() == [0, 0, 0]  # a fitted scene of one Gaussian
    np.save(path, np.zeros(3, np.int64))
    with pytest.raises(InputError, match="puts all 3 Gaussians on the one fitted row 0"):
        read_fitted_rows(path, 3, 4)


@pytest.mark.parametrize("kind", ["pickle", "header_1e10", "fifo", "zeros"])
def test_the_viewer_reports_why_it_leaves_the_labels_layer_out(tmp_path: Path, kind: str, caplog) -> None:
    """A stylized scene's rows file that the guarded reader refuses: the viewer still shows the scene, and its
    output (the page above the viewer, ``python -m abcgs.view``'s lines, the log) says the labels layer is left
    out and why, instead of dropping it silently."""
    from abcgs.view.outputs import _on_stylized_rows
    from abcgs.view.page import ViewerExperiment, viewer_fragment

    rows = tmp_path / "out" / "e" / "stylize" / "fitted_rows.npy"
    rows.parent.mkdir(parents=True)
    _write_rows(rows, kind)
    notes: list[str] = []
    with caplog.at_level("WARNING"):
        assert _on_stylized_rows(np.arange(4), rows, 6, notes, fix="re-run its stylize stage") is None
    assert len(notes) == 1 and notes[0].startswith(f"the labels layer is left out: fitted rows {rows} "), notes
    assert ROWS_REFUSALS[kind] in notes[0] and notes[0].endswith("re-run its stylize stage"), notes
    assert notes[0] in caplog.text
    exp = ViewerExperiment("e", {"stylized": sample_model(6)}, sample_cameras()[:1], 6, target=np.zeros(3),
                           notes=notes)
    html_text = viewer_fragment([exp])
    assert '<p class="abcgs-viewer-note">e: the labels layer is left out: fitted rows' in html_text


# ------------------------------------------------------------------------------------------ special files named as inputs


def test_a_socket_or_a_fifo_given_to_add_scene_or_as_a_painting_is_named_as_such(tmp_path: Path) -> None:
    """``add-scene`` on a socket or a FIFO, and the masks page's ``--painting`` on a FIFO, say what the path is (in
    one line, without opening it: opening a FIFO would wait for a writer), not that it does not exist."""
    import shutil

    from abcgs.add import add_scene
    from abcgs.masks.page.session import PaintSession

    sock_path = tmp_path / "scene.sock"
    with socket.socket(socket.AF_UNIX) as sock:
        sock.bind(str(sock_path))
        fifo = tmp_path / "fifo.png"
        os.mkfifo(fifo)
        params = tmp_path / "params.yaml"
        shutil.copy(REPO_ROOT / "params.yaml", params)
        for path, kind in ((sock_path, "a socket"), (fifo, "a FIFO (named pipe)")):
            with pytest.raises(InputError) as exc:
                add_scene(params, "s1", path, dry_run=True)
            assert str(exc.value) == (f"scene {path} is {kind}, not a regular file; give the scene's folder, or its "
                                      "splat file")
        with pytest.raises(InputError, match=r"^painting .*fifo.png is a FIFO \(named pipe\), not a regular file"):
            PaintSession.for_painting(fifo)
        with pytest.raises(InputError, match=r"^painting .*none.png does not exist$"):
            PaintSession.for_painting(tmp_path / "none.png")


# ------------------------------------------------------------------------------------------ saved stroke maps


@pytest.mark.parametrize("kind", ["fifo", "dev_zero", "loop"])
def test_a_stroke_map_that_is_no_regular_file_is_refused_not_skipped(tmp_path: Path, kind: str) -> None:
    """The reconstruct stage carries the masks page's strokes into the layout: one that is a FIFO (opening it would
    block), a link to a device or a link loop is refused in one line, before anything opens it."""
    from abcgs.io.images import stroke_map_path
    from abcgs.sfm.colmap import carry_strokes

    masks = tmp_path / "masks"
    path = stroke_map_path(masks, "000")
    path.parent.mkdir(parents=True)
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "dev_zero":
        path.symlink_to("/dev/zero")
    else:
        path.symlink_to(path)
    t0 = time.perf_counter()
    with pytest.raises(InputError) as exc:
        carry_strokes(masks, "000", (12, 16), tmp_path / "out")
    assert "\n" not in str(exc.value) and str(path) in str(exc.value) and time.perf_counter() - t0 < 5
    assert not carry_strokes(masks, "001", (12, 16), tmp_path / "out")  # no strokes for that view: nothing carried
