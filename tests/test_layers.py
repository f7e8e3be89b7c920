"""The floors of abcgs: a module imports only from its own floor or the floors below it.

Every module under ``abcgs/`` is parsed (not imported) and each of its ``abcgs`` imports, at any depth (inside
functions and ``TYPE_CHECKING`` blocks too), is checked against :data:`eval.bench.structure.FLOORS` (which
``python -m eval run structure`` counts with). A module's command-line block
(``if __name__ == "__main__":``) is a program run on top of everything and is not checked.

No import ring between modules either (:func:`eval.bench.structure.import_rings` of
:func:`~eval.bench.structure.module_graph`): the imports that run count, inside functions too (a lazy import only
defers a ring), not those of ``TYPE_CHECKING`` blocks. A ring is broken by moving what both sides need down.

Also checked: a name is imported from the module that defines it (no re-exports), except from a package's face
(its ``__init__.py``); settings classes thus come from their ``params`` module. And no function or method under
``abcgs/``, ``stages/`` or ``eval/`` spans more than :data:`eval.bench.structure.MAX_FUNCTION_LINES` (80) lines.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from eval.bench.structure import (
    MAX_FUNCTION_LINES,
    MAX_MODULE_LINES,
    floor_of,
    import_rings,
    long_functions,
    long_modules,
    module_graph,
    module_path,
)
from eval.bench.structure import module_name as _module_name
from eval.bench.structure import upward_imports as _upward_imports

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "abcgs"


def module_name(path: Path) -> str:
    return _module_name(path, ROOT)


def _module_path(module: str) -> Path | None:
    return module_path(module, ROOT)


def upward_imports(module: str, source: str, is_package: bool = False) -> list[str]:
    """One line per import of ``source`` (module ``module``) that reaches a higher floor of the floors table."""
    return _upward_imports(module, source, ROOT, is_package)


MODULES = sorted(PACKAGE.rglob("*.py"))


def test_every_module_has_a_floor() -> None:
    missing = [module_name(p) for p in MODULES if floor_of(module_name(p)) is None]
    assert not missing, f"modules on no floor (add them to FLOORS in eval/bench/structure.py): {missing}"


def test_no_module_imports_a_higher_floor() -> None:
    found = []
    for path in MODULES:
        found += upward_imports(module_name(path), path.read_text(encoding="utf-8"), path.name == "__init__.py")
    assert not found, "imports up the floors (move the shared name down, e.g. into abcgs/types.py, or pass values):\n" \
        + "\n".join(found)


@pytest.mark.parametrize(("module", "source", "expected"), [
    ("abcgs.features.knn", "from abcgs.losses.params import FastParams\n",
     ["abcgs.features.knn:1 (scenes and features) imports abcgs.losses.params (losses)"]),
    ("abcgs.features.knn", "from abcgs.sfm.model import read_scene\n", []),  # the same floor
    ("abcgs.camera_paths", "import numpy\n\ndef f():\n    from abcgs.view import page\n",
     ["abcgs.camera_paths:4 (rendering) imports abcgs.view.page (presentation)"]),
    ("abcgs.render.cpu", "from ..stylize import loop\n", ["abcgs.render.cpu:1 (rendering) imports abcgs.stylize.loop (methods)"]),
    ("abcgs.masks.content", "from abcgs.report import load_runs\n",
     ["abcgs.masks.content:1 (methods) imports abcgs.report (presentation)"]),
    ("abcgs.view.outputs", "from abcgs.params import Params\n",
     ["abcgs.view.outputs:1 (presentation) imports abcgs.params (orchestration)"]),
    ("abcgs.camera_paths", "from abcgs.view.params import PathKind\n",
     ["abcgs.camera_paths:1 (rendering) imports abcgs.view.params (presentation)"]),
    ("abcgs.report", "from abcgs.errors import InputError\nif __name__ == '__main__':\n    from abcgs.params import x\n", []),
])
def test_the_check_names_the_importer_and_the_imported(module: str, source: str, expected: list[str]) -> None:
    assert upward_imports(module, source) == expected


# ------------------------------------------------------------------------------------------------ no import ring
def test_no_import_ring_between_modules() -> None:
    graph = module_graph(ROOT)
    rings = import_rings(graph)
    shown = [" ↔ ".join(ring) + ": " + ", ".join(f"{a}:{graph[a][b]} imports {b}" for a in ring for b in ring
                                                  if b in graph[a]) for ring in rings]
    assert not rings, ("import rings between modules (move what both sides need into the lower one, or a module of "
                       "its own):\n" + "\n".join(shown))


def test_the_ring_check_finds_two_and_three_module_rings() -> None:
    graph = {"a": {"b"}, "b": {"a", "c"}, "c": {"d"}, "d": {"e"}, "e": {"c", "f"}, "f": set(), "g": {"g", "a"}}
    assert import_rings(graph) == [["a", "b"], ["c", "d", "e"]]  # g imports itself: no ring
    assert import_rings({"x": {"y"}, "y": {"z"}}) == []


def test_the_ring_graph_counts_lazy_imports_but_not_type_checking_ones(tmp_path: Path) -> None:
    pkg = tmp_path / "abcgs" / "p"
    pkg.mkdir(parents=True)
    (tmp_path / "abcgs" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from abcgs.p.b import B\n")
    (pkg / "b.py").write_text("B = 1\n\n\ndef late():\n    from abcgs.p import a\n")
    (pkg / "c.py").write_text("from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n    from abcgs.p.a import X\n")
    (pkg / "d.py").write_text("from abcgs.p import c\n\nif __name__ == '__main__':\n    from abcgs.p import d\n")
    graph = module_graph(tmp_path)
    assert graph["abcgs.p.a"] == {"abcgs.p.b": 1} and graph["abcgs.p.b"] == {"abcgs.p.a": 5}
    assert graph["abcgs.p.c"] == {} and graph["abcgs.p.d"] == {"abcgs.p.c": 1}
    assert import_rings(graph) == [["abcgs.p.a", "abcgs.p.b"]]


# ------------------------------------------------------------------------------------------------ no re-exports
def _defined_names(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
    return names


def test_names_are_imported_from_the_module_that_defines_them() -> None:
    files = [*MODULES, *sorted((ROOT / "stages").glob("*.py")), *sorted((ROOT / "eval").rglob("*.py")),
             *sorted((ROOT / "tests").glob("*.py"))]
    found = []
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not (isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").startswith("abcgs.")):
                continue
            source = _module_path(node.module)
            if source is None or source.name == "__init__.py":  # a package's face may re-export
                continue
            defined = _defined_names(source)
            found += [f"{path.relative_to(ROOT)}:{node.lineno}: {a.name} from {node.module}, which does not define it"
                      for a in node.names if a.name not in defined and not _module_path(f"{node.module}.{a.name}")]
    assert not found, "import each name from the module that defines it:\n" + "\n".join(found)


def test_only_package_faces_silence_unused_imports() -> None:
    found = [f"{p.relative_to(ROOT)}:{i}" for p in MODULES if p.name != "__init__.py"
             for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if "noqa: F401" in line]
    assert not found, f"an unused import outside a package's __init__.py (a re-export?): {found}"


# ------------------------------------------------------------------------------------------------ function size
def test_no_function_is_longer_than_the_limit() -> None:
    found = long_functions(ROOT)
    assert not found, (f"functions over {MAX_FUNCTION_LINES} lines (split each into functions of one concept):\n"
                       + "\n".join(f"{name}: {n} lines" for name, n in found))


def test_no_module_is_longer_than_the_limit() -> None:
    found = long_modules(ROOT)
    assert not found, (f"modules over {MAX_MODULE_LINES} lines (split each into modules of one concept):\n"
                       + "\n".join(f"{name}: {n} lines" for name, n in found))


def test_the_module_size_check_reads_every_code_folder(tmp_path: Path) -> None:
    for folder, n in (("abcgs", MAX_MODULE_LINES), ("stages", MAX_MODULE_LINES + 1), ("eval/bench", 700),
                      ("tests", 900)):
        (tmp_path / folder).mkdir(parents=True)
        (tmp_path / folder / "m.py").write_text("x = 1\n" * n)
    assert long_modules(tmp_path) == [("eval/bench/m.py", 700), ("stages/m.py", MAX_MODULE_LINES + 1)]  # not tests


def test_the_size_check_counts_def_to_last_line_in_every_code_folder(tmp_path: Path) -> None:
    def body(n: int) -> str:  # a function spanning n lines, its def line included
        return "".join(f"    x{i} = {i}\n" for i in range(n - 1))

    (tmp_path / "abcgs").mkdir()
    (tmp_path / "abcgs" / "a.py").write_text(f"import functools\n\n\n@functools.cache\ndef limit():\n{body(80)}")
    (tmp_path / "stages").mkdir()
    (tmp_path / "stages" / "s.py").write_text(f"def long():\n{body(81)}")
    (tmp_path / "eval" / "bench").mkdir(parents=True)
    method = "".join("    " + line + "\n" for line in f"def run(self):\n{body(85)}".splitlines())
    (tmp_path / "eval" / "bench" / "b.py").write_text(f"class Bench:\n{method}")
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "t.py").write_text(f"def test_long():\n{body(200)}")  # tests are not measured
    assert long_functions(tmp_path) == [("eval/bench/b.py:Bench.run", 85), ("stages/s.py:long", 81)]
