"""No params value reaches a shell, however DVC selects the stages to run.

``dvc.yaml``'s commands carry no ``${...}``: a ``foreach`` stage takes its key from ``$DVC_STAGE`` and fills it into
its path arguments (:func:`abcgs.pipeline.stage_key`). The schema rejects names with shell syntax, but a stage
selected on its own (``dvc repro -s``, ``--downstream``, ``dvc exp run -s``, a cluster job's ``dvc repro``) runs its
command without the ``preflight`` stage, so the command itself must hold nothing a name could rewrite. These tests
give a copy of the repository an experiment and a scene named to break out of shell quotes, make the hostile
stages' dependencies exist (empty stand-ins: the stage is stopped by the schema at its start) and run each
selection with DVC: no file appears, and the stage's own refusal is in the output.
"""

from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT, copy_repo, run_in

from abcgs.errors import AbcgsError
from abcgs.pipeline import DVC_STAGE_ENV, StageSpec, fill_paths, stage_key

MARK = "PWNED"
EXPERIMENT = f"e'; touch {MARK}; echo '"
"""Closes the single quotes a command would put around ``${key}``, runs ``touch``, reopens them."""
SCENE = f"s'; touch {MARK}; echo '"
DVC = yaml.safe_load((REPO_ROOT / "dvc.yaml").read_text())["stages"]


def test_no_stage_command_interpolates_a_params_value() -> None:
    for name, stage in DVC.items():
        cmd = stage.get("do", stage)["cmd"]
        assert "${" not in str(cmd), f"stage {name}: its command interpolates {cmd!r}"


def _hostile(params: dict) -> None:
    params["colormatches"]["hostile_match"] = dict(params["colormatches"]["tiny_single"])
    params["experiments"][EXPERIMENT] = {**params["experiments"]["tiny_single"], "colormatch": "hostile_match"}
    params["data"]["scenes"][SCENE] = dict(params["data"]["scenes"]["tiny"])


UPSTREAM = {"preflight": None, "make_tiny": None, "styles": "tiny_paint", "reconstruct": "tiny", "fit": "tiny",
            "masks": "tiny", "colormatch": "hostile_match"}
"""The stages upstream of the hostile ones, with their ``foreach`` key: recorded as done, with stand-in outputs."""


def _stand_ins(repo: Path) -> list[str]:
    """Stand-in outputs of :data:`UPSTREAM` (an empty file, or a folder with one); their stage addresses."""
    for name, key in UPSTREAM.items():
        body = DVC[name].get("do", DVC[name])
        for entry in [e for section in ("outs", "metrics", "plots") for e in body.get(section) or []]:
            path = repo / (entry if isinstance(entry, str) else next(iter(entry))).replace(
                "${key}", key or "").replace("${item.scene}", "tiny")
            if path.suffix:
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text("{}")
            else:
                path.mkdir(parents=True, exist_ok=True)
                (path / "stand_in.txt").write_text("x")
    for name, key in UPSTREAM.items():  # a file the stages read inside another's output folder (out/label_use/S.json)
        body = DVC[name].get("do", DVC[name])
        for dep in body.get("deps") or []:
            path = repo / dep.replace("${key}", key or "").replace("${item.scene}", "tiny")
            if dep.startswith("out/") and path.suffix and not path.exists():
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text("{}")
    painting = repo / "data" / "tiny" / "styles" / "paint.png"  # styles@tiny_paint's input, inside make_tiny's output
    painting.parent.mkdir(parents=True, exist_ok=True)
    painting.write_text("x")
    return [name if key is None else f"{name}@{key}" for name, key in UPSTREAM.items()]


@pytest.fixture(scope="module")
def repo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    # the workspace's dvc.yaml: the generator validates params, and these are made for the stages to refuse
    repo = copy_repo(tmp_path_factory.mktemp("hostile") / "repo", _hostile, regenerate_dvc_yaml=False)
    # the upstream stages count as done (in dvc.lock, committed), so that DVC runs the hostile stages' commands
    # under every selection, `dvc exp run` included (which checks the baseline commit's outputs out first)
    for args in (["dvc", "commit", "-f", *_stand_ins(repo)], ["git", "add", "-A"],
                 ["git", "-c", "user.name=ci", "-c", "user.email=ci@example.invalid", "commit", "-qm", "stand-ins"]):
        proc = run_in(args, repo, timeout=300)
        assert proc.returncode == 0, proc.stdout + proc.stderr
    return repo


def _refused_without_running(repo: Path, proc: subprocess.CompletedProcess, stage: str) -> None:
    out = proc.stdout + proc.stderr
    assert not (repo / MARK).exists(), f"a name ran a command:\n{out[-3000:]}"
    assert proc.returncode != 0, out[-3000:]
    assert f"Running stage '{stage}" in out, f"DVC did not start the stage, so the test shows nothing:\n{out[-3000:]}"
    assert "does not match the schema" in out, out[-3000:]  # the stage started, and its schema check refused the name


@pytest.mark.parametrize("args", [["dvc", "repro", "-s", f"stylize@{EXPERIMENT}"],
                                  ["dvc", "repro", "--downstream", "colormatch@hostile_match"],
                                  ["dvc", "exp", "run", "-s", f"stylize@{EXPERIMENT}"]],
                         ids=["repro-s", "repro-downstream", "exp-run-s"])
def test_a_hostile_experiment_name_runs_no_command(repo: Path, args: list[str]) -> None:
    _refused_without_running(repo, run_in(args, repo, timeout=300), "stylize@e'")


@pytest.mark.parametrize("args", [["dvc", "repro", "-s", f"reconstruct@{SCENE}"],
                                  ["dvc", "repro", "--downstream", f"reconstruct@{SCENE}"],
                                  ["dvc", "exp", "run", "-s", f"reconstruct@{SCENE}"]],
                         ids=["repro-s", "repro-downstream", "exp-run-s"])
def test_a_hostile_scene_name_runs_no_command(repo: Path, args: list[str]) -> None:
    _refused_without_running(repo, run_in(args, repo, timeout=300), "reconstruct@s'")


@pytest.mark.parametrize("target, stage", [(f"stylize@{EXPERIMENT}", "stylize@e'"),
                                           (f"reconstruct@{SCENE}", "reconstruct@s'")], ids=["experiment", "scene"])
def test_a_cluster_jobs_dvc_repro_runs_no_command(repo: Path, target: str, stage: str) -> None:
    """The command a cluster job runs: ``dvc repro`` through :mod:`abcgs.cluster.dvc_run`, in the job's clone."""
    from abcgs.cluster.run import dvc_env, repro

    lines: list[str] = []
    rc, _ = repro(repo, ["-s", target], keep_run_cache=True, on_line=lambda line, _: lines.append(line),
                  env=dvc_env(repo))
    _refused_without_running(repo, subprocess.CompletedProcess([], rc, "".join(lines), ""), stage)


# ------------------------------------------------------------------------------------------------ the key
SPEC = StageSpec("stylize", params=("experiments.{key}",), foreach="experiments")
RAW = {"experiments": {"tiny_single": {"scene": "tiny", "colormatch": "m"}}}


def test_the_key_comes_from_the_option_else_from_dvc_stage() -> None:
    assert stage_key(SPEC, "given", {DVC_STAGE_ENV: "stylize@other"}) == "given"
    assert stage_key(SPEC, None, {DVC_STAGE_ENV: "stylize@tiny_single"}) == "tiny_single"
    assert stage_key(SPEC, None, {DVC_STAGE_ENV: "../dvc.yaml:stylize@tiny_single"}) == "tiny_single"
    assert stage_key(SPEC, None, {DVC_STAGE_ENV: "preflight"}) is None
    assert stage_key(SPEC, None, {}) is None
    with pytest.raises(AbcgsError, match=r"names stage 'evaluate'.*--experiment"):
        stage_key(SPEC, None, {DVC_STAGE_ENV: "evaluate@tiny_single"})


def test_path_arguments_get_the_key_and_item_fields() -> None:
    spec = StageSpec("colormatch", foreach="colormatches")
    raw = {"colormatches": {"m": {"scene": "tiny"}}}
    args = argparse.Namespace(out=Path("out/{item.scene}/colormatch/{key}"), root=Path("out"), params=Path("p.yaml"))
    fill_paths(args, spec, raw, "m")
    assert args.out == Path("out/tiny/colormatch/m") and args.root == Path("out")
    with pytest.raises(AbcgsError, match="a name must match"):
        fill_paths(argparse.Namespace(out=Path("out/{key}")), StageSpec("export"), {}, "../../etc")
    with pytest.raises(AbcgsError, match="no key is given"):
        fill_paths(argparse.Namespace(out=Path("out/{key}")), StageSpec("export"), {}, None)
