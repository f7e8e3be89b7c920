"""The cached DAG cannot lie: every stage's deps in dvc.yaml cover the code it runs, and its params are the ones it reads.

- Code: :func:`abcgs.dag.import_closure` of each stage script (every project module it imports, at any depth,
  with the C++ kernel sources and the viewer bundle) must be covered by the stage's ``deps``; a code dep that covers
  nothing it runs would re-run the stage for nothing and fails too.
- Params: each script's :class:`abcgs.pipeline.StageSpec` lists the keys it reads, and :func:`abcgs.pipeline.run_stage`
  hands it a view in which nothing else can be read (tested below); dvc.yaml's ``params:`` must be that list.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest
import yaml

from abcgs.dag import import_closure, missing_deps, unused_code_deps
from abcgs.params import load_params
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
    spec = importlib.util.spec_from_file_location(f"stage_{script.stem}", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.SPEC


@pytest.mark.parametrize("name", sorted(DVC))
def test_stage_deps_cover_the_code_it_runs(name: str) -> None:
    stage = DVC[name]
    closure = import_closure(_script(stage), ROOT)
    assert closure, "empty import closure"
    missing = missing_deps(closure, _deps(stage))
    assert not missing, (f"dvc.yaml stage {name!r} runs code its deps do not list: {[str(m) for m in missing]} "
                         f"(`python -m abcgs.dag {_script(stage).relative_to(ROOT)}` prints the deps it needs)")
    unused = unused_code_deps(closure, _deps(stage))
    assert not unused, f"dvc.yaml stage {name!r} lists code deps it never runs: {unused}"


@pytest.mark.parametrize("name", sorted(DVC))
def test_stage_params_are_the_params_it_reads(name: str) -> None:
    stage = DVC[name]
    spec = _spec(_script(stage))
    declared = [p.replace("{", "${") for p in spec.params]
    tracked = [p for p in _body(stage).get("params", []) if isinstance(p, str)]
    assert sorted(tracked) == sorted(declared), (
        f"dvc.yaml stage {name!r} tracks params {tracked} but {_script(stage).relative_to(ROOT)} declares {declared}")
    foreach = {"${data.scenes}": "data.scenes", "${colormatches}": "colormatches", "${experiments}": "experiments"}
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
    closure = import_closure(_script(stage), ROOT)
    assert "abcgs/fit" in deps and not missing_deps(closure, deps)
    narrowed = [d for d in deps if d != "abcgs/fit"] + ["abcgs/fit/losses.py"]
    assert Path("abcgs/fit/trainer.py") in missing_deps(closure, narrowed)


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
