"""Progress output: a redrawn bar in a terminal, one line per interval in a log (abcgs/progress.py)."""

from __future__ import annotations

import io
import time

from abcgs.progress import progress


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_log_gets_few_whole_lines_with_rate_and_postfix(monkeypatch) -> None:
    monkeypatch.setenv("ABCGS_PROGRESS_INTERVAL", "0.05")
    log = io.StringIO()
    bar = progress(range(40), "fit", stream=log)
    for step in bar:
        time.sleep(0.005)
        bar.set_postfix_str(f"loss={1.0 / (step + 1):.3f}", refresh=False)
    bar.close()
    text = log.getvalue()
    lines = text.splitlines()
    assert "\r" not in text and 2 <= len(lines) <= 12, lines  # ~0.2 s of work at 0.05 s per line, plus the last
    assert lines[-1].startswith("fit: 100%") and "40/40" in lines[-1] and "it/s" in lines[-1] and "loss=" in lines[-1]


def test_the_default_log_interval_keeps_a_long_run_short(monkeypatch) -> None:
    monkeypatch.delenv("ABCGS_PROGRESS_INTERVAL", raising=False)
    log = io.StringIO()
    for _ in progress(range(2000), "stylize", stream=log):
        pass
    assert len(log.getvalue().splitlines()) <= 3  # 2000 fast steps: the first and the last line, not 2000


def test_a_terminal_gets_a_redrawn_bar_and_disabled_means_silent() -> None:
    tty = _Tty()
    for _ in progress(range(5), "fit", stream=tty):
        pass
    assert "\r" in tty.getvalue()
    quiet = io.StringIO()
    for _ in progress(range(5), "fit", stream=quiet, enabled=False):
        pass
    assert quiet.getvalue() == ""
