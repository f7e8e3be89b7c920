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
