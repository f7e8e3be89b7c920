"""A scripted user at the masks-from-strokes page (``python -m abcgs.masks.page``), for the browser tests and the
studies that make masks the way a person would: chromium (playwright) presses keys, moves the mouse over the
canvas and clicks the page's buttons; nothing calls the server's API directly.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs.masks.page.server import make_server, page_url
from abcgs.masks.page.session import PaintSession
from abcgs.masks.strokes import Stroke

CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu-sandbox"]
"""Headless chromium flags for the page (no GPU is needed: it draws on a 2-D canvas)."""


@contextlib.contextmanager
def serve(session: PaintSession) -> Iterator[str]:
    """The page's server for ``session`` on a free loopback port, in a thread; yields its URL (with the token)."""
    server = make_server(session, port=0)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        yield page_url(server)
    finally:
        server.shutdown()
        server.server_close()


def open_page(browser, url: str, viewport: tuple[int, int] = (1100, 760)):
    """A new tab on the page, ready to draw; returns ``(page, requests, errors)`` (every URL it asked for, and its
    uncaught JavaScript errors)."""
    page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
    requests: list[str] = []
    errors: list[str] = []
    page.on("request", lambda r: requests.append(r.url))
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    page.wait_for_function("window.abcgsPaint && window.abcgsPaint.ready", timeout=30_000)
    return page, requests, errors


def show_view(page, name: str) -> None:
    """Switch the page to the view named ``name`` (its file name) with the view picker."""
    page.select_option("#view", label=name)
    page.wait_for_function(
        f"window.abcgsPaint.state.state.items[window.abcgsPaint.state.index].name === {name!r}")


def draw(page, strokes: list[Stroke], width: int) -> None:
    """Draw ``strokes`` (image pixel coordinates of an image ``width`` px wide) with the mouse: pick the label by its
    key (B for the background brush), set the brush size, press, move, release."""
    box = page.locator("#canvas").bounding_box()
    scale = box["width"] / width
    before = page.evaluate("window.abcgsPaint.state.state.items[window.abcgsPaint.state.index].strokes")
    for s in strokes:
        page.keyboard.press(str(s.label) if s.label > 0 else "b")
        page.locator("#brush").fill(str(round(s.radius * scale)))  # the slider is in screen pixels
        x, y = s.points[0]
        page.mouse.move(box["x"] + x * scale, box["y"] + y * scale)
        page.mouse.down()
        for x, y in s.points[1:]:
            page.mouse.move(box["x"] + x * scale, box["y"] + y * scale, steps=2)
        page.mouse.up()
    page.wait_for_function(
        f"window.abcgsPaint.state.state.items[window.abcgsPaint.state.index].strokes === {before + len(strokes)}")


def press(page, button: str, done: str, timeout_ms: int = 120_000) -> None:
    """Click ``#<button>`` and wait for the status line to start with ``done``; a status the page marks as an error
    raises with its text."""
    page.click(f"#{button}")
    page.wait_for_function(
        f"(() => {{ const s = document.getElementById('status'); return s.className === 'error' || "
        f"(s.className === 'ok' && s.textContent.startsWith({done!r})); }})()", timeout=timeout_ms)
    status = page.locator("#status")
    if status.get_attribute("class") != "ok":
        raise AssertionError(f"the page says: {status.text_content()}")


def draw_and_save(browser, session: PaintSession, strokes: list[Stroke], width: int, screenshot: Path,
                  view: str | None = None) -> None:
    """As a user: open ``session``'s page (on the view named ``view``, else the first), draw ``strokes`` (pixels of an
    image ``width`` px wide), Segment, take a screenshot to ``screenshot``, Save. Raises when the page raised a
    JavaScript error or asked for anything outside its local server."""
    with serve(session) as url:
        page, requests, errors = open_page(browser, url, viewport=(1280, 820))
        if view is not None:
            show_view(page, view)
        draw(page, strokes, width)
        press(page, "segment", "segmented")
        page.screenshot(path=str(screenshot))
        press(page, "save", "saved")
        page.close()
    if errors:
        raise RuntimeError(f"the page raised: {errors}")
    if not all(u.startswith((url.split("?", 1)[0], "data:", "blob:")) for u in requests):  # the address, no token
        raise RuntimeError("the page asked for something outside the local server")


def report_saved(label_maps: dict[str, Path], work: Path, screenshots: Path | None, prefix: str) -> None:
    """Print each saved label map's share of every label (``label_maps``: what it is → its PNG), and copy the page
    screenshots that :func:`draw_and_save` left in ``work`` (``page_scene.png``, ``page_painting.png``) to
    ``screenshots/<prefix>_<name>.jpg`` when ``screenshots`` is given."""
    import numpy as np

    from abcgs.io.images import load_image, load_labels, save_image

    for what, path in label_maps.items():
        lab = load_labels(path)
        counts = {int(k): round(float((lab == k).mean()), 3) for k in np.unique(lab)}
        print(f"{what}: label shares {counts}")
    if screenshots is not None:
        for name in ("page_scene", "page_painting"):
            save_image(screenshots / f"{prefix}_{name}.jpg", load_image(work / f"{name}.png"))
