"""Arguments of ``python -m abcgs.cluster`` that could rewrite a job: paths written into sbatch scripts, the overlay
and its ``--data`` folder, ``--set`` values. Each bad one is a one-line message naming the argument; none is pasted
into a script or into YAML text. (Pure functions and the CLI up to its first Slurm call: no Slurm needed.)"""

from __future__ import annotations

import os
import shlex
from pathlib import Path

import pytest
import yaml

from abcgs.cluster.__main__ import main
from abcgs.cluster.plan import PlanError, Resources, apply_sets, load_resources, make_plan
from abcgs.cluster.slurm import SlurmError, check_reachable, render_script, script_path
from abcgs.errors import ParamsError
from abcgs.overlay import read_overlay

ROOT = Path(__file__).resolve().parents[1]


def _plan():
    return make_plan(yaml.safe_load((ROOT / "dvc.yaml").read_text()), yaml.safe_load((ROOT / "params.yaml").read_text()))


@pytest.mark.parametrize("bad", ["\n", "\r", "\x00", "\x1b"])
def test_a_control_character_in_any_script_path_is_refused(tmp_path: Path, bad: str) -> None:
    plan = _plan()
    arr = plan.array("prep")
    evil = f"x{bad}touch /tmp/owned"
    with pytest.raises(SlurmError, match="run folder.*control character"):
        render_script(plan, arr, Resources(), tmp_path / evil, "abc", "/cache", "/venv/bin/python")
    with pytest.raises(SlurmError, match="DVC cache.*control character"):
        render_script(plan, arr, Resources(), tmp_path / "run", "abc", f"/cache/{evil}", "/venv/bin/python")
    with pytest.raises(SlurmError, match="Python interpreter.*control character"):
        render_script(plan, arr, Resources(), tmp_path / "run", "abc", "/cache", f"/venv{evil}/bin/python")
    with pytest.raises(SlurmError, match="--resources"):
        render_script(plan, arr, Resources(extra=(f"--comment={evil}",)), tmp_path / "run", "abc", "/cache", "/py")


def test_paths_are_quoted_for_the_shell_and_kept_out_of_sbatch_lines_they_would_break(tmp_path: Path) -> None:
    plan = _plan()
    cache = "/shared/my cache; touch x"
    text = render_script(plan, plan.array("prep"), Resources(), tmp_path / "run", "abc", cache, "/venv/bin/python")
    assert f"cache {shlex.quote(cache)}." in text
    for odd in (" ", "#", "%", '"', "\\"):
        with pytest.raises(SlurmError, match="#SBATCH lines"):
            render_script(plan, plan.array("prep"), Resources(), tmp_path / f"r{odd}un", "abc", "/c", "/py")
    assert script_path("/plain/path", "--cache", directive=True) == "/plain/path"


@pytest.mark.parametrize("option", ["--run-dir", "--cache", "--cluster-dir"])
def test_submit_refuses_a_newline_in_a_path_argument_before_any_work(tmp_path: Path, option: str, capsys) -> None:
    paths = {"--run-dir": str(tmp_path / "run"), "--cache": str(tmp_path / "cache")}
    if option == "--cluster-dir":
        args = ["--cluster-dir", f"{tmp_path}/c\nrm -rf ~"]
    else:
        paths[option] = f"{paths[option]}\nrm -rf ~"
        args = [a for k, v in paths.items() for a in (k, v)]
    assert main(["submit", *args, "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert f"error: {option}" in err and "control character" in err and len(err.strip().splitlines()) == 1
    assert not any(tmp_path.iterdir())  # nothing written


def test_without_a_reachable_slurm_submit_names_the_local_cluster_script_and_writes_nothing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    """abcgs sets no Slurm up: with no Slurm commands, or a controller that does not answer, it says how to get one."""
    path = os.environ["PATH"]
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    with pytest.raises(SlurmError, match=r"sinfo not found.*python -m eval\.slurm_local install"):
        check_reachable()
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "sinfo").write_text("#!/bin/sh\necho 'sinfo: error: Unable to contact slurm controller' >&2\nexit 1\n")
    (fake / "sinfo").chmod(0o755)
    monkeypatch.setenv("PATH", f"{fake}{os.pathsep}{path}")
    run = tmp_path / "run"
    assert main(["submit", "--run-dir", str(run), "--cache", str(tmp_path / "cache")]) == 2
    err = capsys.readouterr().err
    assert "no Slurm controller answers `sinfo` (sinfo: error: Unable to contact slurm controller)" in err
    assert "python -m eval.slurm_local start DIR" in err and not run.exists()


def test_the_data_folder_goes_into_the_parsed_overlay_not_its_text(tmp_path: Path) -> None:
    overlay = tmp_path / "o.yaml"
    overlay.write_text("# ${shared} in a comment is no value\ndata:\n  scenes:\n    fern:\n      path: ${shared}/fern\n"
                       "  styles:\n    s: ${shared}/s.jpg\n")
    for name in ("x #y", "a: b", "n\nl", "q'\"uote", "{flow}"):
        shared = tmp_path / name
        shared.mkdir()
        doc = read_overlay(overlay, shared, "--data", "--params")
        assert doc == {"data": {"scenes": {"fern": {"path": f"{shared.resolve()}/fern"}},
                                "styles": {"s": f"{shared.resolve()}/s.jpg"}}}, name
    plain = tmp_path / "plain.yaml"
    plain.write_text("stylize: {optim: {iterations: 3}}\n")
    assert read_overlay(plain, None) == {"stylize": {"optim": {"iterations": 3}}}  # no ${shared}: no folder needed


@pytest.mark.parametrize("text, match", [("data: [unclosed", "not a YAML params overlay"), ("- a\n- b\n", "a mapping"),
                                         ("x: !!python/object:os.system {}\n", "not a YAML"),
                                         ("data:\n  a: ${shared}/x\n", "pass --data FOLDER")])
def test_a_bad_overlay_names_the_argument(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "o.yaml"
    path.write_text(text)
    with pytest.raises(ParamsError, match=match) as exc:
        read_overlay(path, None, "--data", "--params")
    assert str(exc.value).startswith("--params") and "\n" not in str(exc.value)
    with pytest.raises(ParamsError, match="--params .* cannot be read"):
        read_overlay(tmp_path / "missing.yaml", None, "--data", "--params")


def test_a_bad_set_or_resources_file_names_the_argument(tmp_path: Path) -> None:
    for item, match in (("x=!!python/object/apply:os.system [id]", "not plain YAML"), ("a=[1", "not plain YAML"),
                        ("stylize.optim.iterations.x=1", "not a mapping")):
        with pytest.raises(PlanError, match=rf"--set .*{match}"):
            apply_sets({"stylize": {"optim": {"iterations": 3}}}, [item])
    for text, match in (("[1, 2]", "a mapping"), ("defaults: [", "not YAML"), ("defaults: 3", "a mapping")):
        (tmp_path / "r.yaml").write_text(text)
        with pytest.raises(PlanError, match=rf"--resources .*{match}"):
            load_resources(tmp_path / "r.yaml")
    with pytest.raises(PlanError, match="--resources .*cannot be read"):
        load_resources(tmp_path / "none.yaml")


def test_a_bad_rev_names_the_argument(capsys) -> None:
    assert main(["plan", "--rev", "--upload-pack=touch x"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --rev '--upload-pack=touch x' is not a commit") and len(err.strip().splitlines()) == 1


def test_an_untested_dvc_is_refused_by_submit_collect_and_the_jobs_dvc(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    """dvc_run.py replaces private DVC functions: a DVC outside DVC_TESTED stops before anything runs."""
    from abcgs.cluster import dvc_run
    from abcgs.cluster.run import DvcVersionError, check_dvc_version

    check_dvc_version()  # the DVC installed here is a tested one
    monkeypatch.setattr(dvc_run, "installed_dvc_version", lambda: "3.71.2")
    with pytest.raises(DvcVersionError, match=r"^abcgs.cluster was tested with DVC 3\.67; this is 3\.71\.2: "):
        check_dvc_version()
    for argv in (["submit", "--dry-run"], ["collect", "/nonexistent/run"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: abcgs.cluster was tested with DVC 3.67; this is 3.71.2:"), err
        assert "pip install 'dvc>=3.67,<3.68'" in err
    assert dvc_run.main(["repro", "--dry"]) == 2
    assert "tested with DVC 3.67; this is 3.71.2" in capsys.readouterr().err
    assert dvc_run.dvc_version_problem("3.66.9") and dvc_run.dvc_version_problem("4.0.0")
    assert dvc_run.dvc_version_problem("3.67.0") is None and dvc_run.dvc_version_problem("3.67.5rc1") is None


def test_only_the_cluster_extra_pins_dvc_to_the_tested_versions() -> None:
    import tomllib

    from abcgs.cluster.dvc_run import DVC_TESTED

    (a, b), (c, d) = DVC_TESTED
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert f"dvc>={a}.{b},<{c}.{d}" in project["optional-dependencies"]["cluster"]
    core = [r for r in project["dependencies"] if r.startswith("dvc")]
    assert core and not any("<" in r for r in core), f"the core package pins DVC's private-API range: {core}"
