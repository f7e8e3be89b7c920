"""The code each pipeline stage runs, for checking ``dvc.yaml``'s code dependencies.

:func:`import_closure` follows a stage script's imports through the project's own modules (``abcgs``; every
``import`` statement anywhere in a module, including the ones inside functions), adds each imported package's
``__init__.py`` (Python runs it first), and the non-Python files the code loads at run time
(:data:`DATA_FILES`: the C++ kernels' sources, the viewer bundle). :func:`missing_deps` compares it with the deps a
stage declares. ``tests/test_dag.py`` runs both on every stage of ``dvc.yaml``; ``python -m abcgs.dag`` prints
each stage's closure as the shortest list of ``deps`` entries that covers it.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterable
from pathlib import Path

PACKAGE = "abcgs"
DATA_FILES: dict[str, tuple[str, ...]] = {
    "abcgs/render/cpu.py": ("abcgs/render/csrc",),  # compiled into the extension this module loads
    "abcgs/view/page.py": ("abcgs/view/static",),  # the splat viewer bundle inlined into pages
}
"""Module → folders of files it loads at run time (their contents determine its results)."""


def _module_file(root: Path, dotted: str) -> Path | None:
    base = root.joinpath(*dotted.split("."))
    for cand in (base.with_suffix(".py"), base / "__init__.py"):
        if cand.is_file():
            return cand
    return None


def _is_type_checking(node: ast.AST) -> bool:
    """``if TYPE_CHECKING:`` / ``if typing.TYPE_CHECKING:``: its body is read by type checkers only, never run."""
    if not isinstance(node, ast.If):
        return False
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _run_nodes(tree: ast.AST) -> Iterable[ast.AST]:
    """Every node of ``tree`` but the bodies of ``if TYPE_CHECKING:`` blocks (their ``else`` branches run)."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        if _is_type_checking(node):
            todo.extend(node.orelse)
            continue
        todo.extend(ast.iter_child_nodes(node))


def _imported_modules(tree: ast.AST, current: str | None) -> Iterable[str]:
    """Dotted names a module's import statements may load (``from a import b``: ``a`` and ``a.b``); imports under
    ``if TYPE_CHECKING:`` load nothing when the code runs and are left out."""
    for node in _run_nodes(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level and current:
                parent = current.split(".")[: -node.level]
                base = ".".join(parent + ([base] if base else []))
            yield base
            for alias in node.names:
                yield f"{base}.{alias.name}"
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) == "import_module"
              and node.args and isinstance(node.args[0], ast.JoinedStr) and current):
            # import_module(f"abcgs.pkg.{name}"): any module of that package
            yield f"{current.rsplit('.', 1)[0]}.*" if current.count(".") else f"{current}.*"


def import_closure(script: Path, root: Path) -> set[Path]:
    """Project files (relative to ``root``) that running ``script`` imports or loads, ``script`` included."""
    root = root.resolve()
    seen: set[Path] = set()
    todo: list[tuple[Path, str | None]] = [(script.resolve(), None)]
    while todo:
        path, dotted = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for name in _imported_modules(ast.parse(path.read_text(encoding="utf-8")), dotted):
            if name.split(".")[0] != PACKAGE:
                continue
            if name.endswith(".*"):
                pkg = root.joinpath(*name[:-2].split("."))
                todo += [(f, f"{name[:-2]}.{f.stem}") for f in sorted(pkg.glob("*.py"))]
                continue
            parts = name.split(".")
            for i in range(1, len(parts) + 1):  # each parent package's __init__, then the module itself
                prefix = ".".join(parts[:i])
                f = _module_file(root, prefix)
                if f is not None:
                    todo.append((f.resolve(), prefix if f.name != "__init__.py" else f"{prefix}.__init__"))
    files = {p.relative_to(root) for p in seen}
    for module, folders in DATA_FILES.items():
        if Path(module) in files:
            for folder in folders:
                files |= {p.relative_to(root) for p in (root / folder).rglob("*") if p.is_file()}
    return files


def covered(file: Path, deps: Iterable[str]) -> bool:
    """Whether ``file`` is one of ``deps`` or lies under one of them (a folder dep)."""
    parts = file.parts
    return any(parts[: len(Path(d).parts)] == Path(d).parts for d in deps)


def missing_deps(closure: Iterable[Path], deps: Iterable[str]) -> list[Path]:
    """Files of ``closure`` that no entry of ``deps`` covers."""
    deps = list(deps)
    return sorted(f for f in closure if not covered(f, deps))


def unused_code_deps(closure: Iterable[Path], deps: Iterable[str], code_roots: tuple[str, ...] = ("abcgs", "stages")) -> list[str]:
    """Code deps (under ``code_roots``) that cover no file of ``closure``: a stage would re-run for nothing."""
    closure = list(closure)
    return [d for d in deps if Path(d).parts[:1] and Path(d).parts[0] in code_roots
            and not any(covered(f, [d]) for f in closure)]


def minimal_deps(closure: set[Path], root: Path) -> list[str]:
    """The closure as few ``deps`` entries as possible: a folder where every file under it is in the closure."""
    root = root.resolve()
    out: list[str] = []

    def whole(folder: Path) -> bool:
        files = [p.relative_to(root) for p in (root / folder).rglob("*") if p.is_file() and "__pycache__" not in p.parts
                 and p.suffix not in (".so", ".pyc") and not p.name.startswith("_kernels")]
        return bool(files) and all(f in closure for f in files)

    for f in sorted(closure):
        if covered(f, out):
            continue
        best = f
        for parent in f.parents:
            if parent == Path(".") or not whole(parent):
                break
            best = parent
        out.append(best.as_posix())
    return sorted(set(out))


def main(argv: list[str] | None = None) -> int:
    """Print each stage script's closure as ``deps`` entries (``python -m abcgs.dag [stages/*.py]``)."""
    root = Path.cwd()
    scripts = [Path(a) for a in (argv if argv is not None else sys.argv[1:])] or sorted(Path("stages").glob("*.py"))
    for script in scripts:
        print(f"{script}:")
        for dep in minimal_deps(import_closure(script, root), root):
            print(f"  - {dep}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
