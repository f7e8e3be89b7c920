"""Atomic file and directory writes.

Every artifact a stage produces is written to a temporary sibling and renamed into place, so an
interrupted stage never leaves a half-written file that DVC would cache.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, is_dir: bool = False) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success rename it onto ``path``.

    Works for files and (with ``is_dir=True``) whole directories. On an exception the temporary is
    removed and ``path`` is left as it was.
    """
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    if is_dir:
        tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent))
        os.chmod(tmp, 0o777 & ~_umask())
    else:
        fd, name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".tmp" + final.suffix, dir=final.parent)
        os.close(fd)
        tmp = Path(name)
    try:
        yield tmp
        if is_dir:
            if final.exists():
                backup = final.with_name(f".{final.name}.old")
                if backup.exists():
                    shutil.rmtree(backup)
                final.rename(backup)
                tmp.rename(final)
                shutil.rmtree(backup)
            else:
                tmp.rename(final)
        else:
            os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the file the usual permissions
            os.replace(tmp, final)
    except BaseException:
        if tmp.exists():
            shutil.rmtree(tmp) if tmp.is_dir() else tmp.unlink()
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "item"):  # numpy / torch scalars
        return obj.item()
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _finite(obj: Any) -> Any:
    """Replace non-finite floats by None (JSON has no NaN; DVC's parsers reject it)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def jsonable(data: Any) -> Any:
    """``data`` as plain JSON types (numpy/torch scalars and arrays, paths converted; NaN/inf → None)."""
    return _finite(json.loads(json.dumps(data, default=_json_default)))


def write_json(path: str | os.PathLike, data: Any, *, indent: int = 2) -> None:
    """Write ``data`` (see :func:`jsonable`) as indented JSON, atomically."""
    write_text(path, json.dumps(jsonable(data), indent=indent, sort_keys=False) + "\n")


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8), atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_stream(path: str | os.PathLike, write: Callable[[BinaryIO], object]) -> int:
    """The one atomic byte writer of abcgs's file formats: ``write`` fills a binary file handle (of a temporary
    sibling that is then renamed onto ``path``); returns the file's size in bytes."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            write(fh)
        size = tmp.stat().st_size
    return size


def write_bytes(path: str | os.PathLike, data: bytes) -> int:
    """Write ``data``, atomically (:func:`write_stream`); returns its size in bytes."""
    return write_stream(path, lambda fh: fh.write(data))
