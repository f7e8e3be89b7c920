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

import ast
import contextlib
import functools
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

PIPELINE_MARKERS = ("slow", "browser", "slurm")
"""A test file that marks a test with one of these runs pipelines, DVC or a browser in subprocesses: such files form
the pipelines lane of ``make test``'s two pytest-xdist processes (:class:`PipelineLane`)."""


def pipeline_lane_files(tests: Path = REPO_ROOT / "tests") -> frozenset[str]:
    """The test files (node-id paths, ``tests/test_x.py``) whose source names ``pytest.mark.<m>`` for a marker ``m``
    of :data:`PIPELINE_MARKERS`. Read from source, as the xdist controller, which schedules, collects no tests;
    ``tests/test_suite_lanes.py`` checks that every collected test with such a marker is in one of them."""
    found = set()
    for path in sorted(tests.glob("test_*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        if any(isinstance(node, ast.Attribute) and node.attr in PIPELINE_MARKERS
               and isinstance(node.value, ast.Attribute) and node.value.attr == "mark" for node in ast.walk(tree)):
            found.add(path.relative_to(tests.parent).as_posix())
    return frozenset(found)


class PipelineLane:
    """``-n 2 --dist loadfile`` (``make test``) with the pipelines in one lane: xdist's file-by-file scheduling, except
    that the :func:`pipeline_lane_files` are one unit, handed out first. One process then runs the pipelines, whose
    DVC bookkeeping and Python start-ups keep only one core busy at a time, while the other runs the remaining files;
    each file's module fixtures and the lane's shared ``tiny_pipeline`` are computed once."""

    @functools.cached_property
    def lane(self) -> frozenset[str]:
        """:func:`pipeline_lane_files`, read on first use: a run without xdist's processes never parses them."""
        return pipeline_lane_files()

    def pytest_xdist_make_scheduler(self, config: pytest.Config, log):
        if config.getvalue("dist") != "loadfile":
            return None
        from xdist.scheduler import LoadFileScheduling

        lane = self.lane

        class LaneScheduling(LoadFileScheduling):
            def _split_scope(self, nodeid: str) -> str:
                scope = super()._split_scope(nodeid)
                return "pipelines" if scope in lane else scope

        config.option.loadscopereorder = False  # units in the workers' order: the lane first
        return LaneScheduling(config, log)

    @pytest.hookimpl(tryfirst=True)
    def pytest_collection_modifyitems(self, items: list[pytest.Item]) -> None:
        if os.environ.get("PYTEST_XDIST_WORKER"):  # every worker sorts alike (xdist checks that they agree)
            items.sort(key=lambda item: item.nodeid.split("::", 1)[0] not in self.lane)  # stable


def pytest_configure(config: pytest.Config) -> None:
    if config.pluginmanager.hasplugin("xdist"):
        config.pluginmanager.register(PipelineLane(), "abcgs-pipeline-lane")


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
