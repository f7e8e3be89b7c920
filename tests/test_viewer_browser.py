"""The offline splat viewer in a real browser: Debian's chromium driven by playwright (no browser download).

Checks are made on pixels read back from the canvas (screenshots of the WebGL canvas, drawn with
``preserveDrawingBuffer``), not on the DOM alone. Software WebGL (SwiftShader) renders headless.

Where chromium is missing these tests skip with the install command, except under CI (``CI`` set), where a
missing browser is a failure: ``make test`` installs it (``apt-get install chromium``) when run as root.
"""

from __future__ import annotations

import base64
import io

import numpy as np
import pytest
import torch
from conftest import launch_chromium

from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.gaussians import GaussianModel, render
from abcgs.render import rgb_to_sh0
from abcgs.types import Background
from abcgs.view.page import prepare_experiment, viewer_page

pytestmark = pytest.mark.browser

W, H = 320, 240
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox", "--disable-gpu-sandbox"]


def _scene(seed: int = 0) -> tuple[GaussianModel, GaussianModel, np.ndarray]:
    """A textured wall (colour gradient + stripes) and a ball in front of it; the 'stylized' copy recolours both."""
    g = torch.Generator().manual_seed(seed)
    u, v = torch.meshgrid(torch.linspace(-1.6, 1.6, 48), torch.linspace(-1.2, 1.2, 36), indexing="xy")
    wall = torch.stack([u.reshape(-1), v.reshape(-1), torch.full((u.numel(),), 1.0)], dim=1)
    d = torch.randn(600, 3, generator=g)
    ball = d / d.norm(dim=1, keepdim=True) * 0.45 + torch.tensor([0.5, 0.1, 0.2])
    means = torch.cat([wall, ball])
    n = means.shape[0]
    labels = np.r_[np.zeros(wall.shape[0], int), np.ones(ball.shape[0], int)]
    stripes = (torch.sin(u.reshape(-1) * 9) > 0).float()
    wall_rgb = torch.stack([0.2 + 0.6 * (u.reshape(-1) + 1.6) / 3.2, 0.3 + 0.5 * stripes, 0.8 - 0.5 * (v.reshape(-1) + 1.2) / 2.4], 1)
    ball_rgb = torch.tensor([0.9, 0.2, 0.1]).expand(ball.shape[0], 3)
    rgb = torch.cat([wall_rgb, ball_rgb])
    scales = torch.cat([torch.full((wall.shape[0], 3), 0.045), torch.full((ball.shape[0], 3), 0.05)])
    scales[: wall.shape[0], 2] = 0.005
    q = torch.zeros(n, 4)
    q[:, 0] = 1
    common = dict(means=means, quats=q, log_scales=scales.log(), opacity_logits=torch.full((n,), 4.0),
                  shN=torch.zeros(n, 0, 3))
    original = GaussianModel(sh0=rgb_to_sh0(rgb)[:, None, :], **common)
    styl_rgb = torch.cat([1.0 - wall_rgb, torch.tensor([0.1, 0.3, 0.9]).expand(ball.shape[0], 3)])
    stylized = GaussianModel(sh0=rgb_to_sh0(styl_rgb)[:, None, :], **{k: v.clone() for k, v in common.items()})
    return original, stylized, labels


def _cameras() -> list[Camera]:
    out = []
    for i, eye in enumerate(([0.0, 0.0, -3.0], [0.6, -0.3, -2.9], [-0.6, 0.2, -2.9])):
        vm = look_at(np.array(eye), np.array([0.0, 0.0, 0.6]))
        out.append(Camera(f"view{i}", intrinsics(300.0, W, H), vm, W, H))
    return out


def _page(tmp_path, name="page.html", mutate=None) -> tuple[str, object]:
    original, stylized, labels = _scene()
    exp = prepare_experiment("synthetic", stylized, _cameras(), original=original, labels=labels, max_gaussians=10_000)
    html = viewer_page([exp], max_width=W)
    if mutate:
        html = mutate(html)
    path = tmp_path / name
    path.write_text(html, encoding="utf-8")
    return path.resolve().as_uri(), exp


def _shot(page) -> np.ndarray:
    from PIL import Image

    url = page.evaluate("document.getElementById('abcgs-canvas').toDataURL('image/png')")
    png = base64.b64decode(url.split(",", 1)[1])
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.float32) / 255.0


@pytest.fixture(scope="module")
def browser():
    with launch_chromium(CHROMIUM_ARGS) as b:
        yield b


@pytest.fixture(scope="module")
def viewer(browser, tmp_path_factory):
    """One loaded page shared by the checks below (loading is the slow part under software GL)."""
    url, exp = _page(tmp_path_factory.mktemp("viewer"))
    page = browser.new_page(viewport={"width": W + 40, "height": H + 200})
    requests, errors = [], []
    page.on("request", lambda r: requests.append(r.url))
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    page.wait_for_function("window.abcgsViewer && window.abcgsViewer.ready", timeout=120_000)
    page.evaluate("window.abcgsViewer.ready")
    yield page, exp, requests, errors
    page.close()


def test_loads_from_file_without_network(viewer):
    page, _, requests, errors = viewer
    assert errors == []
    assert page.evaluate("window.abcgsViewer.state.error") is None
    remote = [u for u in requests if not u.startswith(("file:", "data:", "blob:"))]
    assert remote == [], f"the page asked the network for {remote}"
    assert "all 2,328 Gaussians" in page.locator("#abcgs-note").inner_text()  # says how many Gaussians it shows


def test_camera_path_frames_match_our_rasterizer_and_play(viewer):
    """the viewer's ▷ path is the turntable video's path (spiral here: a forward-facing layout)."""
    page, exp, _, _ = viewer
    assert exp.path_kind == "spiral" and len(exp.path) == 48
    page.evaluate("window.abcgsViewer.setMode('stylized'); window.abcgsViewer.setPathFrame(12)")
    page.evaluate("window.abcgsViewer.settle(10)")
    assert page.evaluate("window.abcgsViewer.state.pathFrame") == 12
    assert "spiral path 13/48" in page.locator("#abcgs-camera").inner_text()
    shot = _shot(page)
    img, alpha, _ = render(exp.layers["stylized"], exp.path[12])
    ours = (img + (1 - alpha) * 1.0).clamp(0, 1).numpy()
    r = np.corrcoef(shot.reshape(-1), ours.reshape(-1))[0, 1]
    assert r > 0.95, f"path frame 12: viewer vs our rasterizer, correlation {r:.3f}"
    page.evaluate("window.abcgsViewer.play(true)")
    page.wait_for_function("window.abcgsViewer.state.pathFrame !== 12 && window.abcgsViewer.state.pathFrame !== null",
                           timeout=30_000)
    page.evaluate("window.abcgsViewer.play(false)")
    assert page.evaluate("window.abcgsViewer.state.playing") is False
    page.evaluate("window.abcgsViewer.setCamera(0)")

def test_stylized_render_matches_our_rasterizer(viewer):
    page, exp, _, _ = viewer
    page.evaluate("window.abcgsViewer.setMode('stylized'); window.abcgsViewer.setCamera(1)")
    page.evaluate("window.abcgsViewer.settle(10)")
    shot = _shot(page)
    assert shot.shape[:2] == (H, W)
    background = np.all(shot > 0.97, axis=2)
    assert background.mean() < 0.7, "the canvas is (nearly) blank"
    img, alpha, _ = render(exp.layers["stylized"], exp.cameras[1])
    ours = (img + (1 - alpha) * 1.0).clamp(0, 1).numpy()
    r = np.corrcoef(shot.reshape(-1), ours.reshape(-1))[0, 1]
    assert r > 0.95, f"viewer vs our rasterizer: correlation {r:.3f}"  # measured 0.992–0.995
    assert float(np.abs(shot - ours).mean()) < 0.04  # measured 0.013


def test_toggle_changes_the_picture(viewer):
    page, _, _, _ = viewer
    pics = {}
    for mode in ("stylized", "original", "labels"):
        page.evaluate(f"window.abcgsViewer.setMode('{mode}'); window.abcgsViewer.setCamera(0)")
        page.evaluate("window.abcgsViewer.settle(8)")
        pics[mode] = _shot(page)
        assert page.locator(f"button[data-mode={mode}]").get_attribute("class") == "active"
    assert np.abs(pics["stylized"] - pics["original"]).mean() > 0.15
    assert np.abs(pics["labels"] - pics["original"]).mean() > 0.05
    # the ball is red in the original and blue when stylized, at the same pixels
    ball = pics["original"][..., 0] - pics["original"][..., 2] > 0.5
    assert ball.sum() > 200
    assert pics["stylized"][ball][:, 2].mean() > pics["stylized"][ball][:, 0].mean() + 0.4


def test_orbit_and_camera_steps_change_the_picture(viewer):
    page, _, _, _ = viewer
    page.evaluate("window.abcgsViewer.setMode('stylized'); window.abcgsViewer.setCamera(0)")
    page.evaluate("window.abcgsViewer.settle(8)")
    before = _shot(page)
    page.evaluate("window.abcgsViewer.orbit(0.5)")
    page.evaluate("window.abcgsViewer.settle(8)")
    after = _shot(page)
    assert np.abs(after - before).mean() > 0.03
    page.click("#abcgs-next")
    assert "camera 2/3" in page.locator("#abcgs-camera").inner_text()


def _first_splat(html: str, replacement_b64: str) -> str:
    marker = 'id="abcgs-splat-0-stylized">'
    start = html.index(marker) + len(marker)
    end = html.index("</script>", start)
    return html[:start] + replacement_b64 + html[end:]


@pytest.mark.parametrize(
    "mutate, expected",
    [
        (lambda h: _first_splat(h, base64.b64encode(b"\x1f\x8b garbage, not a splat" * 10).decode()),
         "could not decode the 'stylized' splat"),
        (lambda h: h.replace('id="abcgs-splat-0-original"', 'id="renamed"'), "missing from the page"),
        (lambda h: h.replace('<script type="application/json" id="abcgs-viewer-data">{',
                             '<script type="application/json" id="abcgs-viewer-data">{oops'), "not valid JSON"),
    ],
    ids=["corrupt-splat", "missing-splat", "bad-data"],
)
def test_bad_splat_data_shows_a_readable_error(browser, tmp_path, mutate, expected):
    url, _ = _page(tmp_path, mutate=mutate)
    page = browser.new_page(viewport={"width": W + 40, "height": H + 200})
    try:
        page.goto(url)
        page.wait_for_function("window.abcgsViewer && window.abcgsViewer.state", timeout=60_000)
        page.wait_for_function("window.abcgsViewer.state.error !== null", timeout=120_000)
        box = page.locator("#abcgs-error")
        assert box.is_visible()
        assert expected in box.inner_text()
    finally:
        page.close()


@pytest.mark.parametrize("background", [Background((0.2, 0.4, 0.6), object=True),
                                        Background(transparent=True, object=True)], ids=["colour", "transparent"])
def test_an_object_shows_on_its_background(browser, tmp_path, background):
    """The ball alone (an object on nothing): empty canvas pixels are the scene's background colour, or clear."""
    from PIL import Image

    original, stylized, _ = _scene()
    ball = torch.arange(original.num_gaussians - 600, original.num_gaussians)
    exp = prepare_experiment("object", stylized.index(ball), _cameras(), original=original.index(ball),
                             max_gaussians=10_000, background=background)
    (tmp_path / "object.html").write_text(viewer_page([exp], max_width=W), encoding="utf-8")
    page = browser.new_page(viewport={"width": W + 40, "height": H + 200})
    try:
        page.goto((tmp_path / "object.html").resolve().as_uri())
        page.wait_for_function("window.abcgsViewer && window.abcgsViewer.ready", timeout=120_000)
        page.evaluate("window.abcgsViewer.ready")
        url = page.evaluate("document.getElementById('abcgs-canvas').toDataURL('image/png')")
    finally:
        page.close()
    rgba = np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGBA"), np.float32) / 255
    corner = rgba[:10, :10].reshape(-1, 4)
    if background.transparent:
        assert corner[:, 3].max() == 0.0
    else:
        np.testing.assert_allclose(corner[:, :3], np.broadcast_to(background.color, corner[:, :3].shape), atol=2 / 255)
        assert corner[:, 3].min() == 1.0
    assert (rgba[..., 3] > 0.5).mean() > 0.01  # the ball is drawn
