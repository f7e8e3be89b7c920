"""Shared fixtures.

- ``tiny_scene``: the embedded synthetic scene, generated once per test session (folder Path with
  images/, masks/, cameras.json, styles/).
- ``tiny_colmap``: the ``reconstruct`` output for ``tiny_scene`` (sparse/, images/, masks/, metrics.json),
  computed once per session (a few seconds of COLMAP).
- ``SHARED_DATA``: ``../shared/data`` next to the repository; tests that need it are marked
  ``@pytest.mark.shared_data`` (marker registered in pyproject.toml) and skip where it is absent.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import cv2  # noqa: F401  (load before anything imports pycolmap; see abcgs/sfm/__init__.py)
import pytest
import yaml

from abcgs.fit.trainer import torch_threads
from abcgs.scene.synthetic import TinySceneParams, make_tiny_scene

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """Tests use tiny tensors: one intra-op thread avoids OpenMP spin-waiting, which makes small ops many times
    slower on a loaded 2-core machine. Tests that compare thread counts set their own inside."""
    with torch_threads(1):
        yield


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The default embedded scene (``TinySceneParams()``), written once per session."""
    return make_tiny_scene(tmp_path_factory.mktemp("tiny") / "tiny", TinySceneParams())


@pytest.fixture(scope="session")
def tiny_colmap(tiny_scene: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``reconstruct`` output for :func:`tiny_scene` with default parameters."""
    from abcgs.sfm.colmap import ReconstructParams, reconstruct

    out = tmp_path_factory.mktemp("tiny_colmap") / "colmap"
    reconstruct(tiny_scene / "images", out, ReconstructParams(), masks_dir=tiny_scene / "masks")
    return out


def run_in(args: list[str], cwd: Path, timeout: int = 900) -> subprocess.CompletedProcess:
    """Run a command (e.g. ``dvc repro``) in ``cwd`` with this interpreter's bin/ first on PATH."""
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONUNBUFFERED"] = "1"
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def copy_repo(dst: Path, edit_params: Callable[[dict], None] | None = None) -> Path:
    """A git+DVC copy of the working tree at ``dst`` (tracked and untracked-not-ignored files, no pipeline
    outputs, so it starts like a clean clone without a cache); ``edit_params`` may change params.yaml first."""
    files = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=REPO_ROOT,
        capture_output=True, check=True,
    ).stdout.decode().split("\0")
    outputs = ("out/", "data/", "reports/")
    for rel in filter(None, files):
        if rel.startswith(outputs):
            continue
        src = REPO_ROOT / rel
        if src.is_file():
            (dst / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst / rel)
    if edit_params is not None:
        params = yaml.safe_load((dst / "params.yaml").read_text())
        edit_params(params)
        (dst / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    git = ["git", "-c", "user.name=ci", "-c", "user.email=ci@example.invalid"]
    for cmd in (["git", "init", "-q"], ["git", "add", "-A"], git + ["commit", "-qm", "copy"]):
        subprocess.run(cmd, cwd=dst, check=True, capture_output=True)
    return dst
