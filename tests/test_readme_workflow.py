"""The README's workflow with commands only, from a bare splat and a painting to a stylized splat.

In a copy of the repository: the README's bash block (``add-scene``, ``add-style``, ``add-experiment``) run as written
as subprocesses, with ``/data/garden`` replaced by a generated bare ``.splat`` (its views kept small with add-scene's
``--views-*`` options, so the short schedule applies) and ``/data/starry.jpg`` by a generated painting; then the
``make repro ARGS="..."`` command that add-experiment prints, as printed (split with shlex, never given to a shell).
The copy has no ``.venv`` for make to reuse (make would install one), so the test runs the steps of the Makefile's
``repro`` recipe itself, read from the Makefile: ``python -m abcgs.dag --update``, ``python -m abcgs.preflight
params.yaml``, ``dvc repro <targets>``. Then the README's ``python -m abcgs.view out/garden_starry`` (``--no-open``).
"""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import cv2
import pytest
import torch
from conftest import REPO_ROOT, copy_repo, run_in
from readme_examples import README, readme_examples
from test_splats import make_model

from abcgs.gaussians.ply import read_ply
from abcgs.io.metrics import info_path
from abcgs.splats.formats.splat import write_splat_file
from abcgs.stylize.schedule import SHORT, SHORT_MAX_PIXELS

pytestmark = pytest.mark.slow

VIEWS = ["--views-count", "8", "--views-width", "128", "--views-height", "96"]
"""Eight views of 128 × 96 pixels: small views, so the stylization takes the short schedule."""
SHORT_REASON = f"median view {128 * 96:,} pixels <= {SHORT_MAX_PIXELS:,}: the short schedule"


def make_repro_steps(targets: list[str]) -> list[list[str]]:
    """The Makefile's ``repro`` recipe as argument lists: ``$(BIN)/`` tools by name (this interpreter's bin/ is
    first on PATH in :func:`run_in`), ``$(ARGS)`` replaced by ``targets``, environment assignments dropped."""
    makefile = (REPO_ROOT / "Makefile").read_text()
    recipe = re.search(r"^repro:[^\n]*\n((?:\t[^\n]*\n)+)", makefile, re.M)
    assert recipe, "the Makefile has no repro recipe"
    steps = []
    for line in recipe.group(1).splitlines():
        words = [w for w in shlex.split(line.strip()) if not re.fullmatch(r"[A-Z_]+=.*", w)]
        words = [w.removeprefix("$(BIN)/") for w in words]
        steps.append([x for w in words for x in (targets if w == "$(ARGS)" else [w])])
    return steps


def _ok(proc, what: str) -> str:
    assert proc.returncode == 0, f"{what}: exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc.stdout


def test_makefile_repro_recipe_is_what_the_workflow_runs() -> None:
    assert make_repro_steps(["evaluate@x", "export@x"]) == [
        ["python", "-m", "abcgs.dag", "--update"], ["python", "-m", "abcgs.preflight", "params.yaml"],
        ["dvc", "repro", "evaluate@x", "export@x"]]


def test_readme_workflow_takes_a_bare_splat_and_a_painting_to_a_stylized_splat(tiny_scene: Path,
                                                                              tmp_path: Path) -> None:
    block = [e for e in readme_examples(README.read_text(encoding="utf-8")) if e.kind == "bash"
             and e.text.startswith("python -m abcgs add-")]
    assert [e.argv[3] for e in block] == ["add-scene", "add-style", "add-experiment"], [e.text for e in block]
    splat, painting = tmp_path / "data" / "chair.splat", tmp_path / "data" / "starry.jpg"
    splat.parent.mkdir()
    write_splat_file(splat, make_model(2500, 0, seed=3))
    cv2.imwrite(str(painting), cv2.imread(str(tiny_scene / "styles" / "paint.png")))
    generated = {"add-scene": {"/data/garden": str(splat)}, "add-style": {"/data/starry.jpg": str(painting)},
                 "add-experiment": {}}
    repo = copy_repo(tmp_path / "repo")
    outputs = []
    for example in block:
        command = example.argv[3]
        argv = [generated[command].get(w, w) for w in example.argv]
        assert all(not w.startswith("/data/") for w in argv), f"no generated data for {example.text}"
        argv += VIEWS if command == "add-scene" else []
        outputs.append(_ok(run_in(argv, repo, timeout=300), example.text))
    assert "a bare splat scene" in outputs[0], outputs[0]
    printed = outputs[-1].strip().splitlines()[-1]  # `run just them with:` then the command
    make = shlex.split(printed)
    assert make[:2] == ["make", "repro"] and len(make) == 3 and make[2].startswith("ARGS="), printed
    targets = shlex.split(make[2].removeprefix("ARGS="))
    assert targets == ["evaluate@garden_starry", "export@garden_starry", "evaluate@garden_starry_nnfm",
                       "export@garden_starry_nnfm"], targets
    for step in make_repro_steps(targets):
        _ok(run_in(step, repo, timeout=1200), " ".join(step))

    out = repo / "out"
    refit = json.loads((out / "garden" / "colormatch" / "garden_starry" / "colormatch.json").read_text())["schedule"]
    assert refit == {"steps": {"refit": SHORT["refit"]}, "name": "short", "reason": SHORT_REASON}, refit
    imported = read_ply(out / "garden" / "gs" / "point_cloud.ply")
    for exp in ("garden_starry", "garden_starry_nnfm"):
        stylized = read_ply(out / exp / "stylize" / "point_cloud.ply")
        assert stylized.num_gaussians > 0 and (stylized.num_gaussians != imported.num_gaussians
                                               or not torch.equal(stylized.sh0, imported.sh0)), exp
        schedule = json.loads(info_path(out / exp / "stylize.json").read_text())["schedule"]  # the full record
        assert schedule == {"steps": {k: SHORT[k] for k in ("main", "color_pass")}, "name": "short",
                            "reason": SHORT_REASON}, schedule
        assert (out / exp / "point_cloud.spz").stat().st_size > 0  # the export stage's splat
    _ok(run_in(["python", "-m", "abcgs.view", "out/garden_starry", "--no-open"], repo, timeout=300), "abcgs.view")
    assert "garden_starry" in (repo / "reports" / "viewers" / "garden_starry.html").read_text()
