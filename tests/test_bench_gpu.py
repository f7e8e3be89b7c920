"""The device setting, and the prepared GPU run (eval/bench/gpu.py): its CPU dry run here, its CUDA run where a GPU is."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest
import torch

from abcgs.errors import InputError
from abcgs.params import Params
from abcgs.runtime import resolve_device
from eval.bench import gpu

ROOT = Path(__file__).resolve().parents[1]
TENSOR_STAGES = ("fit", "masks", "reference", "colormatch", "stylize", "evaluate")


def test_resolve_device() -> None:
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto") == torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if not torch.cuda.is_available():
        with pytest.raises(InputError, match="runtime.device is 'cuda' but torch sees no CUDA GPU"):
            resolve_device("cuda")


def test_runtime_device_is_in_the_schema_and_fit_has_no_device_of_its_own() -> None:
    assert Params.model_fields["runtime"].default_factory().device == "auto"
    from abcgs.fit.params import FitParams

    assert "device" not in FitParams.model_fields


@pytest.mark.parametrize("stage", TENSOR_STAGES)
def test_every_tensor_stage_tracks_and_resolves_the_device(stage: str) -> None:
    """Each stage that computes on tensors tracks ``runtime`` (so DVC re-runs it when the device changes) and hands
    :func:`resolve_device`'s result to the library."""
    src = (ROOT / "stages" / f"{stage}.py").read_text()
    tree = ast.parse(src)
    calls = {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    assert "resolve_device" in calls, f"stages/{stage}.py does not resolve runtime.device"
    spec = next(n for n in ast.walk(tree) if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", "") == "SPEC")
    assert "runtime" in ast.unparse(spec.value), f"stages/{stage}.py's StageSpec does not track runtime"


@pytest.mark.slow
def test_the_gpu_script_dry_run_on_the_cpu(tmp_path: Path) -> None:
    """``python -m eval run gpu run --device cpu --tiny --quick``: every stage's entry point runs under
    ``runtime.device: cpu`` through the script that a lent GPU runs, and its outputs are on disk and on the CPU."""
    from abcgs.gaussians.ply import read_ply

    record = gpu.run(gpu.main_parser().parse_args(
        ["run", "--device", "cpu", "--tiny", "--quick", "--work", str(tmp_path / "work"), "--json", str(tmp_path / "r.json")]))
    out = tmp_path / "work" / "out"
    stages = set(record["tiny_stage_s"])
    assert {"tiny: fit", "tiny: masks", "tiny: reference", "tiny_single: colormatch", "tiny_single: stylize",
            "tiny_single: evaluate"} <= stages
    for ply in (out / "tiny" / "gs" / "point_cloud.ply", out / "tiny_single" / "stylize" / "point_cloud.ply"):
        assert read_ply(ply).device.type == "cpu"
    metrics = json.loads((out / "tiny_single" / "metrics.json").read_text())
    assert 0.0 < metrics["content_ssim"] <= 1.0
    assert json.loads((tmp_path / "r.json").read_text())["device"] == "cpu"


@pytest.mark.cuda
@pytest.mark.slow
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (torch sees none here)")
def test_the_tiny_pipeline_on_cuda_matches_the_cpu_metrics(tmp_path: Path) -> None:
    """The tiny pipeline's headline metrics on CUDA lie within :data:`eval.bench.gpu.TINY_TOLERANCE` of the CPU's
    committed ones (another float order and random stream, the same method)."""
    record = gpu.run(gpu.main_parser().parse_args(["run", "--device", "cuda", "--tiny", "--work", str(tmp_path)]))
    off = {(e, k): r for e, rows in record["tiny_vs_cpu"].items() for k, r in rows.items() if r["within"] is False}
    assert not off, off
