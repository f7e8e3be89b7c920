"""Opening a file that another tool (or another person) made: the one guarded path every reader of a scene takes.

    data = read_bounded(path, "gsplat checkpoint", 8 << 30)          # bytes, at most 8 GiB
    meta = load_json(path, "cameras.json", 64 << 20)                 # a parsed JSON document, bounded
    doc = load_yaml(path, "params file", 4 << 20)                      # YAML, its aliases expanded under a budget

:func:`regular_file` refuses what is not a regular file before anything opens it: a FIFO (opening one blocks until
a writer comes), a device (``/dev/zero`` reads forever), a folder, a symlink loop or a missing file. The reads are
bounded by the caller's limit (the format's own), and every error of the decoder becomes one
:class:`~abcgs.errors.InputError` line naming the file and the fix. JSON is checked for its nesting depth
(:data:`MAX_JSON_DEPTH`) before it is parsed, so no reader recurses into a hostile document; YAML is composed with
its depth bounded (:data:`MAX_YAML_DEPTH`), its aliases expanded under a node budget (:data:`MAX_YAML_NODES`: an
alias bomb of a few hundred bytes names 10⁹ nodes, which every later walk of the document would visit) and its
numbers bounded in length (:data:`MAX_NUMBER_CHARS`).
"""

from __future__ import annotations

import errno
import json
import os
import re
import stat
from pathlib import Path
from typing import Any

import yaml

from abcgs.errors import InputError

MAX_JSON_DEPTH = 64
"""Deepest nesting of arrays and objects read (a camera file nests 4 deep; Python's parser would recurse 200 000)."""
_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)
"""A JSON string (its brackets are no nesting)."""
MAX_YAML_DEPTH = 64
"""Deepest nesting of a YAML document read, aliases expanded (``params.yaml`` nests 6 deep)."""
MAX_YAML_NODES = 200_000
"""Most nodes of a YAML document read, every alias counted as the nodes it stands for (``params.yaml``: about
1000)."""
MAX_NUMBER_CHARS = 100
"""Longest integer or float literal read from YAML (Python's ``int`` refuses more than 4300 digits, with a
``ValueError`` that names no file)."""
_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def regular_file(path: str | os.PathLike, what: str) -> os.stat_result:
    """The ``stat`` of ``path`` (symlinks followed) when it is a regular file; :class:`InputError` naming ``what``
    (``image``, ``gsplat checkpoint``) and ``path`` when it is missing, a symlink loop, a FIFO, a device or a folder.
    Never opens the file (opening a FIFO blocks)."""
    try:
        st = os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise InputError(f"{what} {path} is a symlink loop (a link that leads back to itself); point it at a "
                             "real file") from None
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            raise InputError(f"{what} {path} does not exist") from None
        raise InputError(f"{what} {path} cannot be read ({exc.strerror}); check the path and its permissions") from None
    if not stat.S_ISREG(st.st_mode):
        kind = next((name for test, name in _KINDS if test(st.st_mode)), "not a regular file")
        raise InputError(f"{what} {path} is {kind}, not a regular file; replace it with the file itself")
    return st


def read_bounded(path: str | os.PathLike, what: str, max_bytes: int) -> bytes:
    """The bytes of the regular file ``path`` (:func:`regular_file`), at most ``max_bytes`` (the format's limit):
    a larger file, or one that grows past it while read, raises :class:`InputError` naming ``what``."""
    size = regular_file(path, what).st_size
    if size > max_bytes:
        raise InputError(f"{what} {path} is {size} bytes, more than the {_bytes(max_bytes)} abcgs reads for it; it "
                         "is not such a file, or a corrupt one")
    try:
        with open(path, "rb") as fh:
            data = fh.read(max_bytes + 1)
    except OSError as exc:
        raise InputError(f"{what} {path} cannot be read ({exc.strerror})") from None
    if len(data) > max_bytes:
        raise InputError(f"{what} {path} grew past {_bytes(max_bytes)} while it was read; it is not such a file")
    return data


def read_text(path: str | os.PathLike, what: str, max_bytes: int) -> str:
    """:func:`read_bounded` decoded as UTF-8; :class:`InputError` naming ``what`` when it is not UTF-8 text."""
    data = read_bounded(path, what, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{what} {path} is not UTF-8 text ({exc.reason} at byte {exc.start}); re-export it") from None


def json_depth(data: bytes, chunk: int = 1 << 24) -> int:
    """The deepest nesting of ``[`` and ``{`` in the JSON text ``data`` (brackets inside strings left out), in
    chunks of ``chunk`` bytes so that the scan's memory stays a few times ``chunk``."""
    import numpy as np  # here: reading params.yaml through this module imports no numpy

    text = _STRING.sub(b'""', data)
    depth = deepest = 0
    for start in range(0, len(text), chunk):
        a = np.frombuffer(text, np.uint8, min(chunk, len(text) - start), start)
        sign = (a == ord("[")).astype(np.int8) + (a == ord("{")) - (a == ord("]")) - (a == ord("}"))
        steps = np.cumsum(sign[sign != 0], dtype=np.int64)
        if len(steps):
            deepest = max(deepest, depth + int(steps.max()))
            depth += int(steps[-1])
    return deepest


def parse_json(data: bytes | str, source: str, max_depth: int = MAX_JSON_DEPTH) -> Any:
    """The JSON text ``data`` parsed, its depth bounded by ``max_depth``; :class:`InputError` naming ``source``
    (the file) when it is not JSON (a number of more than 4300 digits included) or nests deeper."""
    raw = data.encode("utf-8", "surrogatepass") if isinstance(data, str) else data
    depth = json_depth(raw)
    if depth > max_depth:
        raise InputError(f"{source} is nested too deeply ({depth} levels, more than {max_depth}) to be a camera or "
                         "transforms file; re-export it")
    try:
        return json.loads(raw)
    except (ValueError, RecursionError) as exc:  # UnicodeDecodeError, a too-long integer, a stray byte
        raise InputError(f"{source} is not readable JSON ({str(exc)[:200]}); re-export it") from None


def load_json(path: str | os.PathLike, what: str, max_bytes: int, max_depth: int = MAX_JSON_DEPTH) -> Any:
    """The JSON document in the file ``path``: :func:`read_bounded`, then :func:`parse_json`."""
    return parse_json(read_bounded(path, what, max_bytes), f"{what} {path}", max_depth)


class _Refused(Exception):
    """A bound of :class:`_BoundedLoader` exceeded (the reason, without the file)."""


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader whose composer refuses a document nested deeper than :data:`MAX_YAML_DEPTH` (it
    recurses once a level) and whose number constructors refuse literals longer than :data:`MAX_NUMBER_CHARS`."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self.depth = 0

    def compose_node(self, parent, index):  # noqa: ANN001, ANN201 (PyYAML's signature)
        self.depth += 1
        try:
            if self.depth > MAX_YAML_DEPTH:
                raise _Refused(f"it nests deeper than {MAX_YAML_DEPTH} levels (line {self.peek_event().start_mark.line + 1})")
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1


def _bounded_number(construct):  # noqa: ANN001, ANN202
    def go(loader: yaml.SafeLoader, node: yaml.ScalarNode):  # noqa: ANN202
        if len(node.value) > MAX_NUMBER_CHARS:
            raise _Refused(f"the number at line {node.start_mark.line + 1} has {len(node.value)} characters, more than "
                           f"{MAX_NUMBER_CHARS}")
        return construct(loader, node)
    return go


_BoundedLoader.add_constructor("tag:yaml.org,2002:int", _bounded_number(yaml.SafeLoader.construct_yaml_int))
_BoundedLoader.add_constructor("tag:yaml.org,2002:float", _bounded_number(yaml.SafeLoader.construct_yaml_float))


def expanded_size(node: yaml.Node, budget: int = MAX_YAML_NODES, max_depth: int = MAX_YAML_DEPTH) -> int:
    """Nodes of the composed YAML ``node`` with every alias expanded (an aliased node counts each time it is named),
    computed once per distinct node; :class:`_Refused` past ``budget`` nodes, past ``max_depth`` levels through the
    aliases, or for a node that contains itself (a recursive alias)."""
    seen: dict[int, tuple[int, int]] = {}  # id → (expanded nodes, levels below it)

    def size(n: yaml.Node, path: frozenset[int]) -> tuple[int, int]:
        if id(n) in path:
            raise _Refused(f"the node at line {n.start_mark.line + 1} contains itself through an alias")
        if id(n) not in seen:
            kids = [x for pair in n.value for x in pair] if isinstance(n, yaml.MappingNode) else (
                n.value if isinstance(n, yaml.SequenceNode) else [])
            total, height = 1, 0
            for k in kids:
                count, below = size(k, path | {id(n)})
                total, height = total + count, max(height, below + 1)
                if total > budget:
                    raise _Refused(f"its aliases expand to more than {budget} nodes (an alias bomb?)")
                if len(path) + height > max_depth:
                    raise _Refused(f"through its aliases it nests deeper than {max_depth} levels")
            seen[id(n)] = (total, height)
        return seen[id(n)]
    return size(node, frozenset())[0]


def duplicate_key(node: yaml.Node) -> str | None:
    """The first key given twice in one mapping of the composed YAML ``node`` (each distinct node looked at once),
    as ``"'key' at lines A and B"``; None when there is none. PyYAML keeps the last of the two silently, where DVC
    and ruamel.yaml refuse the file."""
    seen: set[int] = set()
    stack = [node]
    while stack:
        n = stack.pop()
        if id(n) in seen:
            continue
        seen.add(id(n))
        if isinstance(n, yaml.MappingNode):
            first: dict[tuple[str, str], int] = {}
            for key, value in n.value:
                if isinstance(key, yaml.ScalarNode) and key.tag != "tag:yaml.org,2002:merge":
                    line = key.start_mark.line + 1
                    if (key.tag, key.value) in first:
                        return f"{key.value!r} at lines {first[key.tag, key.value]} and {line}"
                    first[key.tag, key.value] = line
                stack += [key, value]
        elif isinstance(n, yaml.SequenceNode):
            stack += n.value
    return None


def _yaml_reason(exc: BaseException) -> str:
    """One line for an error of the YAML reader: PyYAML's problem and where, without its quoted snippet."""
    if isinstance(exc, yaml.MarkedYAMLError) and exc.problem_mark is not None:
        mark = exc.problem_mark
        return f"{' '.join(filter(None, (exc.context, exc.problem)))} at line {mark.line + 1}, column {mark.column + 1}"
    return " ".join(str(exc).split())[:200]


def parse_yaml(text: str, source: str) -> Any:
    """The YAML document ``text`` (one), composed and constructed within the bounds of this module;
    :class:`InputError` naming ``source`` in one line for any error of the reader or any bound exceeded."""
    loader = None
    try:
        loader = _BoundedLoader(text)  # its reader refuses control characters here
        node = loader.get_single_node()
        if node is None:
            return None
        expanded_size(node)
        twice = duplicate_key(node)
        if twice is not None:
            raise InputError(f"{source} gives the key {twice} of one mapping; keep one (DVC refuses such a file)")
        return loader.construct_document(node)
    except _Refused as exc:
        raise InputError(f"{source} is refused: {exc}; write the values out plainly") from None
    except (yaml.YAMLError, ValueError, TypeError, OverflowError, RecursionError) as exc:
        raise InputError(f"{source} is not valid YAML: {_yaml_reason(exc)}") from None
    finally:
        if loader is not None:
            loader.dispose()


def load_yaml(path: str | os.PathLike, what: str, max_bytes: int) -> Any:
    """The YAML document in the file ``path``: :func:`read_text`, then :func:`parse_yaml`."""
    return parse_yaml(read_text(path, what, max_bytes), f"{path}")


def checked_path(path: str | os.PathLike, what: str) -> Path:
    """``path`` made absolute with its symlinks resolved; :class:`InputError` naming ``what`` for a symlink loop
    (``Path.resolve`` raises ``RuntimeError`` there) or a path the system cannot resolve."""
    try:
        return Path(path).expanduser().resolve()
    except (RuntimeError, OSError) as exc:
        raise InputError(f"{what} {path} cannot be resolved ({exc}); a symlink loop? point it at a real folder or "
                         "file") from None


def _bytes(n: int) -> str:
    return f"{n >> 30} GiB" if n >= 1 << 30 and n % (1 << 30) == 0 else f"{n >> 20} MiB" if n >= 1 << 20 else f"{n} bytes"
