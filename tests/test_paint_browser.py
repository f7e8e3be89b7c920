"""The masks-from-strokes page in a real browser: Debian's chromium driven by playwright (no browser download).

Mouse strokes are drawn on the canvas of a view of the tiny scene (and of its painting), Segment and Save are
pressed, and the label PNGs the server writes are checked against the scene's true labels. Every request the page
makes must go to the local server.

Where chromium is missing these tests skip with the install command, except under CI (``CI`` set), where a
missing browser is a failure (as in tests/test_viewer_browser.py).
"""

from __future__ import annotations

import contextlib
import json
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import launch_chromium

from abcgs.io.images import load_labels
from abcgs.masks.content import label_iou, read_label_files
from abcgs.masks.lifting import NO_VOTE
from abcgs.masks.page.session import PaintSession
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
    assert path.is_file() and sorted(p.name for p in (scene / "masks").iterdir()) == ["000.png", "strokes"]
    assert sorted(p.name for p in (scene / "masks" / "strokes").iterdir()) == ["000.png"]  # the strokes, for the stage
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


def _draw_label_strokes(page, truth: np.ndarray) -> None:
    """Two labels' strokes from ``truth`` drawn with the mouse, then Segment and Save."""
    draw(page, simulated_strokes(truth, 2, radius=1.5), truth.shape[1])
    press(page, "segment", "segmented")
    press(page, "save", "saved")


def test_a_nerfstudio_scene_is_painted_through_images_4(browser, serve, tiny_scene, tmp_path) -> None:
    """data.scenes.ns = {path: a nerfstudio dataset, images: images_4}: the page shows the 40×30 views the pipeline
    reads, saves a 40×30 label map to the scene's masks/, and the reconstruct stage's reader takes it as it is."""
    from test_label_scale import nerfstudio_quarter

    from abcgs.sfm.params import ReconstructParams
    from abcgs.sources.model import write_source_model
    from abcgs.sources.read import read_source

    folder = nerfstudio_quarter(tmp_path / "ns", tiny_scene)
    (tmp_path / "params.yaml").write_text(json.dumps({"data": {"scenes": {"ns": {"path": "ns", "source": {"format": "nerfstudio", "images": "images_4"}}}}}))
    truth = cv2.resize(load_labels(tiny_scene / "masks" / "000.png").astype(np.uint8), (40, 30),
                       interpolation=cv2.INTER_NEAREST).astype(np.int64)
    page, _, errors = open_page(browser, serve(PaintSession.for_params(tmp_path / "params.yaml", "ns")))
    assert page.evaluate("[window.abcgsPaint.state.image.naturalWidth, window.abcgsPaint.state.image.naturalHeight]") \
        == [40, 30]
    assert page.locator("#view option").count() == 16
    _draw_label_strokes(page, truth)
    page.close()
    assert not errors, errors
    saved = load_labels(folder / "masks" / "000.png")
    assert saved.shape == (30, 40) and {1, 2} <= set(np.unique(saved))
    source = read_source(folder, "nerfstudio", images="images_4")
    write_source_model(source, tmp_path / "colmap", ReconstructParams(), masks_dir=folder / "masks")
    assert np.array_equal(load_labels(tmp_path / "colmap" / "masks" / "000.png"), saved)


def test_a_bare_splat_is_painted_on_its_generated_views(browser, serve, tmp_path) -> None:
    """data.scenes.sp = {path: a folder with one splat}: the page shows the views the reconstruct stage rendered
    (out/sp/colmap/images/), saves to the splat's masks/, and the next reconstruct carries them to the masks stage."""
    from test_splats import make_model

    from abcgs.sfm.params import ReconstructParams
    from abcgs.sources.detect import detect_format
    from abcgs.sources.model import write_source_model
    from abcgs.sources.read import read_source
    from abcgs.splats.formats.splat import write_splat_file
    from abcgs.splats.params import SplatViewsParams

    folder = tmp_path / "sp"
    folder.mkdir()
    write_splat_file(folder / "scene.splat", make_model(2500, 0, seed=3))
    views = {"count": 6, "width": 64, "height": 48}
    (tmp_path / "params.yaml").write_text(json.dumps({"data": {"scenes": {"sp": {"path": "sp", "source": {"format": "splat", "views": views}}}}}))
    colmap = tmp_path / "out" / "sp" / "colmap"

    def reconstruct() -> None:  # as stages/reconstruct.py does for a bare splat
        with tempfile.TemporaryDirectory() as work:
            source = read_source(folder, detect_format(folder), views=SplatViewsParams(**views), work=work)
            write_source_model(source, colmap, ReconstructParams(), masks_dir=folder / "masks")

    reconstruct()
    names = sorted(p.name for p in (colmap / "images").iterdir())
    page, _, errors = open_page(browser, serve(PaintSession.for_params(tmp_path / "params.yaml", "sp")))
    assert page.locator("#view option").all_text_contents() == names
    image = cv2.imread(str(colmap / "images" / names[0]))
    truth = np.where(image.max(axis=2) > 20, 1, 2)  # the splat against its background
    _draw_label_strokes(page, truth)
    page.close()
    assert not errors, errors
    saved = load_labels(folder / "masks" / f"{Path(names[0]).stem}.png")
    assert saved.shape == (48, 64) and {1, 2} <= set(np.unique(saved))
    assert detect_format(folder) == "splat"  # masks/ beside the splat keeps it a bare splat scene
    reconstruct()
    assert np.array_equal(load_labels(colmap / "masks" / f"{Path(names[0]).stem}.png"), saved)


def test_two_painted_views_show_their_labels_in_the_strip_of_every_view(browser, serve, tiny_colmap, tmp_path) -> None:
    """With the scene's fit, each Segment carries the labels to every view: the strip shows both painted views'
    labels, and the views no one painted."""
    import math

    from abcgs.gaussians import GaussianModel
    from abcgs.gaussians.ply import write_ply
    from abcgs.masks.page.field_session import THUMB_PHOTO
    from abcgs.sfm.model import read_scene
    from abcgs.viz import LABEL_COLOURS

    scene = read_scene(tiny_colmap)
    model = GaussianModel.from_points(scene.points, scene.colors, init_opacity=0.95)
    model.log_scales = model.log_scales + math.log(3.0)
    write_ply(tmp_path / "fit.ply", model)
    folder = tmp_path / "scene"
    shutil.copytree(tiny_colmap / "images", folder / "images")  # the fit's own (undistorted) views
    session = PaintSession.for_scene(folder)
    assert session.attach_fit(tmp_path / "fit.ply", tiny_colmap), session.field_note
    url = serve(session)
    page, _, errors = open_page(browser, url, viewport=(1280, 1000))
    assert page.locator("#strip figure").count() == 16
    for view in (0, 5):
        truth = load_labels(tiny_colmap / "masks" / f"{view:03d}.png")
        if view:
            page.locator(f"#strip figure[data-item='{view}']").click()
            page.wait_for_function(f"window.abcgsPaint.state.index === {view}")
            page.evaluate("window.scrollTo(0, 0)")  # the strip is below the view: back to the canvas
        draw(page, simulated_strokes(truth, 2, radius=3.0), truth.shape[1])
        press(page, "segment", "segmented")
    page.wait_for_function("document.querySelectorAll('#strip figure.painted').length === 2")
    listing = json.loads(page.evaluate("fetch('/api/strip').then(r => r.text())"))
    assert sorted(v["index"] for v in listing["views"] if v["painted"]) == [0, 5]
    palette = np.array(LABEL_COLOURS[1:4], np.float32)
    for camera in (0, 5, 10):  # both painted views and one no one painted
        png = page.evaluate(f"fetch('/api/strip/{camera}.png').then(r => r.arrayBuffer())"
                            ".then(b => Array.from(new Uint8Array(b)))")
        thumb = cv2.cvtColor(cv2.imdecode(np.array(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        photo = session.field.strip.photos[camera].astype(np.float32)
        colour = (thumb.astype(np.float32) - THUMB_PHOTO * photo) / (1 - THUMB_PHOTO)  # a labelled pixel's colour
        nearest = np.linalg.norm(colour[..., None, :] - palette, axis=-1)
        shown = [int(((nearest.argmin(-1) == k) & (nearest.min(-1) < 8)).sum()) for k in range(3)]
        assert sum(n > 0.05 * thumb.shape[0] * thumb.shape[1] for n in shown) >= 2, (camera, shown)
    page.screenshot(path=str(tmp_path / "paint_strip.png"))
    assert not errors, errors
