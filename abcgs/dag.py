"""``dvc.yaml`` from the stage specs: each stage's command, data deps, code deps, params, outputs.

``python -m abcgs.dag --write`` writes ``dvc.yaml`` from the :class:`abcgs.pipeline.StageSpec` of every script in
:data:`STAGES` (``tests/test_dag.py`` checks that the committed file is current: ``--check``); ``python -m
abcgs.dag`` prints each stage's code deps. A stage's code deps are the files it runs:

:func:`import_closure` follows a stage script's imports through the project's own modules (``abcgs``; every
``import`` statement anywhere in a module, including the ones inside functions), adds each imported package's
``__init__.py`` (Python runs it first), every module of a package that ``importlib.import_module(f"abcgs.pkg.{name}")``
may load or that a :class:`abcgs.plugins.Registry` names (``Registry(kind, type, "abcgs.pkg", ...)``: a registry's
discovery loads each format module of it), and the non-Python files the code loads at run time
(:data:`DATA_FILES`: the C++ kernels' sources, the viewer bundle). :func:`missing_deps` compares it with the deps a
stage declares, :func:`excess_deps` the other way round; :func:`minimal_deps` writes a package as one folder dep where
the stage runs every file of it, and ``dvc.yaml`` lists a stage's deps by package (:func:`grouped_flow`).

A stage validates only the params sections it reads, importing their models by name
(:data:`abcgs.sections.SECTIONS`); :func:`stage_closure` adds those modules (and what they import), and nothing of
the other sections, so editing one section's settings module re-runs only the stages that read that section.
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import re
import sys
from collections.abc import Callable, Iterable
from functools import lru_cache
from pathlib import Path
from types import ModuleType
from typing import Any

import yaml

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


def is_type_checking_block(node: ast.AST) -> bool:
    """``if TYPE_CHECKING:`` / ``if typing.TYPE_CHECKING:``: its body is read by type checkers only, never run."""
    if not isinstance(node, ast.If):
        return False
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def is_main_block(node: ast.AST) -> bool:
    """``if __name__ == "__main__":``: its body runs when the module is the program, not when it is imported."""
    return (isinstance(node, ast.If) and isinstance(node.test, ast.Compare) and isinstance(node.test.left, ast.Name)
            and node.test.left.id == "__name__" and len(node.test.comparators) == 1
            and isinstance(node.test.comparators[0], ast.Constant) and node.test.comparators[0].value == "__main__")


def _run_nodes(tree: ast.AST, imported: bool = False) -> Iterable[ast.AST]:
    """Every node of ``tree`` but the bodies of ``if TYPE_CHECKING:`` blocks (their ``else`` branches run) and, for
    an ``imported`` module, of ``if __name__ == "__main__":``."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        if is_type_checking_block(node) or (imported and is_main_block(node)):
            todo.extend(node.orelse)
            continue
        todo.extend(ast.iter_child_nodes(node))


def _imported_modules(tree: ast.AST, current: str | None) -> Iterable[str]:
    """Dotted names a module's import statements may load (``from a import b``: ``a`` and ``a.b``); imports under
    ``if TYPE_CHECKING:`` load nothing when the code runs and are left out, as are those of an imported module's
    ``if __name__ == "__main__":`` block (``current`` set: the module is imported, not run as the script)."""
    for node in _run_nodes(tree, imported=current is not None):
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
        elif isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) == "Registry":
            # Registry(kind, type, "abcgs.pkg", ...): its discovery imports every module of that package
            for arg in node.args:
                if isinstance(arg, ast.Constant) and isinstance(arg.value, str) and arg.value.startswith(f"{PACKAGE}."):
                    yield arg.value
                    yield f"{arg.value}.*"
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) == "import_module"
              and node.args and isinstance(node.args[0], ast.JoinedStr) and current):
            # import_module(f"abcgs.pkg.{name}"): any module of the package the f-string names (else of the
            # importing module's own package)
            head = node.args[0].values[0] if node.args[0].values else None
            prefix = head.value if isinstance(head, ast.Constant) and isinstance(head.value, str) else ""
            if prefix.startswith(f"{PACKAGE}.") and prefix.endswith(".") and prefix.count(".") >= 2:
                yield f"{prefix[:-1]}.*"
            else:
                yield f"{current.rsplit('.', 1)[0]}.*" if current.count(".") else f"{current}.*"


@lru_cache(maxsize=4096)
def _imports_of_source(text: str, current: str | None) -> tuple[str, ...]:
    """:func:`_imported_modules` of a module's source text, kept for the next stage's closure (every stage imports
    much the same modules; keyed by the text, so an edited file is parsed again)."""
    return tuple(_imported_modules(ast.parse(text), current))


def import_closure(script: Path, root: Path, also: Iterable[str] = (), packages: tuple[str, ...] = (PACKAGE,)
                   ) -> set[Path]:
    """Project files (relative to ``root``) that running ``script`` imports or loads, ``script`` included; ``also``:
    dotted modules it imports by name at run time (importlib), followed the same way; ``packages``: the top-level
    packages whose modules are followed (a benchmark's: ``abcgs`` and ``eval``)."""
    root = root.resolve()
    seen: set[Path] = set()
    todo: list[tuple[Path, str | None]] = [(script.resolve(), None)]
    for dotted in also:
        f = _module_file(root, dotted)
        if f is not None:
            todo.append((f, dotted))
    while todo:
        path, dotted = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for name in _imports_of_source(path.read_text(encoding="utf-8"), dotted):
            if name.split(".")[0] not in packages:
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
                    todo.append((f, prefix if f.name != "__init__.py" else f"{prefix}.__init__"))
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


def source_files(path: Path, root: Path) -> list[Path]:
    """The files under ``path`` (a file or a folder) that are sources, relative to ``root``: not bytecode, not the
    built kernels (``*.so``) nor their build record (``_kernels*``), which the install writes from the sources."""
    paths = [path] if path.is_file() else sorted(path.rglob("*"))
    return [p.relative_to(root) for p in paths if p.is_file() and "__pycache__" not in p.parts
            and p.suffix not in (".so", ".pyc") and not p.name.startswith("_kernels")]


def excess_deps(closure: Iterable[Path], deps: Iterable[str], root: Path,
                code_roots: tuple[str, ...] = ("abcgs", "stages")) -> list[Path]:
    """Files that a stage's code deps (under ``code_roots``) cover but that are not in its ``closure``: files that
    cannot change its output, whose edits would re-run it for nothing."""
    root = root.resolve()
    closure = set(closure)
    out: set[Path] = set()
    for d in deps:
        if Path(d).parts[:1] and Path(d).parts[0] in code_roots:
            out |= {f for f in source_files(root / d, root) if f not in closure}
    return sorted(out)


def minimal_deps(closure: set[Path], root: Path) -> list[str]:
    """The closure as few ``deps`` entries as possible: a folder where every file under it is in the closure."""
    root = root.resolve()
    out: list[str] = []
    listed: dict[Path, list[Path]] = {}

    def whole(folder: Path) -> bool:
        if folder not in listed:
            listed[folder] = source_files(root / folder, root)
        return bool(listed[folder]) and all(f in closure for f in listed[folder])

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


STAGES = ("preflight", "make_tiny", "styles", "style_masks", "reconstruct", "fit", "masks", "reference", "colormatch",
          "stylize", "evaluate", "export_scene", "export", "report")
"""The stage scripts (``stages/<name>.py``), in ``dvc.yaml``'s order."""
FOREACH = {"data.scenes": "${data.scenes}", "data.styles": "${data.styles}", "data.style_masks": "${data.style_masks}",
           "colormatches": "${colormatches}", "experiments": "${experiments}"}
HEADER = """\
# Generated by `python -m abcgs.dag --write` from the stage specs in stages/*.py; tests/test_dag.py checks it is current.
# A stage is a script in stages/; its deps: the inputs its command passes, the preflight stamp, the code it runs (its
# import closure by package; a folder where it runs every file). abcgs.pipeline.run_stage fills '{key}' in from
# $DVC_STAGE: no params value reaches a shell. Metrics and plots are git-tracked (cache: false); the rest DVC-cached.
"""


def load_stage(script: Path) -> ModuleType:
    """A stage script (``stages/<name>.py``) as a module: its ``SPEC`` and its ``main(args, params)``, which is what
    ``dvc repro`` runs."""
    spec = importlib.util.spec_from_file_location(f"stage_{script.stem}", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def load_spec(script: Path) -> Any:
    """The :class:`abcgs.pipeline.StageSpec` of a stage script (its ``SPEC``)."""
    return load_stage(script).SPEC


def stage_closure(script: Path, spec: Any, root: Path) -> set[Path]:
    """:func:`import_closure` of a stage script plus the settings modules of the params sections it reads."""
    from abcgs.sections import SECTIONS

    return import_closure(script, root, also=sorted({SECTIONS[s].module for s in spec.sections}))


class _Flow(list):
    """A list ``dvc.yaml`` writes in flow style (``[a, b, c]``, wrapped at the line width)."""


class _Dumper(yaml.SafeDumper):
    """PyYAML's safe dumper that writes :class:`_Flow` lists in flow style."""


_Dumper.add_representer(_Flow, lambda d, v: d.represent_sequence("tag:yaml.org,2002:seq", v, flow_style=True))


def _flow_item(entry: str) -> str:
    """One entry of a flow list: quoted where YAML's flow context needs it (``${key}``, commas, brackets)."""
    return f"'{entry}'" if any(c in entry for c in "{}[],:#'\"") or entry[:1] in "!&*@`%|>-?" else entry


def _package(entry: str) -> str:
    """The group a dep is listed in: its package folder (``abcgs/io/atomic.py`` → ``abcgs/io``; a folder dep is
    its own group), data deps first (``""``)."""
    parts = Path(entry).parts
    if parts[0] not in ("abcgs", "stages"):
        return ""
    return entry if not entry.endswith(".py") else Path(entry).parent.as_posix()


def grouped_flow(entries: list[str], indent: int, width: int = 120, group: Callable[[str], str] = _package) -> str:
    """``entries`` as a YAML flow list wrapped at ``width``: grouped by ``group`` (default: the data deps first, then
    the code deps by package), a group's entries kept on one line (a line breaks between groups, inside one only where
    it is longer than a line; the ``""`` group alone on its line)."""
    groups: dict[str, list[str]] = {}
    for e in entries:
        groups.setdefault(group(e), []).append(_flow_item(e))
    room = width - indent - 2
    lines: list[str] = []
    line, line_is_data = "", False
    for key, items in groups.items():
        text = " ".join(f"{i}," for i in items)
        if line and (line_is_data or len(line) + 1 + len(text) > room):  # the data deps alone on the first line
            lines.append(line)
            line = ""
        line_is_data = key == ""
        for item in items:
            if line and len(line) + len(item) + 2 > room:
                lines.append(line)
                line = ""
            line = f"{line} {item}," if line else f"{item},"
    lines.append(line)
    pad = " " * (indent + 1)
    return "[" + f"\n{pad}".join(lines).rstrip(",") + "]"


def _dvc(template: Any) -> str:
    """A path or params template as ``dvc.yaml`` writes it: ``{key}`` → ``${key}``."""
    return (template if isinstance(template, str) else Path(template).as_posix()).replace("{", "${")


def stage_entry(script: Path, spec: Any, root: Path, params_path: Path | None = None) -> dict:
    """The ``dvc.yaml`` entry of one stage (the ``do:`` body of a ``foreach`` stage is inside). A stage that reads
    the outputs of every experiment (``report``) names them through its ``reads(params)``, filled in from
    ``params_path`` (default ``root/params.yaml``)."""
    cmd = " ".join([f"python {script.relative_to(root).as_posix()}"]
                   + [f"--{o.option} '{Path(o.path).as_posix()}'" for o in spec.options])
    body: dict[str, Any] = {"cmd": cmd}
    code = minimal_deps(stage_closure(script, spec, root), root)
    reads = getattr(load_stage(script), "reads", None)
    data = [_dvc(d.path) for d in spec.inputs]
    if reads is not None:
        from abcgs.params import load_params

        data += [p for p in reads(load_params(params_path or root / "params.yaml")) if p not in data]
    body["deps"] = data + code
    if spec.params:
        body["params"] = _Flow([_dvc(p) for p in spec.params])
    outs = _Flow([_dvc(o.path) for o in spec.outs if o.kind == "out"])
    metrics = [{_dvc(o.path): {"cache": False}} for o in spec.outs if o.kind == "metric"]
    plots = [{_dvc(o.path): {"cache": False, "x": o.plot_axes[0], "y": o.plot_axes[1]}}
             for o in spec.outs if o.kind == "plot"]
    for key, value in (("outs", outs), ("metrics", metrics), ("plots", plots)):
        if value:
            body[key] = value
    return {"foreach": FOREACH[spec.foreach], "do": body} if spec.foreach else body


def pipeline_yaml(root: Path, params_path: Path | None = None) -> str:
    """The text of ``dvc.yaml`` for the stage scripts under ``root/stages`` and the params file ``params_path``
    (default ``root/params.yaml``; another one: the ``dvc.yaml`` a run of those params needs, e.g. a benchmark
    overlay's)."""
    stages = {name: stage_entry(root / "stages" / f"{name}.py", load_spec(root / "stages" / f"{name}.py"), root,
                                params_path)
              for name in STAGES}
    return stages_yaml(stages, HEADER)


def stages_yaml(stages: dict[str, dict], header: str, group: Callable[[str], str] = _package) -> str:
    """The text of a ``dvc.yaml`` holding ``stages`` (name → entry; a ``foreach`` stage's body under ``do``; each
    body's ``deps`` a list, changed in place), after ``header``: each stage's deps written by :func:`grouped_flow`
    with ``group``, the rest by PyYAML (which wraps flow lists anywhere)."""
    deps = []
    for entry in stages.values():
        body = entry.get("do", entry)
        deps.append(body["deps"])
        body["deps"] = f"DEPS_{len(deps) - 1}"
    text = yaml.dump({"stages": stages}, Dumper=_Dumper, sort_keys=False, width=120, default_flow_style=False)

    def fill(m: re.Match) -> str:
        indent = len(m.group(1))
        return f"{m.group(1)}deps: {grouped_flow(deps[int(m.group(2))], indent + len('deps: '), group=group)}"

    return header + re.sub(r"^( *)deps: DEPS_(\d+)$", fill, text, flags=re.M)


def main(argv: list[str] | None = None) -> int:
    """``python -m abcgs.dag [--write | --update | --check]``: print each stage's code deps, write ``dvc.yaml``,
    write it only where it is not current (``make run`` does, before ``dvc repro``: the report stage's deps follow
    ``params.yaml``'s experiments), or check that the committed one is current."""
    ap = argparse.ArgumentParser(prog="python -m abcgs.dag", description=main.__doc__)
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help="write dvc.yaml from the stage specs")
    mode.add_argument("--update", action="store_true", help="write dvc.yaml when it is not what --write would write")
    mode.add_argument("--check", action="store_true", help="exit 1 when dvc.yaml is not what --write would write")
    args = ap.parse_args(argv)
    root = Path.cwd()
    if args.write or args.update or args.check:
        from abcgs.errors import AbcgsError

        try:
            text = pipeline_yaml(root)
        except AbcgsError as exc:  # params.yaml that does not validate: the same message as the preflight's
            print(f"[dag] error: {exc}", file=sys.stderr)
            return 2
        current = (root / "dvc.yaml").read_text(encoding="utf-8") if (root / "dvc.yaml").is_file() else ""
        if args.check:
            if text != current:
                print("dvc.yaml is not current: run `python -m abcgs.dag --write`", file=sys.stderr)
                return 1
            return 0
        if args.update and text == current:
            return 0
        from abcgs.io.atomic import write_text

        write_text(root / "dvc.yaml", text)
        if args.update:
            print("[dag] dvc.yaml updated (the stages' deps for this params.yaml)")
        return 0
    for name in STAGES:
        script = root / "stages" / f"{name}.py"
        print(f"{script.relative_to(root)}:")
        for dep in minimal_deps(stage_closure(script, load_spec(script), root), root):
            print(f"  - {dep}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
