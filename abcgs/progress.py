"""Progress bars that are readable both in a terminal and in a log file.

In a terminal a tqdm bar redraws in place (at most once a second). When the stream is not a terminal (CI,
``nohup``, ``dvc queue`` logs) a redrawn bar turns into thousands of ``\\r``-separated fragments; there
:func:`progress` prints one plain line (count, rate, ETA and the postfix, e.g. the losses) every
``ABCGS_PROGRESS_INTERVAL`` seconds (default 30) and a last line at the end.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable
from typing import IO, Any

from tqdm import tqdm

DEFAULT_LOG_INTERVAL_S = 30.0


class _LineWriter:
    """A file-like object that turns tqdm's ``\\r`` redraws into whole lines."""

    def __init__(self, stream: IO[str]) -> None:
        self.stream = stream

    def write(self, s: str) -> int:
        text = s.replace("\r", "").strip()
        if text:
            self.stream.write(text + "\n")
        return len(s)

    def flush(self) -> None:
        self.stream.flush()


def log_interval_s() -> float:
    """Seconds between progress lines in a non-interactive log (``ABCGS_PROGRESS_INTERVAL``, default 30)."""
    try:
        return max(0.0, float(os.environ.get("ABCGS_PROGRESS_INTERVAL", DEFAULT_LOG_INTERVAL_S)))
    except ValueError:
        return DEFAULT_LOG_INTERVAL_S


def progress(iterable: Iterable, desc: str, *, enabled: bool = True, stream: IO[str] | None = None, **kwargs: Any) -> tqdm:
    """``tqdm(iterable)`` that redraws in a terminal and writes one line per interval elsewhere."""
    stream = stream if stream is not None else sys.stderr
    interactive = bool(getattr(stream, "isatty", lambda: False)())
    if interactive:
        return tqdm(iterable, desc=desc, disable=not enabled, dynamic_ncols=True, mininterval=1.0, file=stream, **kwargs)
    interval = log_interval_s()
    return tqdm(iterable, desc=desc, disable=not enabled, file=_LineWriter(stream), mininterval=interval,
                maxinterval=max(interval, 10.0), ncols=120, ascii=True, **kwargs)
