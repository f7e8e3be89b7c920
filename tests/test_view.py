"""The viewer page's data (no browser): camera conversion, subsampling, label layer, page assembly."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import torch

from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.errors import InputError
from abcgs.gaussians import GaussianModel
from abcgs.render import sh0_to_rgb
from abcgs.splats.formats.spz import decode_spz
from abcgs.view.page import (
    LABEL_PALETTE,
    label_colored,
    orbit_target,
    prepare_experiment,
    subsample_indices,
    three_camera,
    viewer_page,
)


def _quat_to_matrix(x, y, z, w) -> np.ndarray:
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


@pytest.mark.parametrize("eye", [[0.0, 0.0, -3.0], [1.5, -0.7, -2.0], [-2.0, 1.0, 0.5]])
def test_three_camera_projects_points_where_our_camera_does(eye):
    """A three.js camera (y up, −z forward, vertical fov) built from ours maps world points to the same pixels."""
    w, h = 320, 200
    cam = Camera("c", intrinsics(260.0, w, h), look_at(np.array(eye), np.array([0.2, 0.1, 0.5])), w, h)
    t = three_camera(cam)
    R = _quat_to_matrix(*t["quaternion"])
    pos = np.array(t["position"])
    rng = np.random.default_rng(0)
    pts = np.array([0.2, 0.1, 0.5]) + rng.normal(scale=0.4, size=(50, 3))
    # ours: K [R|t]
    pc = pts @ cam.viewmat[:3, :3].T + cam.viewmat[:3, 3]
    ours = (pc @ cam.K.T)[:, :2] / pc[:, 2:3]
    # three.js: view = inverse(camera world matrix), perspective with fov_y and aspect, NDC → pixels
    v = (pts - pos) @ R  # world → camera (R orthonormal)
    f = 1.0 / np.tan(np.radians(t["fov_y_deg"]) / 2)
    ndc_x = f / t["aspect"] * v[:, 0] / -v[:, 2]
    ndc_y = f * v[:, 1] / -v[:, 2]
    theirs = np.stack([(ndc_x + 1) / 2 * w, (1 - ndc_y) / 2 * h], axis=1)
    np.testing.assert_allclose(theirs, ours, atol=1e-6)
    assert np.allclose(np.linalg.norm(t["quaternion"]), 1.0)


def _model(n=400, seed=0) -> GaussianModel:
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g)
    return GaussianModel(
        means=torch.randn(n, 3, generator=g) + torch.tensor([0.0, 0.0, 4.0]), quats=q / q.norm(dim=1, keepdim=True),
        log_scales=torch.rand(n, 3, generator=g) * 3 - 5, opacity_logits=torch.randn(n, generator=g),
        sh0=torch.rand(n, 1, 3, generator=g), shN=torch.zeros(n, 0, 3),
    )


def test_subsample_keeps_the_most_visible():
    m = _model()
    idx = subsample_indices(m, 100)
    assert len(idx) == 100 and bool((idx[1:] > idx[:-1]).all())
    score = torch.sigmoid(m.opacity_logits) * torch.exp(2 * m.log_scales.max(dim=1).values)
    kept = torch.zeros(m.num_gaussians, dtype=torch.bool)
    kept[idx] = True
    assert float(score[kept].min()) >= float(score[~kept].max())
    assert len(subsample_indices(m, 10_000)) == m.num_gaussians


def test_layers_share_gaussians_and_labels_get_palette_colours():
    m = _model()
    styl = GaussianModel(**{k: getattr(m, k).clone() for k in ("means", "quats", "log_scales", "opacity_logits", "shN")},
                         sh0=torch.zeros_like(m.sh0))
    labels = np.arange(m.num_gaussians) % 3
    cams = [Camera("c", intrinsics(100.0, 64, 48), look_at(np.zeros(3), np.array([0.0, 0.0, 4.0])), 64, 48)]
    exp = prepare_experiment("e", styl, cams, original=m, labels=labels, max_gaussians=50)
    assert set(exp.layers) == {"stylized", "original", "labels"}
    assert torch.equal(exp.layers["original"].means, exp.layers["stylized"].means)
    idx = subsample_indices(styl, 50)
    rgb = sh0_to_rgb(exp.layers["labels"].sh0[:, 0])
    np.testing.assert_allclose(rgb.numpy(), LABEL_PALETTE[labels[idx.numpy()]], atol=1e-6)
    with pytest.raises(InputError, match="labels"):
        label_colored(m, labels[:10])


def test_orbit_target_is_on_the_viewing_axis_at_the_median_depth():
    m = _model()
    cam = Camera("c", intrinsics(100.0, 64, 48), look_at(np.zeros(3), np.array([0.0, 0.0, 1.0])), 64, 48)
    t = orbit_target(m, cam)
    assert np.allclose(t[:2], 0.0, atol=1e-9)
    assert t[2] == pytest.approx(float(np.median(m.means[:, 2].numpy())), rel=1e-6)


def test_page_is_self_contained_and_round_trips_its_splats():
    m = _model()
    cams = [Camera("c", intrinsics(100.0, 64, 48), look_at(np.zeros(3), np.array([0.0, 0.0, 4.0])), 64, 48)]
    html = viewer_page([prepare_experiment("exp<1>", m, cams)], title="t")
    assert "http://" not in html.split("<script>", 1)[0] and "src=" not in html  # nothing fetched
    data = json.loads(re.search(r'id="abcgs-viewer-data">(.*?)</script>', html, re.S).group(1))
    assert data["experiments"][0]["name"] == "exp<1>" and data["experiments"][0]["layers"] == {
        "stylized": "abcgs-splat-0-stylized"}
    b64 = re.search(r'id="abcgs-splat-0-stylized">(.*?)</script>', html, re.S).group(1)
    import base64

    back = decode_spz(base64.b64decode(b64))
    assert back.num_gaussians == m.num_gaussians
    assert "</script" not in html[html.index("<script>") + 8: html.rindex("</script>")]  # the bundle cannot close its tag


def test_embedded_names_cannot_end_or_change_their_script_element():
    m = _model()
    cams = [Camera("c", intrinsics(100.0, 64, 48), look_at(np.zeros(3), np.array([0.0, 0.0, 4.0])), 64, 48)]
    name = "run <!-- <script> </script> & \u2028"
    html = viewer_page([prepare_experiment(name, m, cams)], title="t")
    payload = re.search(r'id="abcgs-viewer-data">(.*?)</script>', html, re.S).group(1)
    assert not set(payload) & set("<>&")  # nothing the HTML parser reads inside a script element
    assert json.loads(payload)["experiments"][0]["name"] == name


def test_view_arguments_are_checked_before_any_work(tmp_path, capsys):
    from abcgs.view.__main__ import main

    for bad in ("-5", "0", "many"):
        with pytest.raises(SystemExit) as exc:
            main([str(tmp_path), "--max-gaussians", bad, "--no-open"])
        assert exc.value.code == 2 and "--max-gaussians" in capsys.readouterr().err
    (tmp_path / "file").write_text("x")
    for out, says in ((tmp_path, "is a folder"), (tmp_path / "file" / "page.html", "not a folder you can write"),
                      (tmp_path / "missing-run" / "p.html", "")):
        assert main([str(tmp_path / "missing-run"), "--out", str(out), "--no-open"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and says in err and len(err.strip().splitlines()) == 1, err
