"""The cached DAG cannot lie: every stage's deps in dvc.yaml cover the code it runs and the data it is given, and its
params are the ones it reads; dvc.yaml is what ``python -m abcgs.dag --write`` makes of the stage specs.

- Current: the committed dvc.yaml equals the generated one.
- Data: a stage's data deps are exactly the paths its command line passes as inputs (``tests/test_pipeline_e2e.py``
  checks that it reads nothing else under ``out/``).
- No excess: no file a stage's code deps cover lies outside its closure (a file that cannot change its output);
  a package is one dep where the stage runs every file of it.
- Code: :func:`abcgs.dag.import_closure` of each stage script (every project module it imports, at any depth,
  with the C++ kernel sources and the viewer bundle) must be covered by the stage's ``deps``; a code dep that covers
  nothing it runs would re-run the stage for nothing and fails too.
- Params: each script's :class:`abcgs.pipeline.StageSpec` lists the keys it reads, and :func:`abcgs.pipeline.run_stage`
  hands it a view in which nothing else can be read (tested below); dvc.yaml's ``params:`` must be that list.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
import yaml

from abcgs.dag import (
    excess_deps,
    import_closure,
    load_spec,
    load_stage,
    minimal_deps,
    missing_deps,
    pipeline_yaml,
    stage_closure,
    unused_code_deps,
)
from abcgs.dag import main as dag_main
from abcgs.errors import ParamsError
from abcgs.layout import report_inputs
from abcgs.params import load_params, validate_params
from abcgs.pipeline import StageSpec, UntrackedParamsError, tracked_view

ROOT = Path(__file__).resolve().parents[1]
DVC = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]


def _body(stage: dict) -> dict:
    return stage.get("do", stage)


def _script(stage: dict) -> Path:
    m = re.search(r"python (stages/\w+\.py)", _body(stage)["cmd"])
    assert m, f"stage command does not run a stages/ script: {_body(stage)['cmd']}"
    return ROOT / m.group(1)


def _deps(stage: dict) -> list[str]:
    return [d for d in _body(stage).get("deps", []) if isinstance(d, str)]


def _spec(script: Path) -> StageSpec:
    return load_spec(script)


def test_dvc_yaml_is_what_the_stage_specs_make() -> None:
    assert (ROOT / "dvc.yaml").read_text(encoding="utf-8") == pipeline_yaml(ROOT), (
        "dvc.yaml is not current: run `python -m abcgs.dag --write` and commit it")


def _command_paths(cmd: str) -> dict[str, str]:
    """``--option 'path'`` pairs of a stage command, with ``{x}`` written as dvc.yaml's ``${x}``."""
    return {m.group(1): m.group(2).replace("{", "${") for m in re.finditer(r"--([\w-]+) '([^']*)'", cmd)}


@pytest.mark.parametrize("name", sorted(DVC))
def test_stage_data_deps_are_the_inputs_its_command_passes(name: str) -> None:
    body = _body(DVC[name])
    spec = _spec(_script(DVC[name]))
    passed = _command_paths(body["cmd"])
    data_deps = [d for d in _deps(DVC[name]) if not d.startswith(("abcgs/", "stages/"))]
    inputs = [passed[d.option] for d in spec.inputs]
    if name == "report":  # the outputs it reads for each experiment, named from the params (its reads())
        inputs += load_stage(_script(DVC[name])).reads(load_params(ROOT / "params.yaml"))
    assert sorted(data_deps) == sorted(inputs), f"{name}: deps {data_deps} but its command passes inputs {inputs}"
    outs = [next(iter(o)) if isinstance(o, dict) else o
            for k in ("outs", "metrics", "plots") for o in body.get(k, [])]
    for o in spec.outs:
        if o.option and o.kind != "folder":
            assert passed[o.option] in outs, f"{name}: --{o.option} {passed[o.option]} is not among its outputs {outs}"
        elif o.option:  # a folder whose files are listed one by one
            assert any(p.startswith(passed[o.option] + "/") for p in outs), f"{name}: nothing listed under --{o.option}"
    assert set(passed) == {o.option for o in spec.options} | ({"params"} if name == "preflight" else set())


@pytest.mark.parametrize("name", sorted(DVC))
def test_stage_deps_cover_the_code_it_runs(name: str) -> None:
    stage = DVC[name]
    closure = stage_closure(_script(stage), _spec(_script(stage)), ROOT)
    assert closure, "empty import closure"
    missing = missing_deps(closure, _deps(stage))
    assert not missing, (f"dvc.yaml stage {name!r} runs code its deps do not list: {[str(m) for m in missing]} "
                         f"(`python -m abcgs.dag {_script(stage).relative_to(ROOT)}` prints the deps it needs)")
    unused = unused_code_deps(closure, _deps(stage))
    assert not unused, f"dvc.yaml stage {name!r} lists code deps it never runs: {unused}"


@pytest.mark.parametrize("name", sorted(DVC))
def test_no_stage_depends_on_a_file_that_cannot_change_its_output(name: str) -> None:
    stage = DVC[name]
    closure = stage_closure(_script(stage), _spec(_script(stage)), ROOT)
    excess = excess_deps(closure, _deps(stage), ROOT)
    assert not excess, f"dvc.yaml stage {name!r} depends on files it never runs: {[str(f) for f in excess]}"


def test_a_package_is_one_dep_where_the_whole_package_runs(tmp_path: Path) -> None:
    pkg = tmp_path / "abcgs"
    (pkg / "whole").mkdir(parents=True)
    (pkg / "part").mkdir()
    for f in ("__init__.py", "whole/__init__.py", "whole/a.py", "part/__init__.py", "part/a.py", "part/b.py"):
        (pkg / f).write_text("")
    (tmp_path / "stage.py").write_text("from abcgs.whole import a\nfrom abcgs.part import a as b\n")
    closure = import_closure(tmp_path / "stage.py", tmp_path)
    deps = minimal_deps(closure, tmp_path)
    assert deps == ["abcgs/__init__.py", "abcgs/part/__init__.py", "abcgs/part/a.py", "abcgs/whole", "stage.py"]
    assert excess_deps(closure, deps, tmp_path, code_roots=("abcgs",)) == []
    assert excess_deps(closure, ["abcgs/part"], tmp_path, code_roots=("abcgs",)) == [Path("abcgs/part/b.py")]


def test_dvc_yaml_is_short_enough_to_read() -> None:
    lines = (ROOT / "dvc.yaml").read_text(encoding="utf-8").count("\n")
    assert lines <= 300, f"dvc.yaml has {lines} lines"


@pytest.mark.parametrize("name", sorted(DVC))
def test_stage_params_are_the_params_it_reads(name: str) -> None:
    stage = DVC[name]
    spec = _spec(_script(stage))
    declared = [p.replace("{", "${") for p in spec.params]
    tracked = [p for p in _body(stage).get("params", []) if isinstance(p, str)]
    assert sorted(tracked) == sorted(declared), (
        f"dvc.yaml stage {name!r} tracks params {tracked} but {_script(stage).relative_to(ROOT)} declares {declared}")
    foreach = {"${data.scenes}": "data.scenes", "${data.styles}": "data.styles",
               "${data.style_masks}": "data.style_masks", "${colormatches}": "colormatches", "${experiments}": "experiments"}
    if spec.foreach:  # a script that takes no key (export: a PLY path) may serve several foreach stages
        assert spec.foreach == foreach.get(stage.get("foreach")), f"{name}: StageSpec.foreach does not match dvc.yaml"


def test_the_closure_follows_imports_inside_functions_and_package_inits(tmp_path: Path) -> None:
    pkg = tmp_path / "abcgs"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from abcgs.sub import c\n")
    (pkg / "sub" / "a.py").write_text("def f():\n    from abcgs.sub.b import g\n")
    (pkg / "sub" / "b.py").write_text("import os\ng = 1\n")
    (pkg / "sub" / "c.py").write_text("")
    (pkg / "unused.py").write_text("")
    script = tmp_path / "stage.py"
    script.write_text("from abcgs.sub import a\n")
    got = {p.as_posix() for p in import_closure(script, tmp_path)}
    assert got == {"stage.py", "abcgs/__init__.py", "abcgs/sub/__init__.py", "abcgs/sub/a.py", "abcgs/sub/b.py",
                   "abcgs/sub/c.py"}
    assert missing_deps(import_closure(script, tmp_path), ["stage.py", "abcgs/sub"]) == [Path("abcgs/__init__.py")]


def test_a_registry_makes_every_module_of_the_package_it_names_a_dep(tmp_path: Path) -> None:
    """``Registry(kind, type, "abcgs.pkg", ...)`` (abcgs.plugins) imports each module of ``abcgs.pkg`` by name when it
    discovers the formats: all of them are code the stage runs, none of the registry's own package's siblings."""
    pkg = tmp_path / "abcgs"
    (pkg / "formats").mkdir(parents=True)
    for rel in ("__init__.py", "plugins.py", "unrelated.py", "formats/__init__.py", "formats/one.py", "formats/two.py"):
        (pkg / rel).write_text("")
    (pkg / "registry.py").write_text('from abcgs.plugins import Registry\nR = Registry("format", object, '
                                     '"abcgs.formats", "FORMAT", order=str)\n')
    script = tmp_path / "stage.py"
    script.write_text("from abcgs import registry\n")
    got = {p.as_posix() for p in import_closure(script, tmp_path)}
    assert got == {"stage.py", "abcgs/__init__.py", "abcgs/plugins.py", "abcgs/registry.py", "abcgs/formats/__init__.py",
                   "abcgs/formats/one.py", "abcgs/formats/two.py"}


def test_imports_under_type_checking_are_not_run_but_their_else_branch_is(tmp_path: Path) -> None:
    pkg = tmp_path / "abcgs"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    for name in ("heavy", "light", "fallback"):
        (pkg / f"{name}.py").write_text("")
    script = tmp_path / "stage.py"
    script.write_text("import typing\nfrom typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from abcgs import heavy\n"
                      "if typing.TYPE_CHECKING:\n    import abcgs.heavy\nelse:\n    from abcgs import fallback\n"
                      "from abcgs import light\n")
    got = {p.as_posix() for p in import_closure(script, tmp_path)}
    assert got == {"stage.py", "abcgs/__init__.py", "abcgs/light.py", "abcgs/fallback.py"}


def test_removing_one_imported_file_from_a_stage_deps_is_caught() -> None:
    stage = DVC["fit"]
    deps = _deps(stage)
    closure = stage_closure(_script(stage), _spec(_script(stage)), ROOT)
    assert "abcgs/fit" in deps and not missing_deps(closure, deps)
    narrowed = [d for d in deps if d != "abcgs/fit"] + ["abcgs/fit/losses.py"]
    assert Path("abcgs/fit/training.py") in missing_deps(closure, narrowed)


def test_a_stage_cannot_read_params_it_does_not_track() -> None:
    params = load_params(ROOT / "params.yaml")
    view = tracked_view(params, ["fit", "data.scenes.tiny"], "fit")
    assert view.fit.iterations == params.fit.iterations
    assert view.data.scenes["tiny"].path == params.data.scenes["tiny"].path
    assert view.scene_section("tiny", "fit") == params.fit
    with pytest.raises(UntrackedParamsError, match="stylize"):
        _ = view.stylize.optim.iterations
    with pytest.raises(UntrackedParamsError, match="data.styles"):
        _ = view.data.styles["tiny_paint"]
    partial = tracked_view(params, ["evaluate.flow", "experiments.tiny_single"], "x")
    assert partial.evaluate.flow == params.evaluate.flow
    with pytest.raises(UntrackedParamsError, match="evaluate.fid_patch_size"):
        _ = partial.evaluate.fid_patch_size
    with pytest.raises(UntrackedParamsError, match="experiments.tiny_semantic"):
        _ = partial.experiments["tiny_semantic"]
    with pytest.raises(UntrackedParamsError):
        list(partial.experiments)


@pytest.mark.parametrize("section", ["viewer"])
def test_a_settings_module_is_a_dep_only_of_the_stages_that_read_its_section(section: str) -> None:
    """Editing ``abcgs/view/params.py`` (say, a help text) leaves every stage up to date but those that read
    ``viewer`` (and the preflight stage, which validates the whole file)."""
    from abcgs.dag import covered
    from abcgs.sections import SECTIONS

    module = SECTIONS[section].file()
    depending = {name for name, stage in DVC.items() if covered(Path(module), _deps(stage))}
    reading = {name for name, stage in DVC.items() if section in _spec(_script(stage)).sections}
    assert depending - reading == {"preflight"}, f"stages that depend on {module} without reading {section}"


def test_an_imported_modules_main_block_is_not_run_but_the_scripts_is(tmp_path: Path) -> None:
    pkg = tmp_path / "abcgs"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "cli.py").write_text("if __name__ == '__main__':\n    from abcgs import heavy\n")
    for name in ("heavy", "tool"):
        (pkg / f"{name}.py").write_text("")
    script = tmp_path / "stage.py"
    script.write_text("from abcgs import cli\nif __name__ == '__main__':\n    from abcgs import tool\n")
    got = {p.as_posix() for p in import_closure(script, tmp_path)}
    assert got == {"stage.py", "abcgs/__init__.py", "abcgs/cli.py", "abcgs/tool.py"}


def test_a_paintings_content_is_a_dep_of_every_stage_that_reads_it() -> None:
    """The params hold a painting's path, which DVC tracks as text: the ``styles`` / ``style_masks`` stages depend on
    the files themselves and copy them under out/styles, and the stages that read paintings depend on that folder, so
    replacing a painting at the same path re-runs them."""
    for name, section in (("styles", "data.styles"), ("style_masks", "data.style_masks")):
        assert DVC[name]["foreach"] == "${" + section + "}"
        assert "${item}" in _deps(DVC[name])
        assert _body(DVC[name])["outs"] == [f"out/styles/${{key}}{'.png' if name == 'styles' else '.labels.png'}"]
    for name in ("colormatch", "stylize", "evaluate"):
        assert "out/styles" in _deps(DVC[name]), f"{name} reads paintings but does not depend on out/styles"
    assert {"out/styles/tiny_paint.png", "out/styles/tiny_paint2.png"} <= set(_deps(DVC["report"]))


def test_the_report_names_the_outputs_it_reads() -> None:
    """The report depends on each experiment's records, renders and scene outputs by name, not on all of out/: a
    stage's output that it does not read (a scene's export) cannot re-run it."""
    stage = DVC["report"]
    deps = stage["deps"]
    assert "out" not in deps and "--root" not in stage["cmd"]
    params = load_params(ROOT / "params.yaml")
    assert params.experiments
    for name, exp in params.experiments.items():
        for path in (f"out/{name}/stylize.json", f"out/{name}/eval.json", f"out/{name}/eval_consistency.png",
                     f"out/{name}/stylize"):
            assert path in deps, path
        for path in (f"out/{exp.scene}/colmap", f"out/{exp.scene}/gs/point_cloud.ply", f"out/{exp.scene}/masks",
                     f"out/{exp.scene}/reconstruct.json"):
            assert path in deps, path
    assert not any(d.endswith(".spz") or d.startswith(f"out/{s}/gs/history") for d in deps for s in params.data.scenes)
    assert {f"out/styles/{k}.png" for k in params.data.styles} <= set(deps)


def test_an_experiment_added_to_the_params_is_refused_until_dvc_yaml_names_its_outputs(tmp_path: Path) -> None:
    """The report's deps come from params.yaml's experiments: with one added and dvc.yaml not regenerated, the
    preflight names the outputs the report would not depend on and the command that fixes it; `abcgs.dag --update`
    (which `make run` runs first) writes them, after which the preflight passes this check."""
    from abcgs.preflight import check_report_inputs

    raw = yaml.safe_load((ROOT / "params.yaml").read_text())
    name, exp = next(iter(raw["experiments"].items()))
    raw["experiments"]["added_exp"] = dict(exp)
    params = validate_params(raw)
    (tmp_path / "dvc.yaml").write_text((ROOT / "dvc.yaml").read_text())
    with pytest.raises(ParamsError, match=r"out/added_exp/stylize\.json.*python -m abcgs\.dag --write"):
        check_report_inputs(params, tmp_path / "dvc.yaml")
    stages = yaml.safe_load((tmp_path / "dvc.yaml").read_text())["stages"]
    stages["report"]["deps"] += [p for p in report_inputs(params) if p not in stages["report"]["deps"]]
    (tmp_path / "dvc.yaml").write_text(yaml.safe_dump({"stages": stages}))
    check_report_inputs(params, tmp_path / "dvc.yaml")
    assert f"out/{name}/stylize.json" in report_inputs(params)


def test_dag_update_writes_dvc_yaml_only_where_it_is_not_current(tmp_path: Path, monkeypatch, capsys) -> None:
    """`python -m abcgs.dag --update` in a copy of the repository: nothing to do on the committed files; with an
    experiment added to params.yaml it rewrites dvc.yaml so that the report depends on the new experiment's outputs;
    invalid params are reported as the preflight reports them, with no traceback and dvc.yaml untouched."""
    for sub in ("abcgs", "stages"):
        shutil.copytree(ROOT / sub, tmp_path / sub, ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    for f in ("params.yaml", "dvc.yaml"):
        shutil.copy(ROOT / f, tmp_path / f)
    monkeypatch.chdir(tmp_path)
    before = (tmp_path / "dvc.yaml").read_text()
    assert dag_main(["--update"]) == 0 and (tmp_path / "dvc.yaml").read_text() == before
    raw = yaml.safe_load((tmp_path / "params.yaml").read_text())
    raw["experiments"]["added_exp"] = dict(next(iter(raw["experiments"].values())))
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    assert dag_main(["--update"]) == 0 and "dvc.yaml updated" in capsys.readouterr().out
    assert "out/added_exp/stylize.json" in yaml.safe_load((tmp_path / "dvc.yaml").read_text())["stages"]["report"]["deps"]
    after = (tmp_path / "dvc.yaml").read_text()
    raw["experiments"]["added_exp"]["colormatch"] = "no_such_match"
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    assert dag_main(["--update"]) == 2
    assert "[dag] error:" in capsys.readouterr().err and (tmp_path / "dvc.yaml").read_text() == after


def test_bytecode_beside_the_sources_changes_no_folder_dep(tmp_path: Path) -> None:
    """Python writes ``__pycache__/*.pyc`` beside each module it imports (its default; not where
    PYTHONDONTWRITEBYTECODE is set). With the project's ``.dvcignore`` DVC leaves them out of a folder dep's hash, so a
    stage that imports a module of ``abcgs/fit`` does not make the stages depending on ``abcgs/fit`` out of date."""
    import subprocess
    import sys

    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "mod.py").write_text("X = 1\n")
    shutil.copy(ROOT / ".dvcignore", tmp_path / ".dvcignore")

    def dvc(*args: str) -> str:
        return subprocess.run([sys.executable, "-m", "dvc", *args], cwd=tmp_path, capture_output=True, text=True,
                              check=True).stdout

    dvc("init", "--no-scm", "-q")
    dvc("stage", "add", "-q", "-n", "s", "-d", "pkg", "-o", "o.txt", "echo done > o.txt")
    dvc("repro", "-q")
    assert "up to date" in dvc("status")
    (tmp_path / "pkg" / "__pycache__").mkdir()
    (tmp_path / "pkg" / "__pycache__" / "mod.cpython-311.pyc").write_bytes(b"\x00bytecode")
    assert "up to date" in dvc("status")
    (tmp_path / "pkg" / "mod.py").write_text("X = 2\n")  # a source change still counts
    assert "modified" in dvc("status")
