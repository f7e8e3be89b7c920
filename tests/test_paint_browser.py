"""The masks-from-strokes page in a real browser: Debian's chromium driven by playwright (no browser download).

Mouse strokes are drawn on the canvas of a view of the tiny scene (and of its painting), Segment and Save are
pressed, and the label PNGs the server writes are checked against the scene's true labels. Every request the page
makes must go to the local server.

Where chromium is missing these tests skip with the install command, except under CI (``CI`` set), where a
missing browser is a failure (as in tests/test_viewer_browser.py).
"""

from __future__ import annotations

import contextlib
import shutil
import time

import numpy as np
import pytest
from conftest import launch_chromium

from abcgs.io.images import load_labels
from abcgs.masks.content import label_iou, read_label_files
from abcgs.masks.lifting import NO_VOTE
from abcgs.masks.paint import PaintSession
from eval.bench.paint_iou import simulated_strokes
from eval.bench.paint_page import CHROMIUM_ARGS, draw, open_page, press
from eval.bench.paint_page import serve as serve_page

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def browser():
    with launch_chromium(CHROMIUM_ARGS) as b:
        yield b


@pytest.fixture()
def serve():
    with contextlib.ExitStack() as stack:
        yield lambda session: stack.enter_context(serve_page(session))


def test_strokes_on_a_view_segment_and_save_a_mask(browser, serve, tiny_scene, tmp_path) -> None:
    scene = tmp_path / "scene"
    shutil.copytree(tiny_scene / "images", scene / "images")  # the fixture's own masks/ stay untouched
    truth = load_labels(tiny_scene / "masks" / "000.png")
    url = serve(PaintSession.for_scene(scene))
    page, requests, errors = open_page(browser, url)
    assert page.locator("#view option").count() == 16
    draw(page, simulated_strokes(truth, 3, radius=3.0), truth.shape[1])
    press(page, "segment", "segmented")
    assert "cut" in page.locator("#views li.current").text_content()
    page.screenshot(path=str(tmp_path / "paint_after_segment.png"))
    press(page, "save", "saved")
    page.close()

    path = scene / "masks" / "000.png"
    assert path.is_file() and sorted(p.name for p in (scene / "masks").iterdir()) == ["000.png"]
    labels = read_label_files([path], [truth.shape])[0][0]
    assert set(np.unique(labels)) <= {NO_VOTE, 0, 1, 2, 3} and {1, 2, 3} <= set(np.unique(labels))  # NO_VOTE: undecided
    iou = label_iou(labels, truth, 3)
    assert all(v >= 0.7 for v in iou.values()), iou  # the strokes landed where they were drawn
    assert not errors, errors
    origin = url.split("?", 1)[0]  # the page's address without its token
    assert all(u.startswith((origin, "data:", "blob:")) for u in requests), [u for u in requests
                                                                            if not u.startswith(origin)]


def test_the_painting_mode_writes_its_label_map(browser, serve, tiny_scene, tmp_path) -> None:
    out = tmp_path / "paint_labels.png"
    truth = load_labels(tiny_scene / "styles" / "paint_labels.png")
    url = serve(PaintSession.for_painting(tiny_scene / "styles" / "paint.png", out))
    page, _, errors = open_page(browser, url)
    assert page.locator("#view-nav").is_hidden()
    draw(page, simulated_strokes(truth, 2, radius=4.0), truth.shape[1])
    press(page, "save", "saved")  # Save cuts what has strokes and is not cut yet
    page.close()
    labels = read_label_files([out], [truth.shape])[0][0]
    assert {1, 2, 3} <= set(np.unique(labels))
    iou = label_iou(labels, truth, 3)
    assert all(v >= 0.7 for v in iou.values()), iou
    assert not errors, errors


def test_fast_strokes_while_switching_views_all_reach_a_slow_server(browser, serve, tiny_scene, tmp_path,
                                                                     monkeypatch) -> None:
    """A user who draws 12 quick strokes on a loaded server, switching views between them without waiting for a view
    to load: every stroke is kept, on the server and in the page's view list. The server answers stroke lists after
    a random 0–0.25 s (in threads, so answers come back out of order)."""
    scene = tmp_path / "scene"
    shutil.copytree(tiny_scene / "images", scene / "images")
    session = PaintSession.for_scene(scene)
    rng = np.random.default_rng(0)
    delays = iter(rng.uniform(0.0, 0.25, 1000))
    slow_set = session.set_strokes

    def set_strokes(*args, **kw):
        time.sleep(next(delays))
        return slow_set(*args, **kw)

    monkeypatch.setattr(session, "set_strokes", set_strokes)
    page, _, errors = open_page(browser, serve(session))
    box = page.locator("#canvas").bounding_box()
    for k in range(12):
        if k % 3 == 2:  # switch view, then draw at once (the next view may not have loaded yet)
            page.select_option("#view", index=int(k // 3) % 3)
        y = box["y"] + box["height"] * (0.2 + 0.05 * k)
        page.mouse.move(box["x"] + 10, y)
        page.mouse.down()
        page.mouse.move(box["x"] + box["width"] / 2, y, steps=3)
        page.mouse.up()
    page.wait_for_function("Object.values(window.abcgsPaint.state.views).every((v) => !v.sending)", timeout=30_000)
    local = page.evaluate("Object.fromEntries(Object.entries(window.abcgsPaint.state.views)"
                          ".map(([i, v]) => [i, v.strokes.length]))")
    server = {str(i): len(it.strokes) for i, it in enumerate(session.items) if it.strokes}
    listed = page.evaluate("Array.from(document.querySelectorAll('#views li .tags')).map((t) => t.textContent)")
    shown = page.evaluate("window.abcgsPaint.state.state.items.map((it) => it.strokes)")
    page.close()
    assert sum(server.values()) == 12, server
    assert {i: n for i, n in local.items() if n} == server
    assert [int(t.split(" stroke")[0]) if "stroke" in t else 0 for t in listed] == shown
    assert sum(shown) == 12 and not errors, errors
