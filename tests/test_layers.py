"""The floors of abcgs: a module imports only from its own floor or the floors below it.

Every module under ``abcgs/`` is parsed (not imported) and each of its ``abcgs`` imports, at any depth (inside
functions and ``TYPE_CHECKING`` blocks too), is checked against :data:`FLOORS`. A module's command-line block
(``if __name__ == "__main__":``) is a program run on top of everything and is not checked.

Also checked: a name is imported from the module that defines it (no re-exports), except from a package's face
(its ``__init__.py``); settings classes thus come from their ``params`` module.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from abcgs.dag import is_main_block

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "abcgs"

FLOORS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("foundations", (
        "abcgs", "abcgs.errors", "abcgs.types", "abcgs.dotted", "abcgs.sections", "abcgs.progress", "abcgs.cameras",
        "abcgs.runtime",
        "abcgs.io", "abcgs.io.atomic", "abcgs.io.digest", "abcgs.io.images", "abcgs.io.metrics", "abcgs.io.tables",
    )),
    ("rendering", ("abcgs.render", "abcgs.gaussians", "abcgs.io.ply", "abcgs.io.spz", "abcgs.viz",
                   "abcgs.camera_paths", "abcgs.silhouette")),
    ("scenes and features", ("abcgs.sfm", "abcgs.scene", "abcgs.layout", "abcgs.features")),
    ("losses", ("abcgs.losses",)),
    ("methods", ("abcgs.fit", "abcgs.splats", "abcgs.sources", "abcgs.masks", "abcgs.stylize", "abcgs.evaluation")),
    ("presentation", ("abcgs.view", "abcgs.report")),
    ("orchestration", ("abcgs.params", "abcgs.preflight", "abcgs.pipeline", "abcgs.dag", "abcgs.overlay",
                       "abcgs.add", "abcgs.cluster", "abcgs.__main__", "abcgs.view.__main__",
                       "abcgs.sources.check")),  # the preflight stage's reading of datasets
)
"""Floors, lowest first, each a name and the modules or packages on it (the longest matching prefix decides). A
package's ``params`` module (its settings' schema) is on the package's floor; the modes it shares with lower floors
live in :mod:`abcgs.types`."""


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def floor_of(module: str) -> int | None:
    """Index in :data:`FLOORS` of ``module`` (the longest matching entry wins), None when no entry matches."""
    best, best_len = None, -1
    for i, (_, entries) in enumerate(FLOORS):
        for entry in entries:
            if (module == entry or module.startswith(entry + ".")) and len(entry) > best_len:
                best, best_len = i, len(entry)
    return best


def abcgs_imports(source: str, module: str, is_package: bool) -> list[tuple[int, str]]:
    """``(line, imported module)`` for every ``abcgs`` import of ``source`` outside its ``__main__`` block
    (``from P import name`` counts as P, or as P.name where that is a module)."""
    tree = ast.parse(source)
    skip = {id(n) for top in tree.body if is_main_block(top) for n in ast.walk(top)}
    out = []
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names if a.name.split(".")[0] == "abcgs"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "abcgs":
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.append((node.lineno, sub if _module_path(sub) else target))
    return sorted(set(out))


def _module_path(module: str) -> Path | None:
    base = ROOT.joinpath(*module.split("."))
    for p in (base.with_suffix(".py"), base / "__init__.py"):
        if p.is_file():
            return p
    return None


def upward_imports(module: str, source: str, is_package: bool = False) -> list[str]:
    """One line per import of ``source`` (module ``module``) that reaches a higher floor."""
    own = floor_of(module)
    out = []
    for line, target in abcgs_imports(source, module, is_package):
        theirs = floor_of(target)
        if own is not None and theirs is not None and theirs > own:
            out.append(f"{module}:{line} ({FLOORS[own][0]}) imports {target} ({FLOORS[theirs][0]})")
    return out


MODULES = sorted(PACKAGE.rglob("*.py"))


def test_every_module_has_a_floor() -> None:
    missing = [module_name(p) for p in MODULES if floor_of(module_name(p)) is None]
    assert not missing, f"modules on no floor (add them to FLOORS in tests/test_layers.py): {missing}"


def test_no_module_imports_a_higher_floor() -> None:
    found = []
    for path in MODULES:
        found += upward_imports(module_name(path), path.read_text(encoding="utf-8"), path.name == "__init__.py")
    assert not found, "imports up the floors (move the shared name down, e.g. into abcgs/types.py, or pass values):\n" \
        + "\n".join(found)


@pytest.mark.parametrize(("module", "source", "expected"), [
    ("abcgs.features.knn", "from abcgs.losses.params import FastParams\n",
     ["abcgs.features.knn:1 (scenes and features) imports abcgs.losses.params (losses)"]),
    ("abcgs.features.knn", "from abcgs.sfm.model import SceneData\n", []),  # the same floor
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
