"""Splat formats by registry: every module of ``abcgs/splats/formats/`` brings its ``FORMAT`` (detect, read, write,
frame), the registry finds them all, and a format added at run time is read and written like the built-in ones.
Every format writes its single-file bytes through :func:`abcgs.io.atomic.write_stream` (one atomic byte writer)."""

from __future__ import annotations

import ast
import io
from pathlib import Path
from typing import get_args

import numpy as np
import pytest
import torch

from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.io.atomic import write_bytes
from abcgs.splats.contract import SplatFormatSpec, SplatProvenance, read_bytes
from abcgs.splats.registry import (
    detect_splat_format,
    format_of,
    read_splat,
    register,
    registered,
    unregister,
    write_splat,
)
from abcgs.types import SplatFormat

ROOT = Path(__file__).resolve().parents[1]
FORMATS_DIR = ROOT / "abcgs" / "splats" / "formats"


def _model(n: int = 20, seed: int = 0) -> GaussianModel:
    g = torch.Generator().manual_seed(seed)
    return GaussianModel(means=torch.randn(n, 3, generator=g), quats=torch.nn.functional.normalize(
        torch.randn(n, 4, generator=g), dim=1), log_scales=torch.randn(n, 3, generator=g) - 3,
        opacity_logits=torch.randn(n, generator=g), sh0=torch.randn(n, 1, 3, generator=g), shN=torch.zeros(n, 0, 3))


def test_every_format_module_brings_a_format_and_the_registry_finds_it():
    modules = sorted(p.stem for p in FORMATS_DIR.glob("*.py") if p.name != "__init__.py")
    formats = registered()
    assert sorted(formats) == sorted(get_args(SplatFormat)), "abcgs.types.SplatFormat and the format modules differ"
    assert len(modules) == len(formats)
    for spec in formats.values():
        assert isinstance(spec, SplatFormatSpec) and callable(spec.read) and callable(spec.write)


def test_detection_order_puts_specific_formats_before_general_ones():
    order = list(registered())
    assert order.index("supersplat") < order.index("ply") and order.index("splatfacto") < order.index("ply")
    assert order.index("inria") < order.index("splatfacto")


# ---- a toy format: one module's worth of code, registered at run time -----------------------------------------------
def _toy_read(path: Path, drop_invalid: bool) -> tuple[GaussianModel, dict]:
    arrays = np.load(io.BytesIO(read_bytes(path, "toy file")))
    return GaussianModel(**{k: torch.from_numpy(arrays[k]) for k in arrays.files}), {}


def _toy_write(model: GaussianModel, path: Path, like: SplatProvenance) -> None:
    buf = io.BytesIO()
    np.savez(buf, **{k: v.detach().numpy() for k, v in model.items()})
    write_bytes(path, buf.getvalue())


TOY = SplatFormatSpec("toy", _toy_read, _toy_write, detect=lambda p: p.suffix == ".toy", rank=5, suffixes=(".toy",))


@pytest.fixture
def toy():
    register(TOY)
    try:
        yield TOY
    finally:
        unregister("toy")


def test_a_registered_toy_format_is_detected_read_and_written_back(toy, tmp_path: Path):
    model = _model()
    TOY.write(model, tmp_path / "scene.toy", None)
    assert detect_splat_format(tmp_path / "scene.toy") == "toy"
    imported = read_splat(tmp_path / "scene.toy")
    assert imported.provenance.format == "toy" and imported.provenance.n_gaussians == 20
    assert torch.equal(imported.model.means, model.means)
    out = write_splat(imported.model, tmp_path / "back.toy", imported.provenance)
    back = read_splat(out, "toy").model
    for name, value in model.items():
        assert torch.equal(getattr(back, name), value), name
    assert "toy" in registered() and format_of("toy") is TOY


def test_a_format_name_is_registered_once(toy):
    with pytest.raises(ValueError, match="already registered"):
        register(TOY)


def test_after_unregistering_the_toy_format_is_unknown(tmp_path: Path):
    (tmp_path / "scene.toy").write_bytes(b"x")
    with pytest.raises(InputError, match="unknown splat file type"):
        detect_splat_format(tmp_path / "scene.toy")
    with pytest.raises(InputError, match="unknown splat_format 'toy'"):
        read_splat(tmp_path / "scene.toy", "toy")


# ---- one atomic byte writer --------------------------------------------------------------------------------------
def _writes_files_directly(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.Call):
            continue
        name = getattr(node.func, "attr", getattr(node.func, "id", None))
        if name == "open" and any(isinstance(a, ast.Constant) and isinstance(a.value, str) and set(a.value) & set("wax")
                                  for a in node.args[1:2] + [k.value for k in node.keywords if k.arg == "mode"]):
            found.append(f"{path.name}:{node.lineno} open(..., write mode)")
        elif name in ("write_bytes", "write_text") and isinstance(node.func, ast.Attribute) and not (
                isinstance(node.func.value, ast.Name) and node.func.value.id in ("tmp",)):
            found.append(f"{path.name}:{node.lineno} Path.{name}")
        elif name == "save" and isinstance(node.func, ast.Attribute) and len(node.args) > 1 and not (
                isinstance(node.args[1], ast.Name) and node.args[1].id == "fh"):
            found.append(f"{path.name}:{node.lineno} torch.save to a path")
    return found


def test_formats_write_bytes_only_through_the_atomic_writer():
    files = [*sorted(FORMATS_DIR.glob("*.py")), ROOT / "abcgs" / "gaussians" / "ply.py"]
    found = [hit for p in files for hit in _writes_files_directly(p)]
    assert not found, f"format modules that write a file themselves (use abcgs.io.atomic.write_stream): {found}"


def test_the_check_sees_a_direct_write():
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "m.py"
        p.write_text("def f(path, x):\n    open(path, 'wb').write(x)\n    torch.save(x, path)\n")
        assert len(_writes_files_directly(p)) == 2
