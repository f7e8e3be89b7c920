"""Shared plumbing of the DVC stage scripts in ``stages/``: the stage contract, params, logging, errors.

A stage script declares a :class:`StageSpec` — its name, the ``foreach`` collection it fans out over, the params
keys it reads (``experiments.{key}``, ``colormatches.{item.colormatch}``), and its data inputs and outputs
(:class:`Dep`, :class:`Out`: path templates from :mod:`abcgs.layout`, each passed as a command-line option) — and a
short ``main(args, params)`` that calls the library. ``dvc.yaml`` is generated from these specs
(``python -m abcgs.dag --write``): each stage's command passes exactly its inputs and outputs, its ``deps`` are
those inputs plus the code it runs, its ``params`` the keys it reads. :func:`run_stage` then

1. validates the params sections the stage reads (:func:`abcgs.sections.validate_sections`; the preflight stage,
   which every stage depends on, validated the whole file);
2. hands ``main`` a *tracked view* of the params (:func:`tracked_view`): only the declared keys can be read, any
   other raises :class:`UntrackedParamsError`, so a stage cannot depend on a value DVC does not track;
3. sets up logging and turns an :class:`abcgs.errors.AbcgsError` into a one-paragraph message and exit status 2
   instead of a traceback.

A ``foreach`` stage's key (``stylize@tiny_single`` → ``tiny_single``) is the key option when given, else read
from ``$DVC_STAGE``, which DVC sets for the command (:func:`stage_key`); its path arguments name the key as
``{key}`` / ``{item.F}`` (``--out out/{key}/stylize``), filled in here. ``dvc.yaml``'s commands therefore carry no
params value that a shell would parse, however a stage is selected (``-s``, ``--downstream``, ``dvc exp run``, a
cluster job).
"""

from __future__ import annotations

import argparse
import errno
import inspect
import logging
import os
import re
import sys
import time
import types
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel

from abcgs import layout
from abcgs.dotted import lookup
from abcgs.errors import AbcgsError
from abcgs.sections import NAME_PATTERN, NAME_RE, ParamsBase, read_params_file, validate_sections

log = logging.getLogger("abcgs")
_STORAGE_ERRNOS = {
    errno.ENOSPC: "The disk is full: free space (e.g. `dvc gc` for old cache entries) or move out/ and the DVC cache "
                  "to a larger disk (`dvc cache dir`).",
    errno.EDQUOT: "The disk quota is used up: free space or ask for a larger quota.",
    errno.EFBIG: "A file grew past the file system's or the process's file-size limit (`ulimit -f`): raise the limit "
                 "or move out/ and the DVC cache to a file system that allows larger files.",
    errno.EROFS: "The file system is read-only: run the pipeline in a writable checkout.",
    errno.EACCES: "Permission denied: the output folder must be writable by you.",
}
"""Storage errors a stage reports as a message (what to do) instead of a traceback."""

Foreach = Literal["data.scenes", "data.styles", "data.style_masks", "colormatches", "experiments"]
KEY_OPTION: dict[str, str] = {"data.scenes": "scene", "data.styles": "style", "data.style_masks": "style",
                              "colormatches": "colormatch", "experiments": "experiment"}
"""The command-line option that names a ``foreach`` stage's key by hand (``--scene tiny``, ``--experiment
tiny_single``); under DVC the key comes from :data:`DVC_STAGE_ENV` instead (:func:`stage_key`)."""
DVC_STAGE_ENV = "DVC_STAGE"
"""The variable DVC sets for a stage's command: the stage's address, ``stylize@tiny_single`` (with ``dvc.yaml:`` in
front when DVC runs in another folder). ``dvc.yaml`` passes no params value in a command (a name there would be
parsed by the shell): a ``foreach`` stage learns its key from this variable, and its path arguments name the key as
``{key}`` / ``{item.F}``, filled in by :func:`run_stage`."""


@dataclass(frozen=True)
class Dep:
    """A data input of a stage: passed to its script as ``--<option> <path>`` and listed in its ``deps``."""

    option: str
    path: str | Path
    """A path template (:mod:`abcgs.layout`), with ``{key}`` / ``{item.F}`` for a ``foreach`` stage's entry, or
    ``{item}`` for the entry itself where it is a path (``data.styles``)."""
    help: str = ""


@dataclass(frozen=True)
class Out:
    """An output of a stage, under ``outs`` (DVC-cached), ``metrics`` or ``plots`` (git-tracked, ``cache: false``).

    ``option`` set: passed to the script as ``--<option> <path>``; ``None``: a file the script writes inside or
    beside another of its options' paths (``gs/history.csv`` in ``--out out/S/gs``, ``stylize_info.json`` beside
    ``--metrics out/E/stylize.json``), listed on its own because DVC treats it differently (a plot, not cached).
    """

    path: str | Path
    option: str | None = None
    kind: Literal["out", "metric", "plot", "folder"] = "out"
    """``folder``: a folder passed to the script whose files are listed as outputs of their own (some cached, some
    not), not as one output."""
    plot_axes: tuple[str, str] | None = None
    """``(x, y)`` columns of a plot."""
    help: str = ""


PREFLIGHT = Dep("preflight", layout.PREFLIGHT_STAMP, "the preflight stage's stamp (every stage runs after it)")


@dataclass(frozen=True)
class StageSpec:
    """What a stage script is to ``dvc.yaml``.

    ``params``: the dotted params keys the stage reads, with ``{key}`` for the ``foreach`` key and ``{item.F}`` for
    field ``F`` of the ``foreach`` entry — written into ``dvc.yaml`` as ``${key}`` / ``${item.F}``.
    ``deps`` / ``outs``: its data inputs and outputs; every stage but ``preflight`` also depends on the preflight
    stamp (:data:`PREFLIGHT`).
    """

    name: str
    params: tuple[str, ...] = ()
    foreach: Foreach | None = None
    deps: tuple[Dep, ...] = ()
    outs: tuple[Out, ...] = ()

    @property
    def inputs(self) -> tuple[Dep, ...]:
        """Every data input, the preflight stamp first."""
        return self.deps if self.name == "preflight" else (PREFLIGHT, *self.deps)

    @property
    def options(self) -> tuple[Dep | Out, ...]:
        """The path options the script takes, in command-line order."""
        return (*self.inputs, *(o for o in self.outs if o.option))

    @property
    def sections(self) -> frozenset[str]:
        """The top-level params sections the stage reads (and validates)."""
        return frozenset(p.split(".")[0] for p in self.params)

    def fill(self, template: str, raw: Mapping[str, Any], key: str | None) -> str:
        """``template`` with ``{key}`` / ``{item.F}`` filled in from the raw params file, as DVC fills in
        ``${key}`` / ``${item.F}``."""
        item = _lookup(raw, self.foreach).get(key, {}) if self.foreach and key is not None else {}

        def fill(m: re.Match) -> str:
            name = m.group(1)
            if name == "key":
                return str(key)
            if name == "item":  # a foreach over a mapping of scalars (data.styles: key → path)
                return str(item)
            value = item.get(name.removeprefix("item.")) if isinstance(item, Mapping) else None
            return str(value)

        return re.sub(r"\{(key|item(?:\.[A-Za-z_]+)?)\}", fill, template)

    def resolved_params(self, raw: Mapping[str, Any], key: str | None) -> tuple[str, ...]:
        """``params`` with ``{key}`` / ``{item.F}`` filled in (:meth:`fill`)."""
        return tuple(self.fill(p, raw, key) for p in self.params)


def _lookup(raw: Mapping[str, Any], dotted: str) -> Mapping[str, Any]:
    node = lookup(raw, dotted, {})
    return node if isinstance(node, Mapping) else {}


class UntrackedParamsError(AttributeError):
    """A stage read a params key it does not declare (and so ``dvc.yaml`` does not track)."""


def _untracked(path: str, stage: str) -> None:
    """Raise :class:`UntrackedParamsError` for params key ``path`` read by ``stage``."""
    raise UntrackedParamsError(
        f"stage {stage!r} read params key {path!r}, which it does not track: add it to the stage's "
        f"StageSpec.params in stages/ and to its params: list in dvc.yaml")


class _TrackedDict(dict):
    """A mapping section (``data.scenes``, ``experiments``, …) restricted to its tracked entries."""

    def __init__(self, items: dict, path: str, stage: str, hidden: Sequence[str]) -> None:
        super().__init__(items)
        self._path, self._stage, self._hidden = path, stage, set(hidden)

    def __missing__(self, key: str):
        if key in self._hidden:
            _untracked(f"{self._path}.{key}", self._stage)
        raise KeyError(key)

    def _whole(self, *_: Any):
        _untracked(f"{self._path} (all of it)", self._stage)

    # iterating the whole section would read entries the stage does not track
    __iter__ = keys = values = items = __len__ = _whole  # type: ignore[assignment]


def _tree(paths: Sequence[str]) -> dict:
    """Dotted paths → nested dict; ``True`` marks a whole subtree."""
    root: dict = {}
    for p in paths:
        node = root
        parts = p.split(".")
        for part in parts[:-1]:
            nxt = node.setdefault(part, {})
            if nxt is True:
                break
            node = nxt
        else:
            node[parts[-1]] = True
    return root


class _ModelView:
    """A params model of which only the tracked fields can be read; its methods run against the view too."""

    __slots__ = ("_model", "_tree", "_path", "_stage")

    def __init__(self, model: BaseModel, tree: dict, path: str, stage: str) -> None:
        for k, v in (("_model", model), ("_tree", tree), ("_path", path), ("_stage", stage)):
            object.__setattr__(self, k, v)

    def __getattr__(self, name: str) -> Any:
        model, tree = object.__getattribute__(self, "_model"), object.__getattribute__(self, "_tree")
        path, stage = object.__getattribute__(self, "_path"), object.__getattribute__(self, "_stage")
        cls = type(model)
        if name in cls.model_fields:
            here = f"{path}.{name}" if path else name
            if name not in tree:
                _untracked(here, stage)
            return _restrict(getattr(model, name), tree[name], here, stage)
        attr = inspect.getattr_static(cls, name, None)
        if isinstance(attr, property):
            return attr.fget(self)
        if inspect.isfunction(attr):
            return types.MethodType(attr, self)
        return getattr(model, name)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("params are read-only in a stage")

    def __repr__(self) -> str:
        return f"<tracked view of {type(object.__getattribute__(self, '_model')).__name__}>"


def _restrict(value: Any, tree: dict | bool, path: str, stage: str) -> Any:
    if tree is True:
        return value
    if isinstance(value, BaseModel):
        return _ModelView(value, tree, path, stage)
    if isinstance(value, dict):
        kept = {k: _restrict(v, tree[k], f"{path}.{k}", stage) for k, v in value.items() if k in tree}
        return _TrackedDict(kept, path, stage, [k for k in value if k not in tree])
    return value


def tracked_view(params: ParamsBase, tracked: Sequence[str], stage: str = "?") -> ParamsBase:  # a view that reads like the params
    """A copy of ``params`` in which only the dotted keys ``tracked`` (and what lies under them) can be read."""
    return _restrict(params, _tree(tracked), "", stage)


def stage_parser(spec: StageSpec, description: str) -> argparse.ArgumentParser:
    """The script's arguments: ``--params``, the key option of a ``foreach`` stage, and one required path option per
    input and output of the spec (:attr:`StageSpec.options`)."""
    ap = argparse.ArgumentParser(prog=f"stages/{spec.name}.py", description=description)
    ap.add_argument("--params", type=Path, default=Path("params.yaml"), help="the pipeline's params file")
    if spec.foreach:
        opt = KEY_OPTION[spec.foreach]
        ap.add_argument(f"--{opt}", help=f"a key of {spec.foreach} (under DVC: the key in ${DVC_STAGE_ENV}, "
                                         f"{spec.name}@<key>)")
    for o in spec.options:
        if o.option == "params":  # the params file as a data dep (the preflight stage): the option above
            continue
        ap.add_argument(f"--{o.option}", type=Path, required=True, metavar="PATH",
                        help=f"{o.help} (dvc.yaml: {Path(o.path).as_posix()})".lstrip())
    return ap


def stage_key(spec: StageSpec, given: str | None, environ: Mapping[str, str]) -> str | None:
    """The ``foreach`` key this run is for: ``given`` (the key option, a run by hand), else the part after ``@`` of
    the DVC stage running the script (:data:`DVC_STAGE_ENV`); ``None`` outside a ``foreach`` entry."""
    if given is not None:
        return given
    stage, at, key = environ.get(DVC_STAGE_ENV, "").partition("@")
    if not at:
        return None
    stage = stage.rsplit(":", 1)[-1]  # `path/dvc.yaml:` in front when DVC runs in another folder
    if spec.foreach and stage != spec.name:
        raise AbcgsError(f"${DVC_STAGE_ENV} names stage {stage!r}, which does not run stages/{spec.name}.py; pass "
                         f"--{KEY_OPTION[spec.foreach]} NAME")
    return key


def fill_paths(args: argparse.Namespace, spec: StageSpec, raw: Mapping[str, Any], key: str | None) -> None:
    """Path arguments with ``{key}`` / ``{item.F}`` in them (``--out out/{key}/stylize``) → the stage's paths."""
    for name, value in vars(args).items():
        if not isinstance(value, Path) or "{" not in str(value):
            continue
        if key is None:
            raise AbcgsError(f"--{name.replace('_', '-')} {value} names the stage's key, but no key is given: run "
                             f"it under DVC (which passes ${DVC_STAGE_ENV}) or give the path itself")
        if not NAME_RE.fullmatch(key):
            raise AbcgsError(f"${DVC_STAGE_ENV} {key!r}: a name must match {NAME_PATTERN}; fix it in the params file")
        setattr(args, name, Path(spec.fill(str(value), raw, key)))


def stage_paths(spec: StageSpec, raw: Mapping[str, Any], key: str | None, out: Path = layout.OUT) -> dict[str, Path]:
    """The stage's path options for the ``foreach`` entry ``key``, as ``dvc.yaml`` passes them and
    :func:`fill_paths` fills them in, with ``out/`` moved to ``out`` (to run a stage's ``main`` elsewhere):
    ``{"colmap": Path("out/tiny/colmap"), …}``, keyed like ``argparse`` attributes."""
    paths = {}
    for o in spec.options:
        p = Path(spec.fill(Path(o.path).as_posix(), raw, key))
        paths[o.option.replace("-", "_")] = out / p.relative_to(layout.OUT) if p.is_relative_to(layout.OUT) else p
    return paths


READ_AUDIT_ENV = "ABCGS_READ_AUDIT"
"""A folder: when set, each stage writes there (``<stage>.json``) every path under ``out/`` it opened for reading
or listed through Python (:func:`sys.addaudithook`), for checking that it reads only its declared inputs
(``tests/test_pipeline_e2e.py``). Reads by C++ code (OpenCV, COLMAP) are not seen."""


def _audit_reads(spec: StageSpec, environ: Mapping[str, str]) -> Callable[[], None] | None:
    """With :data:`READ_AUDIT_ENV` set: record the stage's reads under ``out/`` from now on; the returned function
    writes them to ``<folder>/<stage>.json``."""
    folder = environ.get(READ_AUDIT_ENV)
    if not folder:
        return None
    cwd = Path.cwd()
    out = cwd / layout.OUT
    seen: set[str] = set()

    def reading(mode: str | None, flags: int) -> bool:
        if mode is None:  # os.open
            return not flags & (os.O_WRONLY | os.O_RDWR)
        return not mode.strip("rbt")

    def hook(event: str, args: tuple) -> None:
        if event == "open" and isinstance(args[0], (str, os.PathLike)) and reading(args[1], args[2]):
            path = args[0]
        elif event in ("os.listdir", "os.scandir") and args and isinstance(args[0], (str, os.PathLike)):
            path = args[0]
        else:
            return
        p = cwd / os.fsdecode(path)
        if p.is_relative_to(out):
            seen.add(p.relative_to(cwd).as_posix())

    sys.addaudithook(hook)

    def write() -> None:
        import json

        name = environ.get(DVC_STAGE_ENV, spec.name).rsplit(":", 1)[-1]
        Path(folder).mkdir(parents=True, exist_ok=True)
        (Path(folder) / f"{name}.json").write_text(json.dumps(sorted(seen), indent=1))

    return write


def run_stage(
    spec: StageSpec, parser: argparse.ArgumentParser, main: Callable[[argparse.Namespace, ParamsBase], None], argv=None
) -> int:
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    t0 = time.perf_counter()
    try:
        raw = read_params_file(args.params)
        params = validate_sections(raw, spec.sections, str(args.params))
        key = stage_key(spec, getattr(args, KEY_OPTION[spec.foreach]) if spec.foreach else None, os.environ)
        if spec.foreach and key is None:
            raise AbcgsError(f"which entry of {spec.foreach}? pass --{KEY_OPTION[spec.foreach]} NAME")
        if spec.foreach and key not in _lookup(raw, spec.foreach):
            raise AbcgsError(f"{key!r} is not a key of {spec.foreach} in {args.params}")
        if spec.foreach:
            setattr(args, KEY_OPTION[spec.foreach], key)  # main reads args.scene / args.experiment
        fill_paths(args, spec, raw, key)
        if spec.name != "preflight" and not args.preflight.is_file():
            raise AbcgsError(f"{args.preflight} is missing: the preflight stage checks the params and inputs first "
                             "(dvc repro preflight)")
        audit = _audit_reads(spec, os.environ)
        main(args, tracked_view(params, spec.resolved_params(raw, key), spec.name))
        if audit is not None:
            audit()
    except AbcgsError as exc:
        print(f"\n[{spec.name}] error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        if exc.errno not in _STORAGE_ERRNOS:
            raise
        where = f" writing {exc.filename}" if exc.filename else ""
        print(f"\n[{spec.name}] error: {exc.strerror}{where}. {_STORAGE_ERRNOS[exc.errno]} Nothing of this stage was "
              "kept (outputs are written atomically); run it again afterwards.", file=sys.stderr)
        return 2
    log.info("[%s] done in %.1f s", spec.name, time.perf_counter() - t0)
    return 0
