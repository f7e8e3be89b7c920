"""Headless chromium for the pages this project makes (the report's viewer, the masks page): Debian's chromium
driven by playwright, with no browser download."""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator

INSTALL_HINT = "`apt-get install -y chromium` (make test does this when run as root)"


def find_chromium() -> str | None:
    """``$ABCGS_CHROMIUM``, else ``chromium`` or ``chromium-browser`` on the PATH; None when there is none."""
    return os.environ.get("ABCGS_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")


@contextlib.contextmanager
def launch_chromium(args: list[str], executable: str | None = None) -> Iterator[object]:
    """A playwright ``Browser`` on ``executable`` (default :func:`find_chromium`), closed on exit."""
    from playwright.sync_api import sync_playwright

    exe = executable or find_chromium()
    if exe is None:
        raise RuntimeError(f"chromium is not installed: {INSTALL_HINT}")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=args)
        try:
            yield browser
        finally:
            browser.close()
