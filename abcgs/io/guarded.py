"""Opening a file that another tool (or another person) made: the one guarded path every reader of a scene takes.

    data = read_bounded(path, "gsplat checkpoint", 8 << 30)          # bytes, at most 8 GiB
    meta = load_json(path, "cameras.json", 64 << 20)                 # a parsed JSON document, bounded
    doc = load_yaml(path, "params file", 4 << 20)                      # YAML, its aliases expanded under a budget
    rows = load_npy(path, "fitted rows", kinds="iu", ndim=1, max_items=n)  # a .npy array, its header checked first

:func:`regular_file` refuses what is not a regular file before anything opens it: a FIFO (opening one blocks until
a writer comes), a device (``/dev/zero`` reads forever), a folder, a symlink loop or a missing file. The reads are
bounded by the caller's limit (the format's own), and every error of the decoder becomes one
:class:`~abcgs.errors.InputError` line naming the file and the fix. JSON is checked for its nesting depth
(:data:`MAX_JSON_DEPTH`) before it is parsed, so no reader recurses into a hostile document; YAML is composed with
its depth bounded (:data:`MAX_YAML_DEPTH`), its aliases expanded under a node budget (:data:`MAX_YAML_NODES`: an
alias bomb of a few hundred bytes names 10⁹ nodes, which every later walk of the document would visit) and its
numbers bounded in length (:data:`MAX_NUMBER_CHARS`). A ``.npy`` array (:func:`load_npy`) is checked from its
header (dtype, no pickle, dimensions, count against the file's size) before any of it is allocated.
"""

from __future__ import annotations

import errno
import json
import math
import os
import re
import stat
import tokenize
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


MAX_NPY_HEADER = 10_000
"""Longest ``.npy`` header read (bytes; numpy's own default limit): a header of one 1-D array is under 128."""
_NPY_KINDS = {"iu": "integers", "i": "signed integers", "u": "unsigned integers", "f": "floating-point numbers",
              "b": "booleans"}


def load_npy(path: str | os.PathLike, what: str, *, kinds: str, ndim: int, max_items: int, tail: str = ""):
    """The array in the ``.npy`` file ``path``, read through the guarded path: a regular file
    (:func:`regular_file`: not a FIFO, a device such as ``/dev/zero``, a folder or a symlink loop) whose header
    (numpy's ``read_magic`` and ``read_array_header_1_0``/``_2_0``, at most :data:`MAX_NPY_HEADER` bytes) states a
    plain dtype of ``kinds`` (numpy kind letters: ``"iu"`` integers; never an object array, so no pickle is
    loaded), ``ndim`` dimensions and at most ``max_items`` values, checked before anything is allocated; and whose
    size is that header's plus the data it states, exactly (a truncated file, or bytes after the data, are
    refused). :class:`InputError` naming ``what`` and ``path`` in one line otherwise, ``tail`` (what follows, the
    fix) after the reason."""
    import numpy as np  # here: reading params.yaml through this module imports no numpy
    from numpy.lib import format as npy

    size = regular_file(path, what).st_size
    end = f"; {tail}" if tail else ""

    def refuse(reason: str) -> InputError:
        return InputError(f"{what} {path} {reason}{end}")

    if size == 0:
        raise refuse("is empty, not a .npy file")
    try:
        with open(path, "rb") as fh:
            try:
                version = npy.read_magic(fh)
                read_header = {(1, 0): npy.read_array_header_1_0, (2, 0): npy.read_array_header_2_0}.get(version)
                if read_header is None:
                    raise refuse(f"is a .npy file of format version {version[0]}.{version[1]}; abcgs reads 1.0 and "
                                 "2.0 (what numpy.save writes)")
                shape, fortran, dtype = read_header(fh, max_header_size=MAX_NPY_HEADER)
            except InputError:
                raise
            except (ValueError, SyntaxError, TypeError, OverflowError, EOFError, tokenize.TokenError) as exc:
                raise refuse(f"is not a .npy array file ({' '.join(str(exc).split())[:160]})") from None
            if dtype.hasobject:
                raise refuse("holds Python objects, which numpy stores as a pickle; abcgs never loads a pickle")
            if dtype.kind not in kinds or dtype.fields is not None or dtype.subdtype is not None:
                raise refuse(f"holds {dtype} values, not {_NPY_KINDS.get(kinds, f'of the kinds {kinds}')}")
            if len(shape) != ndim or any(d < 0 for d in shape):
                raise refuse(f"holds an array of shape {shape}, not a {ndim}-D one")
            count = math.prod(shape)
            if count > max_items:
                raise refuse(f"states {count} values in its header, more than the {max_items} it can hold here")
            expected = fh.tell() + count * dtype.itemsize
            if size != expected:
                state = "is truncated" if size < expected else f"has {size - expected} bytes after its data"
                raise refuse(f"{state}: it is {size} bytes, its header states {count} values of {dtype.itemsize} "
                             f"bytes, {expected} bytes in all")
            data = fh.read(count * dtype.itemsize)
    except OSError as exc:
        raise InputError(f"{what} {path} cannot be read ({exc.strerror or exc}){end}") from None
    if len(data) != count * dtype.itemsize:
        raise refuse("changed while it was read")
    array = np.frombuffer(data, dtype=dtype, count=count).reshape(shape, order="F" if fortran else "C")
    return array.astype(dtype.newbyteorder("="))  # a writable copy, in the machine's byte order


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
