"""Masks from strokes (abcgs.masks.page): GrabCut per label from a few strokes, the saved label PNGs, the JSON API.

The page itself is driven in a browser by tests/test_paint_browser.py.
"""

from __future__ import annotations

import http.client
import http.cookiejar
import json
import re
import subprocess
import sys
import threading
import urllib.error
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest

from abcgs.errors import InputError
from abcgs.io.images import save_image
from abcgs.masks.content import label_iou, read_label_files
from abcgs.masks.grabcut import fill_gaps, gmm_log_density, segment
from abcgs.masks.page.command import main
from abcgs.masks.page.server import make_server, page_url
from abcgs.masks.page.session import PaintSession
from abcgs.masks.strokes import BACKGROUND, Stroke, rasterize_strokes
from abcgs.viz import LABEL_COLOURS, colorize_labels

H, W = 120, 160


def two_shapes(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A textured background (label 3), a red disc (1) and a blue rotated box with stripes (2), with pixel noise.

    Returns ``(H, W, 3) uint8`` RGB and the true labels ``(H, W) int64``.
    """
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    img = np.stack([90 + 50 * xx / W, 140 - 30 * yy / H, 80 + 40 * np.sin(xx / 9.0) * np.cos(yy / 11.0)], -1)
    for _ in range(40):  # blobs, some in colours near the shapes' (a brownish red, a slate blue)
        c = [(170, 85, 70), (80, 90, 150), (200, 190, 120), (60, 100, 60)][rng.integers(4)]
        cv2.circle(img, (int(rng.integers(W)), int(rng.integers(H))), int(rng.integers(3, 9)), c, -1)
    truth = np.full((H, W), 3, np.int64)
    disc = (xx - 48) ** 2 + (yy - 58) ** 2 < 26**2
    img[disc] = [200, 50, 45]
    img[disc & (np.hypot(xx - 40, yy - 50) < 9)] = [235, 150, 60]  # a highlight of another colour
    box = np.zeros((H, W), np.uint8)
    cv2.fillPoly(box, [cv2.boxPoints(((115, 62), (44, 70), 20)).astype(np.int32)], 1)
    box = box.astype(bool)
    stripes = (np.sin((xx + yy) / 3.0) > 0)
    img[box] = [40, 70, 190]
    img[box & stripes] = [70, 110, 220]
    truth[disc], truth[box] = 1, 2
    img = img + rng.normal(0, 10, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8), truth


def line(label: int, *xy: float, radius: float = 3.0) -> Stroke:
    return Stroke(label, np.array(xy, float).reshape(-1, 2), radius)


# ≤ 3 strokes per label, each well inside its region
SHAPE_STROKES = [line(1, 35, 58, 62, 58), line(1, 48, 45, 48, 72),
                 line(2, 110, 45, 120, 80), line(2, 104, 62, 126, 60)]
BACKGROUND_STROKES = [line(3, 8, 8, 150, 8), line(3, 8, 112, 150, 112), line(3, 80, 20, 80, 100)]


def test_a_few_strokes_per_label_cut_two_shapes_and_the_background() -> None:
    img, truth = two_shapes()
    seg = segment(img, SHAPE_STROKES + BACKGROUND_STROKES)
    assert seg.labels.shape == (H, W) and seg.labels.dtype == np.int64
    iou = label_iou(seg.labels, truth, 3)
    assert all(v >= 0.9 for v in iou.values()), iou
    assert set(seg.probability) == {1, 2, 3} and all(p.shape == (H, W) for p in seg.probability.values())


def test_the_background_brush_leaves_the_rest_unassigned() -> None:
    img, truth = two_shapes()
    bg = [Stroke(BACKGROUND, s.points, s.radius) for s in BACKGROUND_STROKES]
    seg = segment(img, SHAPE_STROKES + bg)
    iou = label_iou(seg.labels, np.where(truth == 3, 0, truth), 2)
    assert iou[1] >= 0.9 and iou[2] >= 0.9, iou
    assert (seg.labels[truth == 3] == 0).mean() > 0.95
    assert set(np.unique(seg.labels)) == {0, 1, 2}


def test_one_object_alone_is_cut_from_its_strokes() -> None:
    img, truth = two_shapes()
    seg = segment(img, [s for s in SHAPE_STROKES if s.label == 1])
    assert label_iou(seg.labels, np.where(truth == 1, 1, 0), 1)[1] >= 0.9
    assert set(np.unique(seg.labels)) == {0, 1}


def test_a_seed_raster_works_like_strokes_and_large_views_are_cut_smaller() -> None:
    img, truth = two_shapes()
    strokes = SHAPE_STROKES + BACKGROUND_STROKES
    seeds = rasterize_strokes(strokes, (H, W))
    assert np.array_equal(segment(img, seeds).labels, segment(img, strokes).labels)
    small = segment(img, strokes, max_side=100)  # cut at 100x75, labels scaled back up
    assert small.labels.shape == (H, W)
    assert all(v >= 0.85 for v in label_iou(small.labels, truth, 3).values())


def test_gaps_take_the_label_around_them_nearest_in_colour() -> None:
    """Two regions with strokes and an unclaimed gap between them, in the second region's colour."""
    lab = np.zeros((20, 30, 3), np.float32)
    lab[:, 12:] = [60, 20, -10]
    labels = np.zeros((20, 30), np.int64)
    labels[:, :10], labels[:, 20:] = 1, 2
    claimed = labels > 0
    seeds = np.full((20, 30), -1, np.int64)
    seeds[5, 2:8], seeds[5, 22:28] = 1, 2
    out, after = fill_gaps(labels, claimed, lab, seeds)
    assert (out[:, 10:20] == 2).all() and (out[:, :10] == 1).all() and after.all()
    inside = labels.copy()  # a hole inside region 1 takes 1, whatever its colour
    inside[8:12, 3:6] = 0
    lab2 = lab.copy()
    lab2[8:12, 3:6] = [60, 20, -10]
    assert (fill_gaps(inside, inside > 0, lab2, seeds)[0][8:12, 3:6] == 1).all()


def test_without_fill_the_gaps_stay_unassigned() -> None:
    img, truth = two_shapes()
    strokes = [line(1, 35, 58, 62, 58), line(2, 110, 45, 120, 80), line(3, 8, 8, 12, 8, radius=1)]
    filled, gaps = segment(img, strokes), segment(img, strokes, fill=False)
    assert (gaps.labels == 0).any() and not (filled.labels == 0).any()
    assert np.array_equal(filled.labels[gaps.labels > 0], gaps.labels[gaps.labels > 0])
    # what no cut claimed is marked: undecided, not unassigned
    assert filled.claimed.all() and np.array_equal(gaps.claimed, gaps.labels > 0)


def test_the_cuts_run_side_by_side_give_what_one_after_another_gives(monkeypatch) -> None:
    import abcgs.masks.grabcut as grabcut

    img, _ = two_shapes(3)
    side_by_side = segment(img, SHAPE_STROKES + BACKGROUND_STROKES + [line(0, 150, 60, 155, 60)])

    class OneAfterAnother:
        def __init__(self, max_workers: int) -> None:
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc) -> None:
            pass

        def map(self, fn, items):
            return map(fn, items)

    monkeypatch.setattr(grabcut, "ThreadPoolExecutor", OneAfterAnother)
    serial = segment(img, SHAPE_STROKES + BACKGROUND_STROKES + [line(0, 150, 60, 155, 60)])
    assert np.array_equal(side_by_side.labels, serial.labels)
    assert np.array_equal(side_by_side.claimed, serial.claimed)
    assert side_by_side.probability.keys() == serial.probability.keys() == {1, 2, 3}
    assert all(np.array_equal(side_by_side.probability[k], serial.probability[k]) for k in serial.probability)


def test_rasterize_strokes_paints_labels_in_order() -> None:
    seeds = rasterize_strokes([line(2, 10, 10, 30, 10, radius=2), line(0, 20, 5, 20, 15, radius=1),
                               Stroke(5, np.array([[40.0, 30.0]]), 3)], (40, 50))
    assert seeds.dtype == np.int64 and seeds.shape == (40, 50)
    assert seeds[10, 12] == 2 and seeds[10, 20] == 0  # the later background stroke crosses the first
    assert seeds[29, 39] == 5 and seeds[0, 0] == -1
    assert (seeds == 2).sum() > 2 * 20


def test_label_colours_cycle_past_the_end_and_the_page_overlay_uses_them() -> None:
    from abcgs.masks.page.server import overlay_rgba

    n = len(LABEL_COLOURS)
    lab = np.array([[0, 1, n - 1, n]])
    col = colorize_labels(lab)
    assert (col[0, 0] == 0).all() and np.array_equal(col[0, 2], LABEL_COLOURS[n - 1])
    assert np.array_equal(col[0, 3], LABEL_COLOURS[1])  # past the end: from label 1's colour on
    assert np.array_equal(overlay_rgba(lab)[..., :3], col)


def test_gmm_log_density_reads_opencv_models() -> None:
    from scipy.stats import multivariate_normal

    rng = np.random.default_rng(1)
    means = rng.uniform(0, 255, (5, 3))
    covs = [np.diag(rng.uniform(20, 200, 3)) for _ in range(5)]
    weights = np.array([0.4, 0.3, 0.2, 0.1, 0.0])
    model = np.concatenate([weights, means.reshape(-1), np.stack(covs).reshape(-1)])[None]
    x = rng.uniform(0, 255, (50, 3))
    want = np.log(sum(w * multivariate_normal(m, c + np.eye(3) * 1e-2).pdf(x)
                      for w, m, c in zip(weights, means, covs) if w > 0))
    assert np.allclose(gmm_log_density(model, x), want, rtol=1e-6)


def test_segment_errors_say_what_to_do() -> None:
    img, _ = two_shapes()
    with pytest.raises(InputError, match="no label strokes"):
        segment(img, [Stroke(BACKGROUND, np.array([[5.0, 5.0]]), 3)])
    with pytest.raises(InputError, match="seed map"):
        segment(img, np.zeros((10, 10), int))
    with pytest.raises(InputError, match="stroke"):
        Stroke.from_json({"label": 1, "points": "nowhere"})


@pytest.mark.parametrize("label, why", [(2.7, "must be an integer, not 2.7"), (float("inf"), "must be an integer"),
                                        (True, "must be an integer, not true"), ("2", "must be an integer"),
                                        (255, r"outside 0\.\.254"), (-1, r"outside 0\.\.254"),
                                        (10**400, r"outside 0\.\.254")])
def test_a_stroke_label_is_an_integer_0_to_254_and_says_so(label, why) -> None:
    """A label that is a float (2.7 would silently be 2; 1e400, read as inf, overflowed into a 500), a bool, a string
    or out of range is refused in one line (the page's server answers 400 with it)."""
    with pytest.raises(InputError, match=why):
        Stroke.from_json({"label": label, "points": [[1.0, 2.0]]})
    with pytest.raises(InputError, match="stroke"):
        Stroke.from_json({"label": 1, "points": [[10**400, 2]]})
    assert Stroke.from_json({"label": 254, "points": [[1.0, 2.0]]}).label == 254


# ----------------------------------------------------------------------------------------------
# Saving and the session
# ----------------------------------------------------------------------------------------------


def make_scene(root: Path, n: int = 3) -> Path:
    for i in range(n):
        img, _ = two_shapes(seed=i)
        save_image(root / "images" / f"view{i:02d}.png", img)
    return root


def test_save_writes_label_pngs_of_the_views_with_strokes_that_read_back(tmp_path) -> None:
    scene = make_scene(tmp_path / "scene")
    s = PaintSession.for_scene(scene)
    assert [it.name for it in s.items] == ["view00.png", "view01.png", "view02.png"]
    s.set_strokes(0, SHAPE_STROKES + BACKGROUND_STROKES)
    s.set_strokes(2, SHAPE_STROKES)
    written = s.save()  # cuts both first
    assert written == [scene / "masks" / "view00.png", scene / "masks" / "view02.png"]
    assert not (scene / "masks" / "view01.png").exists()  # no strokes, no file
    maps, palette = read_label_files(written, [(H, W)] * 2)
    assert palette == {}  # numbered, single-channel
    assert np.array_equal(maps[0], s.items[0].result.labels) and np.array_equal(maps[1], s.items[2].result.labels)
    assert set(np.unique(maps[0])) == {1, 2, 3}
    assert cv2.imread(str(written[0]), cv2.IMREAD_UNCHANGED).ndim == 2
    assert not list((scene / "masks").glob(".*"))  # atomic writes leave no temporaries
    state = s.state()
    assert [it["saved"] for it in state["items"]] == [True, False, True] and state["n_labels"] == 3


def test_scene_and_painting_errors(tmp_path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"no scene found \(it is empty\); put the photos in .*empty/images/"):
        PaintSession.for_scene(tmp_path / "empty")
    with pytest.raises(InputError, match="does not exist"):
        PaintSession.for_scene(tmp_path / "nowhere")
    save_image(tmp_path / "p.png", two_shapes()[0])
    with pytest.raises(InputError, match=".png"):
        PaintSession.for_painting(tmp_path / "p.png", tmp_path / "p_labels.jpg")
    assert PaintSession.for_painting(tmp_path / "p.png").items[0].out_path == tmp_path / "p_labels.png"
    s = PaintSession.for_scene(make_scene(tmp_path / "scene", 1))
    with pytest.raises(InputError, match="nothing to save"):
        s.save()


def test_the_views_are_the_ones_the_pipeline_reads(tmp_path, capsys) -> None:
    """An ``images_N`` folder (given, or a params scene's ``images:``), and a bare splat's generated views, with
    their label maps in the scene's masks/."""
    scene = make_scene(tmp_path / "scene", 2)
    small = tmp_path / "scene" / "images_2"
    small.mkdir()
    for p in (scene / "images").iterdir():
        save_image(small / p.name, cv2.resize(cv2.imread(str(p))[..., ::-1], (W // 2, H // 2)))
    s = PaintSession.for_scene(scene, images="images_2")
    assert [it.image_path for it in s.items] == sorted(small.iterdir()) and s.size(0) == (H // 2, W // 2)
    assert s.items[1].out_path == scene / "masks" / "view01.png"
    (tmp_path / "params.yaml").write_text(json.dumps({"data": {"scenes": {
        "s": {"path": "scene", "source": {"images": "images_2"}}, "sp": {"path": "splat"}}}}))
    assert [it.image_path for it in PaintSession.for_params(tmp_path / "params.yaml", "s").items] == sorted(small.iterdir())
    (tmp_path / "splat").mkdir()
    (tmp_path / "splat" / "model.spz").write_bytes(b"")
    with pytest.raises(InputError, match=r"holds no views yet: run dvc repro reconstruct@sp first"):
        PaintSession.for_params(tmp_path / "params.yaml", "sp")
    assert main(["--scene", "sp", "--params", str(tmp_path / "params.yaml"), "--no-open"]) == 2
    assert "dvc repro reconstruct@sp" in capsys.readouterr().err
    with pytest.raises(InputError, match=r"is a bare splat: its views are the ones the reconstruct stage"):
        PaintSession.for_scene(tmp_path / "splat")
    views = tmp_path / "out" / "sp" / "colmap" / "images"
    views.mkdir(parents=True)
    save_image(views / "view_000.png", two_shapes()[0])
    (tmp_path / "splat" / "masks").mkdir()  # label maps beside the splat: still a bare splat scene
    s = PaintSession.for_params(tmp_path / "params.yaml", "sp")
    assert [(it.image_path, it.out_path) for it in s.items] == [(views / "view_000.png",
                                                                  tmp_path / "splat" / "masks" / "view_000.png")]
    with pytest.raises(InputError, match="no scene 'x'"):
        PaintSession.for_params(tmp_path / "params.yaml", "x")


def test_cli_explains_a_missing_images_folder(tmp_path, capsys) -> None:
    assert main([str(tmp_path), "--no-open"]) == 2
    assert f"put the photos in {tmp_path / 'images'}/" in capsys.readouterr().err
    assert main(["--no-open"]) == 2
    assert "--painting" in capsys.readouterr().err


# ----------------------------------------------------------------------------------------------
# The JSON API
# ----------------------------------------------------------------------------------------------


OPENER = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(http.cookiejar.CookieJar()))
"""A browser's memory for :func:`request`: the cookie the page's address (with its token) sets."""


@pytest.fixture()
def served(tmp_path):
    def start(session: PaintSession) -> str:
        server = make_server(session, port=0)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        servers.append(server)
        with OPENER.open(page_url(server), timeout=60) as r:  # as a browser opens the printed address
            assert r.status == 200
        return f"http://127.0.0.1:{server.server_port}"

    servers: list = []
    yield start
    for server in servers:
        server.shutdown()
        server.server_close()


def request(url: str, body: dict | None = None) -> tuple[int, bytes, str]:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json"} if data else {})
    try:
        with OPENER.open(req, timeout=60) as r:
            return r.status, r.read(), r.headers["Content-Type"]
    except urllib.error.HTTPError as e:
        return e.code, e.read(), e.headers["Content-Type"]


def test_the_api_takes_strokes_cuts_and_saves(tmp_path, served) -> None:
    scene = make_scene(tmp_path / "scene", 2)
    url = served(PaintSession.for_scene(scene))
    status, page, ctype = request(url + "/")
    assert status == 200 and ctype.startswith("text/html") and b"Segment" in page
    assert b"http://" not in page and b"https://" not in page  # nothing from the network
    state = json.loads(request(url + "/api/state")[1])
    assert state["mode"] == "scene" and [it["name"] for it in state["items"]] == ["view00.png", "view01.png"]
    status, png, ctype = request(url + "/api/image/1")
    assert status == 200 and ctype == "image/png"
    assert cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR).shape == (H, W, 3)

    status, body, _ = request(url + "/api/labels/0.png")
    assert status == 404 and "Segment" in json.loads(body)["error"]
    strokes = [s.to_json() for s in SHAPE_STROKES + BACKGROUND_STROKES]
    status, body, _ = request(url + "/api/strokes/0", {"strokes": strokes})
    assert status == 200 and json.loads(body)["strokes"] == len(strokes)
    assert json.loads(request(url + "/api/strokes/0")[1])["strokes"][0]["label"] == 1
    status, body, _ = request(url + "/api/segment/0", {})
    assert status == 200, body
    result = json.loads(body)
    assert set(result["counts"]) == {"1", "2", "3"} and result["item"]["cut"]
    status, png, _ = request(url + "/api/labels/0.png")
    labels = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert labels.shape == (H, W) and all(v >= 0.9 for v in label_iou(labels, two_shapes(0)[1], 3).values())
    status, png, _ = request(url + "/api/overlay/0.png")
    assert cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED).shape == (H, W, 4)

    status, body, _ = request(url + "/api/segment/1", {})
    assert status == 400 and "no label strokes" in json.loads(body)["error"]
    status, body, _ = request(url + "/api/strokes/0", {"strokes": [{"label": 1}]})
    assert status == 400 and "stroke" in json.loads(body)["error"]
    status, body, _ = request(url + "/api/save", {})
    assert status == 200, body
    assert json.loads(body)["written"] == [str(scene / "masks" / "view00.png")]
    maps, _ = read_label_files([scene / "masks" / "view00.png"], [(H, W)])
    assert np.array_equal(maps[0], labels)
    assert request(url + "/api/nothing")[0] == 404


def test_a_late_stroke_list_of_an_older_revision_is_ignored(tmp_path, served) -> None:
    """The page sends each view's whole list with its revision; one that arrives after a newer one changes nothing."""
    url = served(PaintSession.for_scene(make_scene(tmp_path / "scene", 2)))
    strokes = [s.to_json() for s in SHAPE_STROKES]
    assert json.loads(request(url + "/api/strokes/0")[1]) == {"strokes": [], "revision": 0}
    status, body, _ = request(url + "/api/strokes/0", {"strokes": strokes[:3], "revision": 3})
    assert status == 200 and json.loads(body)["accepted"] and json.loads(body)["revision"] == 3
    status, body, _ = request(url + "/api/strokes/0", {"strokes": strokes[:2], "revision": 2})  # late
    item = json.loads(body)
    assert status == 200 and not item["accepted"] and item["strokes"] == 3 and item["revision"] == 3
    assert json.loads(request(url + "/api/strokes/0")[1])["revision"] == 3
    status, body, _ = request(url + "/api/segment/0", {"strokes": strokes[:1], "revision": 1})  # cuts the newest
    assert status == 200 and json.loads(body)["item"]["strokes"] == 3
    status, body, _ = request(url + "/api/strokes/0", {"strokes": strokes, "revision": 4})
    assert json.loads(body)["strokes"] == len(strokes) and json.loads(body)["stale"]
    for bad in (-1, "5", True, 1.5):
        status, body, _ = request(url + "/api/strokes/1", {"strokes": strokes, "revision": bad})
        assert status == 400 and "revision" in json.loads(body)["error"]


def test_the_api_segments_a_painting_into_its_label_map(tmp_path, served) -> None:
    img, truth = two_shapes(3)
    save_image(tmp_path / "painting.png", img)
    out = tmp_path / "regions" / "painting_labels.png"
    url = served(PaintSession.for_painting(tmp_path / "painting.png", out))
    state = json.loads(request(url + "/api/state")[1])
    assert state["mode"] == "painting" and len(state["items"]) == 1
    strokes = [s.to_json() for s in SHAPE_STROKES + BACKGROUND_STROKES]
    status, body, _ = request(url + "/api/segment/0", {"strokes": strokes})
    assert status == 200, body
    assert json.loads(request(url + "/api/save", {})[1])["written"] == [str(out)]
    maps, _ = read_label_files([out], [(H, W)])
    assert all(v >= 0.9 for v in label_iou(maps[0], truth, 3).values())


# ----------------------------------------------------------------------------------------------
# Only the server's own page drives it
# ----------------------------------------------------------------------------------------------


def raw_request(port: int, method: str, path: str, headers: dict[str, str], body: bytes = b"") -> tuple[int, dict]:
    """One request with exactly these headers (``http.client`` adds none but ``Accept-Encoding``); status, JSON."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    try:
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
        for k, v in headers.items():
            conn.putheader(k, v)
        conn.endheaders()
        try:
            for i in range(0, len(body), 1 << 20):
                conn.send(body[i:i + (1 << 20)])
        except (BrokenPipeError, ConnectionResetError):  # the server answered and closed without reading it all
            pass
        r = conn.getresponse()
        return r.status, json.loads(r.read() or b"{}")
    finally:
        conn.close()


@pytest.fixture()
def paint_process(tmp_path):
    """``python -m abcgs.masks.page SCENE --no-open`` in a process of its own (its memory is measured): port, pid."""
    scene = make_scene(tmp_path / "scene", 1)
    proc = subprocess.Popen([sys.executable, "-m", "abcgs.masks.page", str(scene), "--no-open"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    line = proc.stdout.readline()
    m = re.search(r"http://127\.0\.0\.1:(\d+)/\?token=([\w-]+)", line)
    assert m, line + proc.stdout.read() if proc.poll() is not None else line
    yield int(m.group(1)), m.group(2), proc.pid, scene
    proc.terminate()
    proc.wait(timeout=30)


def _peak_rss_mb(pid: int) -> float:
    status = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(r"VmHWM:\s+(\d+) kB", status).group(1)) / 1024


def test_the_server_refuses_other_pages_hosts_and_bodies(paint_process) -> None:
    port, token, pid, scene = paint_process
    own = {"Host": f"127.0.0.1:{port}", "Content-Type": "application/json", "Cookie": f"abcgs_paint_{port}={token}"}
    strokes = json.dumps({"strokes": [s.to_json() for s in SHAPE_STROKES]}).encode()

    def post(path: str, body: bytes, **headers: str) -> tuple[int, dict]:
        h = {**own, "Content-Length": str(len(body)), **headers}
        return raw_request(port, "POST", path, {k: v for k, v in h.items() if v is not None}, body)

    # without the token (another user of the machine) nothing is served; with it in the address, the page gets it
    for headers in ({"Host": own["Host"]}, {"Host": own["Host"], "Cookie": f"abcgs_paint_{port}=guess"}):
        status, body = raw_request(port, "GET", "/api/state", headers)
        assert status == 403 and "token" in body["error"]
    assert raw_request(port, "GET", f"/api/state?token={token}", {"Host": own["Host"]})[0] == 200
    status, _ = post("/api/save", b"{}", Cookie=None)
    assert status == 403
    # another web page (a cross-origin fetch or form) or a rebound DNS name cannot press Save
    status, body = post("/api/strokes/0", strokes, Origin="http://evil.example")
    assert status == 403 and "http://evil.example" in body["error"]
    status, body = post("/api/save", b"{}", Host=f"evil.example:{port}")
    assert status == 403 and "evil.example" in body["error"]
    assert raw_request(port, "GET", "/api/state", {"Host": f"rebound.example:{port}"})[0] == 403
    status, body = post("/api/strokes/0", strokes, **{"Content-Type": "text/plain"})
    assert status == 415 and "application/json" in body["error"]
    # malformed requests: a 400 with a one-line reason
    for length in ("-1", "abc", str(1 << 40), None, "5" * 5000, "\u00b2", "0"):
        status, body = post("/api/strokes/0", strokes, **{"Content-Length": length})
        assert status == 400 and "\n" not in body["error"] and ("Content-Length" in body["error"] or "larger" in
                                                               body["error"]), (length, body)
    status, body = post("/api/strokes/0", b"", **{"Content-Length": "0"})
    assert status == 400 and body["error"].startswith("Content-Length 0: the request has no body"), body
    status, body = raw_request(port, "GET", "/api/image/" + "9" * 5000, {"Host": own["Host"], "Cookie": own["Cookie"]})
    assert status == 400 and "is not an index of this page's images" in body["error"], body
    for bad in (b"{not json", b"[1, 2]", b'{"strokes": 5}', b'{"strokes": "abc"}', b'{"strokes": [[1, 2]]}',
                b'{"strokes": [{"label": "x", "points": [[1, 2]]}]}', b'{"fill": "yes"}', b"\xff\xfe", b"[" * 100000):
        status, body = post("/api/segment/0", bad)
        assert status == 400 and body["error"] and "\n" not in body["error"], (bad[:40], status, body)
    # a body far larger than its Content-Length claims is not read: the server stays small
    status, _ = post("/api/strokes/0", b"x" * (200 << 20), **{"Content-Length": "-1"})
    assert status == 400
    print(f"paint server peak RSS: {_peak_rss_mb(pid):.0f} MB")
    assert _peak_rss_mb(pid) < 200, f"the server grew to {_peak_rss_mb(pid):.0f} MB"
    assert not (scene / "masks").exists()  # nothing above saved anything
    # the page's own requests still work
    assert post("/api/strokes/0", strokes, Origin=f"http://127.0.0.1:{port}")[0] == 200
    status, body = post("/api/save", b"{}", Origin=f"http://localhost:{port}", Host=f"localhost:{port}")
    assert status == 200 and body["written"] == [str(scene / "masks" / "view00.png")], body


def test_a_photo_size_view_is_cut_at_a_quarter_megapixel_and_its_labels_follow_the_photos_edge(monkeypatch) -> None:
    from abcgs.masks.edges import upsample_labels
    from abcgs.masks.grabcut import WORK_PIXELS

    h, w = 1080, 1920
    yy, xx = np.mgrid[:h, :w]
    truth = np.where(yy > 0.4 * xx + 100, 2, 1)  # a slanted edge between two colours
    img = np.where((truth == 1)[..., None], np.uint8([200, 60, 40]), np.uint8([40, 90, 200])).astype(np.uint8)
    strokes = [Stroke(1, np.array([[1500.0, 200.0], [1800.0, 300.0]]), 12.0),
               Stroke(2, np.array([[200.0, 800.0], [500.0, 1000.0]]), 12.0)]
    sizes = []
    real = cv2.grabCut

    def spy(feats, mask, *args):
        sizes.append(mask.shape)
        return real(feats, mask, *args)

    monkeypatch.setattr(cv2, "grabCut", spy)
    seg = segment(img, strokes)
    assert seg.labels.shape == (h, w) and sizes and all(a * b <= WORK_PIXELS for a, b in sizes), sizes
    wrong = seg.labels != truth
    assert wrong.mean() < 0.002, wrong.mean()  # the border lies on the photo's edge, within a pixel or two
    # a label map at the working size brought back along the edge beats nearest-neighbour scaling
    small = cv2.resize(truth.astype(np.uint8), (682, 384), interpolation=cv2.INTER_NEAREST).astype(np.int64)
    guided, _ = upsample_labels(small, np.ones_like(small, bool), img)
    nearest = cv2.resize(small.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
    assert (guided != truth).sum() < 0.8 * (nearest != truth).sum()  # measured 1577 wrong pixels against 2251
