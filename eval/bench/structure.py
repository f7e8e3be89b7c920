"""Structure numbers of the ``abcgs`` package, read from the source (parsed, never imported).

    python -m eval run structure                         # this tree, printed
    python -m eval run structure --json docs/measurements/structure.json --label now   # stored, with the commit

Measured:

- ``modules``: ``.py`` files under ``abcgs/`` (and their lines).
- ``packages``: the units arrows are counted between: each sub-package of ``abcgs`` (``abcgs.io``, ``abcgs.render``,
  …) and each top-level module (``abcgs.pipeline``); ``abcgs/__init__.py`` is the unit ``abcgs``.
- ``import_arrows``: distinct ordered pairs of units (A, B), A ≠ B, where a module of A imports a module of B
  (at any depth: inside functions and ``TYPE_CHECKING`` blocks too; a module's ``if __name__ == "__main__":`` block
  is a program on top of everything and is left out).
- ``upward_imports``: imports from a module to a module on a higher floor of :data:`FLOORS` (``tests/test_layers.py``
  fails on any); ``upward_imports_by_package``: the same with each module on its unit's floor (no module placed apart
  from its package); ``mutual_pairs``: unit pairs that import each other (an arrow that runs back).
- ``module_rings``: the import rings between modules (``tests/test_layers.py`` fails on any), each the sorted modules
  of one strongly connected component of more than one module of :func:`module_graph` (:func:`import_rings`);
  ``module_ring_count``: how many. An arrow here is an import statement run when the code runs: inside functions
  too (a lazy import still closes a ring, it only defers it), but not in ``TYPE_CHECKING`` blocks (read by type
  checkers only) nor in a module's ``__main__`` block; a module naming itself is no ring. A name looked up at run
  time (``importlib.import_module``, as :class:`abcgs.plugins.Registry` finds the format modules) is no import
  statement and no arrow, as for ``import_arrows``.
- ``side_effect_imports``: lines ``import abcgs  # noqa: F401`` under ``abcgs/``, ``stages/`` and ``eval/`` (an import
  made only for what importing the package does).
- ``dvc_yaml_lines``: lines of the generated ``dvc.yaml``; ``core_pins_dvc_minor``: whether ``pyproject.toml``'s
  core ``dependencies`` cap DVC below its next minor version (the cluster code's private-API range).
- ``longest_functions``: the longest functions and methods of ``abcgs/`` in lines (``def`` to last line).

:func:`long_functions` lists the functions over :data:`MAX_FUNCTION_LINES` under ``abcgs/``, ``stages/`` and
``eval/`` (``tests/test_layers.py`` fails on any).

With ``--json FILE --label NAME`` the numbers are stored under ``NAME`` in ``FILE`` (other labels are kept), with the
tree's git commit; the file's ``provenance`` (:func:`eval.record.provenance`) is that of its last write.
"""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

from abcgs.runtime import setup

setup()  # as every benchmark does first (tests/test_openmp_wait_policy.py); this one loads no torch

# isort: split
from abcgs.dag import is_main_block, is_type_checking_block

FLOORS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("foundations", (
        "abcgs", "abcgs.errors", "abcgs.types", "abcgs.dotted", "abcgs.sections", "abcgs.progress", "abcgs.cameras",
        "abcgs.runtime", "abcgs.plugins",
        "abcgs.io", "abcgs.io.atomic", "abcgs.io.digest", "abcgs.io.images", "abcgs.io.metrics", "abcgs.io.tables",
    )),
    ("rendering", ("abcgs.render", "abcgs.gaussians", "abcgs.viz",
                   "abcgs.camera_paths", "abcgs.silhouette")),
    ("scenes and features", ("abcgs.sfm", "abcgs.scene", "abcgs.layout", "abcgs.features")),
    ("losses", ("abcgs.losses",)),
    ("methods", ("abcgs.fit", "abcgs.splats", "abcgs.sources", "abcgs.masks", "abcgs.stylize", "abcgs.evaluation")),
    ("presentation", ("abcgs.view", "abcgs.report", "abcgs.masks.page")),
    ("orchestration", ("abcgs.params", "abcgs.preflight", "abcgs.pipeline", "abcgs.dag", "abcgs.overlay",
                       "abcgs.add", "abcgs.add_experiment", "abcgs.cluster", "abcgs.source_check", "abcgs.__main__",
                       "abcgs.entry_checks", "abcgs.dvc_file",
                       "abcgs.view.__main__")),
)
"""Floors, lowest first, each a name and the modules or packages on it (the longest matching prefix decides). A
package's ``params`` module (its settings' schema) is on the package's floor; the modes it shares with lower floors
live in :mod:`abcgs.types`. ``tests/test_layers.py`` checks the package against this table."""


def module_name(path: Path, root: Path) -> str:
    """Dotted name of a ``.py`` file under ``root`` (``abcgs/io/__init__.py`` → ``abcgs.io``)."""
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def module_path(module: str, root: Path) -> Path | None:
    """The file of a dotted module under ``root`` (a module file or a package's ``__init__.py``), None if neither."""
    base = root.joinpath(*module.split("."))
    for p in (base.with_suffix(".py"), base / "__init__.py"):
        if p.is_file():
            return p
    return None


def floor_of(module: str, floors: tuple[tuple[str, tuple[str, ...]], ...] = FLOORS) -> int | None:
    """Index in ``floors`` of ``module`` (the longest matching entry wins), None when no entry matches."""
    best, best_len = None, -1
    for i, (_, entries) in enumerate(floors):
        for entry in entries:
            if (module == entry or module.startswith(entry + ".")) and len(entry) > best_len:
                best, best_len = i, len(entry)
    return best


def abcgs_imports(source: str, module: str, is_package: bool, root: Path,
                  type_checking: bool = True) -> list[tuple[int, str]]:
    """``(line, imported module)`` for every ``abcgs`` import of ``source`` (module ``module``) outside its
    ``__main__`` block (and, with ``type_checking=False``, outside the bodies of its ``TYPE_CHECKING`` blocks: the
    imports run); ``from P import name`` counts as ``P.name`` where that is a module, else as ``P``."""
    tree = ast.parse(source)
    skip = {id(n) for top in tree.body if is_main_block(top) for n in ast.walk(top)}
    if not type_checking:
        skip |= {id(n) for block in ast.walk(tree) if is_type_checking_block(block)
                 for stmt in block.body for n in ast.walk(stmt)}
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
                out.append((node.lineno, sub if module_path(sub, root) else target))
    return sorted(set(out))


def upward_imports(module: str, source: str, root: Path, is_package: bool = False,
                   floors: tuple[tuple[str, tuple[str, ...]], ...] = FLOORS) -> list[str]:
    """One line per import of ``source`` (module ``module``) that reaches a higher floor of ``floors``."""
    own = floor_of(module, floors)
    out = []
    for line, target in abcgs_imports(source, module, is_package, root):
        theirs = floor_of(target, floors)
        if own is not None and theirs is not None and theirs > own:
            out.append(f"{module}:{line} ({floors[own][0]}) imports {target} ({floors[theirs][0]})")
    return out


def module_graph(root: Path) -> dict[str, dict[str, int]]:
    """Module → {module it imports: the line of its first such import} for every module under ``root/abcgs``: the
    imports that run (inside functions too; not in ``TYPE_CHECKING`` or ``__main__`` blocks), a module's imports of
    itself left out."""
    graph: dict[str, dict[str, int]] = {}
    for path in sorted(p for p in (root / "abcgs").rglob("*.py") if "__pycache__" not in p.parts):
        module = module_name(path, root)
        edges = graph.setdefault(module, {})
        for line, target in abcgs_imports(path.read_text(encoding="utf-8"), module, path.name == "__init__.py", root,
                                          type_checking=False):
            if target != module:
                edges.setdefault(target, line)
    return graph


def import_rings(graph: Mapping[str, Iterable[str]]) -> list[list[str]]:
    """The import rings of ``graph`` (node → the nodes it imports): each strongly connected component of more than one
    node, its nodes sorted, the rings sorted (Tarjan's algorithm, without recursion)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    rings: list[list[str]] = []

    def enter(node: str) -> tuple[str, Iterator[str]]:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        return node, iter(sorted(graph.get(node, ())))

    for start in sorted(set(graph).union(*graph.values())):
        if start in index:
            continue
        work = [enter(start)]
        while work:
            node, targets = work[-1]
            for target in targets:
                if target not in index:
                    work.append(enter(target))
                    break
                if target in on_stack:
                    low[node] = min(low[node], index[target])
            else:  # every target seen: close the node
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = stack[stack.index(node):]
                    del stack[stack.index(node):]
                    on_stack.difference_update(component)
                    if len(component) > 1:
                        rings.append(sorted(component))
    return sorted(rings)


def unit_of(module: str) -> str:
    """The unit arrows are counted between: ``abcgs.<first part>`` (a sub-package or a top-level module)."""
    parts = module.split(".")
    return ".".join(parts[:2])


def _functions(tree: ast.AST, prefix: str) -> list[tuple[str, int]]:
    out = []
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            out.append((f"{prefix}.{node.name}", node.end_lineno - node.lineno + 1))
            out += _functions(node, f"{prefix}.{node.name}")
        elif isinstance(node, ast.ClassDef):
            out += _functions(node, f"{prefix}.{node.name}")
        elif not isinstance(node, ast.Lambda):
            out += _functions(node, prefix)
    return out


MAX_FUNCTION_LINES = 80
"""The most lines a function or method under :data:`CODE_FOLDERS` may span (``def`` to its last line; decorators not
counted, a nested function's lines counted in the function around it too)."""

CODE_FOLDERS = ("abcgs", "stages", "eval")
"""The folders of the project's code that :func:`long_functions` reads."""


def long_functions(root: Path, limit: int = MAX_FUNCTION_LINES,
                   folders: tuple[str, ...] = CODE_FOLDERS) -> list[tuple[str, int]]:
    """``("path:qualified name", lines)`` of every function and method longer than ``limit`` lines in the ``.py``
    files under ``folders`` of ``root``, longest first."""
    found = []
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            found += [(f"{path.relative_to(root).as_posix()}:{name[1:]}", n)
                      for name, n in _functions(ast.parse(path.read_text(encoding="utf-8")), "") if n > limit]
    return sorted(found, key=lambda f: (-f[1], f[0]))


MAX_MODULE_LINES = 500
"""The most lines a ``.py`` module under :data:`CODE_FOLDERS` may hold."""


def long_modules(root: Path, limit: int = MAX_MODULE_LINES,
                 folders: tuple[str, ...] = CODE_FOLDERS) -> list[tuple[str, int]]:
    """``(path, lines)`` of every ``.py`` module over ``limit`` lines under ``folders`` of ``root``, longest first."""
    found = []
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            n = path.read_text(encoding="utf-8").count("\n")
            if n > limit:
                found.append((path.relative_to(root).as_posix(), n))
    return sorted(found, key=lambda f: (-f[1], f[0]))


def _core_pins_dvc_minor(pyproject: Path) -> bool | None:
    """Whether the core ``[project] dependencies`` hold a ``dvc`` requirement with an upper bound (``<``)."""
    if not pyproject.is_file():
        return None
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        return None
    deps = tomllib.loads(pyproject.read_text(encoding="utf-8")).get("project", {}).get("dependencies", [])
    return any(re.match(r"dvc\b(?![-\w])", d) and "<" in d for d in deps)


def measure(root: Path, top: int = 10) -> dict:
    """The structure numbers of the tree at ``root`` (its ``abcgs/``, ``stages/``, ``eval/``)."""
    root = root.resolve()
    files = sorted(p for p in (root / "abcgs").rglob("*.py") if "__pycache__" not in p.parts)
    arrows: set[tuple[str, str]] = set()
    upward: list[str] = []
    upward_by_package: list[str] = []
    functions: list[tuple[str, int]] = []
    unplaced: list[str] = []
    lines = 0
    for path in files:
        source = path.read_text(encoding="utf-8")
        lines += source.count("\n")
        module = module_name(path, root)
        if floor_of(module) is None:
            unplaced.append(module)
        for _, target in abcgs_imports(source, module, path.name == "__init__.py", root):
            if unit_of(module) != unit_of(target):
                arrows.add((unit_of(module), unit_of(target)))
        upward += upward_imports(module, source, root, path.name == "__init__.py")
        for line, target in abcgs_imports(source, module, path.name == "__init__.py", root):
            a, b = floor_of(unit_of(module)), floor_of(unit_of(target))
            if unit_of(module) != unit_of(target) and a is not None and b is not None and b > a:
                upward_by_package.append(f"{module}:{line} ({FLOORS[a][0]}) imports {target} ({FLOORS[b][0]})")
        functions += [(f"{path.relative_to(root).as_posix()}:{name}", n)
                      for name, n in _functions(ast.parse(source), "")]
    mutual = sorted({tuple(sorted(a)) for a in arrows if (a[1], a[0]) in arrows})
    rings = import_rings(module_graph(root))
    side_effect = sorted(f"{p.relative_to(root).as_posix()}:{i}"
                         for folder in ("abcgs", "stages", "eval") for p in (root / folder).rglob("*.py")
                         for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
                         if line.strip().startswith("import abcgs  # noqa: F401"))
    functions.sort(key=lambda f: (-f[1], f[0]))
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                                check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = None
    dvc_yaml = root / "dvc.yaml"
    return {
        "commit": commit,
        "dvc_yaml_lines": dvc_yaml.read_text(encoding="utf-8").count("\n") if dvc_yaml.is_file() else None,
        "core_pins_dvc_minor": _core_pins_dvc_minor(root / "pyproject.toml"),
        "modules": len(files),
        "lines": lines,
        "packages": len({unit_of(module_name(p, root)) for p in files}),
        "import_arrows": len(arrows),
        "upward_imports": len(upward),
        "upward_import_lines": upward,
        "upward_imports_by_package": len(upward_by_package),
        "upward_by_package_lines": upward_by_package,
        "mutual_pairs": [list(p) for p in mutual],
        "module_rings": rings,
        "module_ring_count": len(rings),
        "unplaced_modules": unplaced,
        "side_effect_imports": len(side_effect),
        "functions": len(functions),
        "functions_over_80_lines": sum(n > 80 for _, n in functions),
        "modules_over_500_lines": [f"{m} {n}" for m, n in long_modules(root)],
        "longest_functions": [{"function": f.replace(":.", ":"), "lines": n} for f, n in functions[:top]],
    }


ROWS = (("modules", "modules under abcgs/"), ("lines", "lines under abcgs/"),
        ("packages", "units (sub-packages and top-level modules)"), ("import_arrows", "import arrows between units"),
        ("upward_imports", "imports up the floors (by module)"),
        ("upward_imports_by_package", "imports up the floors (by package)"),
        ("mutual_pairs", "unit pairs importing each other"), ("module_rings", "import rings between modules"),
        ("side_effect_imports", "`import abcgs  # noqa: F401`"),
        ("functions_over_80_lines", "functions over 80 lines"),
        ("modules_over_500_lines", "modules over 500 lines (abcgs/, stages/, eval/)"), ("dvc_yaml_lines", "dvc.yaml lines"),
        ("core_pins_dvc_minor", "core package pins DVC's minor version"))


def markdown(record: dict, labels: list[str]) -> str:
    """A table of the stored numbers, one column per label, and the longest functions of each."""
    def cell(v):
        return str(len(v)) if isinstance(v, list) else ("yes" if v is True else "no" if v is False else str(v))

    lines = ["| | " + " | ".join(labels) + " |", "| --- |" + " ---: |" * len(labels)]
    lines += [f"| {text} | " + " | ".join(cell(record[lb].get(key)) for lb in labels) + " |" for key, text in ROWS]
    for lb in labels:
        longest = ", ".join(f"`{f['function'].split(':')[-1]}` {f['lines']}" for f in record[lb]["longest_functions"][:5])
        lines.append(f"\nLongest functions ({lb}): {longest}.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from eval.record import bench_parser, write_record  # here: importing this module (the layer checks) loads no abcgs

    ap = bench_parser(__doc__, json_help="store the numbers in this file under --label")
    ap.prog = "python -m eval run structure"
    ap.add_argument("--root", type=Path, default=Path("."), help="the tree to measure (default: here)")
    ap.add_argument("--label", default="now", help="the key the numbers are stored under (before, after, …)")
    ap.add_argument("--top", type=int, default=10, help="how many of the longest functions to list")
    ap.add_argument("--markdown", nargs="+", metavar="LABEL",
                    help="print the numbers stored in --json under these labels as a markdown table; measure nothing")
    args = ap.parse_args(argv)
    if args.markdown and args.json is None:
        ap.error("--markdown prints the numbers stored in a record: give it with --json")
    if args.markdown:
        print(markdown(json.loads(args.json.read_text()), args.markdown))
        return 0
    numbers = measure(args.root, args.top)
    if args.json:
        record = json.loads(args.json.read_text()) if args.json.is_file() else {}
        record.pop("provenance", None)  # an earlier write's
        record[args.label] = numbers
        write_record(args.json, record, argv)
    summary = {k: v for k, v in numbers.items() if k not in ("upward_import_lines", "longest_functions")}
    print(json.dumps(summary, indent=1))
    for f in numbers["longest_functions"]:
        print(f"{f['lines']:5d}  {f['function']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
