"""Files from strangers: corrupt, hostile or inconsistent datasets and splats stop at their reader, before any stage
works, in one line naming the file, the record and the fix (docs/INPUTS.md lists every check). The valid inputs are
eval/bench/fuzz.py's; the fuzzing itself is tests/test_fuzz_readers.py."""

from __future__ import annotations

import gzip
import json
import logging
import shutil
import struct
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import REPO_ROOT

from abcgs.errors import InputError
from abcgs.gaussians.ply import read_ply, write_ply
from abcgs.sfm.model import layout_scene, read_scene, write_scene
from abcgs.sources.read import read_source
from abcgs.splats.formats.spz import decode_spz, encode_spz
from abcgs.splats.registry import read_splat
from eval.bench.fuzz import make_targets, sample_model
from eval.bench.fuzz_mutations import gzip_bomb


@pytest.fixture
def params_file(tmp_path: Path) -> Path:
    for name in ("params.yaml", "dvc.yaml"):
        shutil.copy(REPO_ROOT / name, tmp_path / name)
    return tmp_path / "params.yaml"


def _cli(capsys, *argv: str) -> tuple[int, str, str]:
    from abcgs.__main__ import main

    rc = main(list(argv))
    out = capsys.readouterr()
    return rc, out.out, out.err


def _one_line(err: str) -> None:
    assert err.count("\n") == 1 and "Traceback" not in err, err


# ------------------------------------------------------------------------------------------ splats


def test_a_gzip_bomb_spz_is_refused_with_bounded_memory() -> None:
    raw = gzip.decompress(encode_spz(sample_model(1000)))
    bomb = gzip_bomb(raw, 8 << 30)  # 8 MB that inflates to 8 GiB
    assert len(bomb) < 16 << 20
    tracemalloc.start()
    t0 = time.perf_counter()
    with pytest.raises(InputError, match=r"more than \d+ bytes for 1000 Gaussians"):
        decode_spz(bomb, source="bomb.spz")
    seconds, peak = time.perf_counter() - t0, tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert seconds < 10 and peak < 64 << 20, (seconds, peak)
    # a header that claims enough Gaussians to hold the bomb is refused from the header, before inflating
    claims = raw[:8] + struct.pack("<I", 50_000_000) + raw[12:]
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="more than 100x compression .* gzip bomb"):
        decode_spz(gzip_bomb(claims, 8 << 30), source="bomb.spz")
    assert time.perf_counter() - t0 < 1
    with pytest.raises(InputError, match="header states 4294967295 Gaussians"):
        decode_spz(gzip.compress(raw[:8] + struct.pack("<I", 2**32 - 1) + raw[12:]), source="bomb.spz")


def test_add_scene_refuses_a_bomb_in_one_line_within_10_s_and_1_gb(tmp_path: Path, params_file: Path, capsys) -> None:
    raw = gzip.decompress(encode_spz(sample_model(1000)))
    (tmp_path / "bomb.spz").write_bytes(gzip_bomb(raw, 8 << 30))
    argv = ["add-scene", "bomb", str(tmp_path / "bomb.spz"), "--params", str(params_file), "--dry-run"]
    t0 = time.perf_counter()
    rc, _, err = _cli(capsys, *argv)
    assert time.perf_counter() - t0 < 10
    assert rc == 2 and "bomb.spz: more than" in err, err
    _one_line(err)
    # the whole command in a process of its own, for its peak memory (its imports included); an intermediate process
    # reads it, as RUSAGE_CHILDREN of this one would include every child the test session ran before
    measure = ("import resource, subprocess, sys; r = subprocess.run([sys.executable, '-m', 'abcgs', *sys.argv[1:]]); "
               "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); sys.exit(r.returncode)")
    proc = subprocess.run([sys.executable, "-c", measure, *argv], capture_output=True, text=True, timeout=120,
                          cwd=REPO_ROOT)
    *lines, peak_kib = proc.stderr.splitlines()
    assert proc.returncode == 2 and "\n".join(lines) + "\n" == err
    assert int(peak_kib) / 2**20 < 1.0, peak_kib


def test_non_finite_gaussians_are_refused_with_their_count_or_dropped(tmp_path: Path, caplog) -> None:
    model = sample_model(64)
    model.means[3, 0] = float("nan")
    model.log_scales[5, 1] = float("inf")
    write_ply(tmp_path / "bad.ply", model)
    for read in (lambda: read_splat(tmp_path / "bad.ply"), lambda: read_ply(tmp_path / "bad.ply")):
        with pytest.raises(InputError, match=r"bad.ply: 2 of 64 Gaussians have a NaN or infinite value.*"
                                             r"splat_nonfinite: drop"):
            read()
    with caplog.at_level(logging.WARNING):
        kept = read_splat(tmp_path / "bad.ply", drop_invalid=True)
    assert kept.model.num_gaussians == 62 and bool(torch.isfinite(kept.model.log_scales).all())
    assert "2 of 64 Gaussians" in caplog.text and "dropped" in caplog.text


def test_add_scene_takes_every_setting_its_messages_name(tmp_path: Path, params_file: Path, capsys) -> None:
    model = sample_model(64)
    model.means[3, 0] = float("nan")
    (tmp_path / "splat").mkdir()
    write_ply(tmp_path / "splat" / "scene.ply", model)
    rc, _, err = _cli(capsys, "add-scene", "s", str(tmp_path / "splat"), "--params", str(params_file), "--dry-run")
    assert rc == 2 and "1 of 64 Gaussians" in err and "splat_nonfinite: drop" in err
    _one_line(err)
    rc, out, err = _cli(capsys, "add-scene", "s", str(tmp_path / "splat"), "--params", str(params_file), "--dry-run",
                        "--splat-nonfinite", "drop", "--splat-format", "ply", "--views-count", "8",
                        "--views-kind", "orbit")
    assert rc == 0, err
    assert "63 Gaussians" in out and "splat_nonfinite: drop" in out and "splat_format: ply" in out
    assert "count: 8" in out and "kind: orbit" in out
    rc, _, err = _cli(capsys, "add-scene", "s", str(tmp_path / "splat"), "--params", str(params_file),
                      "--splat-nonfinite", "drop", "--splat-format", "ply", "--views-count", "8")
    assert rc == 0, err
    entry = json.loads(json.dumps(__import__("yaml").safe_load(params_file.read_text())["data"]["scenes"]["s"]))
    assert entry["splat_format"] == "ply" and entry["splat_nonfinite"] == "drop"
    assert entry["source"] == {"format": "splat", "views": {"count": 8}}


def test_add_scene_dry_run_refuses_what_the_real_run_refuses(tmp_path: Path, params_file: Path, capsys) -> None:
    (tmp_path / "s").mkdir()
    write_ply(tmp_path / "s" / "scene.ply", sample_model(16))
    errors = []
    for extra in (["--dry-run"], []):
        rc, _, err = _cli(capsys, "add-scene", "a..", str(tmp_path / "s"), "--params", str(params_file), *extra)
        assert rc == 2, err
        _one_line(err)
        errors.append(err)
    assert errors[0] == errors[1]


def test_view_with_a_missing_params_file_says_so(tmp_path: Path, capsys) -> None:
    from abcgs.view.__main__ import main

    assert main([str(tmp_path), "--params", str(tmp_path / "missing.yaml"), "--no-open",
                 "--out", str(tmp_path / "v.html")]) == 2
    err = capsys.readouterr().err
    assert "--params" in err and "missing.yaml does not exist" in err
    _one_line(err)


# ------------------------------------------------------------------------------------------ datasets


@pytest.fixture
def datasets(tmp_path: Path):
    return make_targets(tmp_path / "data", ("colmap_bin", "colmap_txt", "transforms", "llff"))


def test_a_truncated_cameras_bin_is_refused(datasets, tmp_path: Path) -> None:
    """By the dataset reader, and by the scene reader in a layout of the same model (as the reconstruct stage
    leaves one: sparse/, images/, scene.json)."""
    t = datasets["colmap_bin"]
    cameras = t.files[0]
    folder = cameras.parents[2]
    layout = tmp_path / "layout"
    shutil.copytree(folder / "images", layout / "images")
    shutil.copytree(cameras.parent, layout / "sparse")
    write_scene(layout_scene(layout, format="colmap"), layout)
    for c in (cameras, layout / "sparse" / "cameras.bin"):
        c.write_bytes(c.read_bytes()[:30])
    for read in (lambda: read_source(folder, "colmap"), lambda: read_scene(layout)):
        with pytest.raises(InputError, match=r"cameras.bin states 5 cameras but its 22 remaining bytes hold at most 0"):
            read()


@pytest.mark.parametrize("line, message", [
    ("1 PINHOLE 32 24 0 0 16 12", "focal length fx = 0 px is not plausible"),
    ("1 PINHOLE 0 0 30 30 16 12", "the image size 0 x 0 is not a size in pixels"),
    ("1 PINHOLE 32 24 nan 30 16 12", "are not all finite"),
    ("1 PINHOLE 32 24 30 30 16", "camera 1 is PINHOLE with 3 parameters; that model has 4"),
])
def test_colmap_text_intrinsics_are_checked(datasets, line: str, message: str) -> None:
    t = datasets["colmap_txt"]
    cameras = t.files[0]
    lines = [ln for ln in cameras.read_text().splitlines() if not ln.startswith("1 ")]
    cameras.write_text("\n".join(lines + [line]) + "\n")
    with pytest.raises(InputError, match=message):
        read_source(cameras.parents[2], "colmap")


def _transforms(t) -> tuple[Path, dict]:
    return t.files[0], json.loads(t.files[0].read_text())


def test_duplicate_and_too_many_frames_are_refused_quickly(datasets) -> None:
    path, meta = _transforms(datasets["transforms"])
    folder = path.parent
    meta["frames"].append(dict(meta["frames"][0]))
    path.write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"frames\[0\] and frames\[5\] both name 'images/view00.png'.*remove the "
                                         r"repeated one"):
        read_source(folder, "nerfstudio")
    meta["frames"] = meta["frames"][:5] * 19_200  # 96 000 frames
    path.write_text(json.dumps(meta))
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="lists 96000 views, more than the 20000"):
        read_source(folder, "nerfstudio")
    assert time.perf_counter() - t0 < 10


@pytest.mark.parametrize("edit, message", [
    (lambda m: m.update(fl_x=0), "focal length fx = 0 px is not plausible for a 32 x 24 image"),
    (lambda m: m.update(w=0, h=0), "the image size 0 x 0 is not a size in pixels"),
    (lambda m: m.update(cx=float("nan")), "not a finite number"),
    (lambda m: m["frames"][1].update(transform_matrix=(np.diag([1.0, 1, -1, 1])).tolist()), "not a proper rotation"),
    (lambda m: m["frames"][2].update(file_path="../elsewhere/view02.png"),
     r"frames\[2\].file_path '../elsewhere/view02.png' names .* outside the scene folder .*DVC tracks only the "
     r"scene's folder.*copy the file into the scene's folder"),
])
def test_transforms_values_are_checked(datasets, edit, message: str) -> None:
    path, meta = _transforms(datasets["transforms"])
    edit(meta)
    (path.parent.parent / "elsewhere").mkdir()
    shutil.copy(path.parent / "images" / "view02.png", path.parent.parent / "elsewhere" / "view02.png")
    path.write_text(json.dumps(meta))
    with pytest.raises(InputError, match=message):
        read_source(path.parent, "nerfstudio")


def test_deeply_nested_json_is_refused(datasets) -> None:
    path = datasets["transforms"].files[0]
    path.write_text("[" * 200_000 + "]" * 200_000)
    with pytest.raises(InputError, match="nested too deeply"):
        read_source(path.parent, "nerfstudio")


def test_zero_size_in_add_scene_is_one_line(datasets, params_file: Path, capsys) -> None:
    path, meta = _transforms(datasets["transforms"])
    meta.update(w=0, h=0)
    path.write_text(json.dumps(meta))
    rc, _, err = _cli(capsys, "add-scene", "zero", str(path.parent), "--params", str(params_file))
    assert rc == 2 and "image size 0 x 0" in err
    _one_line(err)


def test_llff_poses_with_nan_are_refused(datasets) -> None:
    path = datasets["llff"].files[0]
    arr = np.load(path)
    arr[2, 3] = np.nan
    np.save(path, arr)
    with pytest.raises(InputError, match="rows 2 hold NaN or infinite values"):
        read_source(path.parent, "llff")


# ------------------------------------------------------------------------------------------ params before DVC


def test_an_empty_params_file_gets_preflights_message(tmp_path: Path, capsys) -> None:
    from abcgs.preflight import main

    (tmp_path / "params.yaml").write_text("")
    assert main([str(tmp_path / "params.yaml")]) == 2
    err = capsys.readouterr().err
    assert "must be a YAML mapping" in err
    _one_line(err)
    make = (REPO_ROOT / "Makefile").read_text()
    for target in ("run", "repro"):
        recipe = make.split(f"\n{target}: install\n", 1)[1].split("\n\n", 1)[0]
        assert recipe.index("abcgs.preflight") < recipe.index("dvc repro"), target
