"""Shared fixtures.

- ``tiny_scene``: the embedded synthetic scene, generated once per test session (folder Path with
  images/, masks/, cameras.json, styles/).
- ``tiny_colmap``: the ``reconstruct`` output for ``tiny_scene`` (sparse/, images/, masks/, metrics.json),
  computed once per session (a few seconds of COLMAP).
- ``tiny_pipeline``: a git + DVC copy of the working tree with REDUCED iteration counts after its first ``dvc repro``
  (each stage's reads recorded under ``reads/`` beside it), computed once per session: the end-to-end tests work in
  it, the cluster tests seed their shared DVC cache from it.
- ``proxy``: the LPIPS-style proxy distance over a seeded random VGG-16 (no weights file), for evaluation tests.
- ``SHARED_DATA``: ``../shared/data`` next to the repository; tests that need it are marked
  ``@pytest.mark.shared_data`` (marker registered in pyproject.toml) and skip where it is absent.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from abcgs.runtime import setup

setup()  # before any test imports torch: OpenMP's wait policy, OpenCV before pycolmap

import pytest

from abcgs.runtime import torch_threads
from abcgs.scene.params import TinySceneParams
from abcgs.scene.synthetic import make_tiny_scene
from eval.bench.browser import INSTALL_HINT, find_chromium
from eval.bench.browser import launch_chromium as launch_browser
from eval.bench.repo_copy import copy_repo, run_in  # noqa: F401  (re-exported for the end-to-end tests)

REPO_ROOT = Path(__file__).resolve().parents[1]


def chromium_path() -> str:
    """Debian's chromium for the browser tests (``$ABCGS_CHROMIUM`` first); skipped with the install command where it
    is missing, a failure under CI."""
    path = find_chromium()
    if path:
        return path
    msg = f"chromium is not installed: {INSTALL_HINT}"
    if os.environ.get("CI"):
        pytest.fail(msg)
    pytest.skip(msg)


@contextlib.contextmanager
def launch_chromium(args: list[str]):
    """A headless chromium (playwright driving :func:`chromium_path`, no browser download) for a module's tests."""
    pytest.importorskip("playwright.sync_api")
    with launch_browser(args, chromium_path()) as browser:
        yield browser


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
    """``reconstruct`` output for :func:`tiny_scene` with default parameters (its scene included)."""
    from abcgs.sfm.params import ReconstructParams
    from abcgs.sources.photos import reconstruct_photos

    out = tmp_path_factory.mktemp("tiny_colmap") / "colmap"
    reconstruct_photos(tiny_scene, out, ReconstructParams())
    return out


@pytest.fixture(scope="session")
def tiny_pipeline(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The reduced tiny pipeline, run once: ``{"repo": Path, "repro": CompletedProcess, "reads": Path}``. The first
    user of ``repo`` may change it afterwards (the end-to-end tests do); its DVC cache only grows."""
    from abcgs.pipeline import READ_AUDIT_ENV
    from eval.bench.regression import reduce

    root = tmp_path_factory.mktemp("e2e")
    repo, reads = copy_repo(root / "repo", reduce), root / "reads"
    env = {**os.environ, READ_AUDIT_ENV: str(reads)}  # each stage records its reads under out/
    proc = run_in(["dvc", "repro"], repo, timeout=2400, env=env)  # ~3-8 min on an idle 2-core VM; generous when shared
    assert proc.returncode == 0, f"dvc repro failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}"
    return {"repo": repo, "repro": proc, "reads": reads}


@pytest.fixture(scope="session")
def proxy():
    """A perceptual distance of the ``proxy`` kind over seeded random VGG-16 weights (evaluation tests)."""
    from abcgs.evaluation.content import PerceptualDistance
    from abcgs.features.vgg import random_state_dict

    return PerceptualDistance("proxy", vgg_state=random_state_dict(0, "relu5_3"), vgg_info={"source": "random (test)"})
