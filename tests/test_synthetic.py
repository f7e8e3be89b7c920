"""The embedded synthetic scene: determinism, layout, labels, cameras, paintings."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from pydantic import ValidationError

from abcgs.io.images import list_images, load_image, load_labels
from abcgs.scene.params import TinySceneParams
from abcgs.scene.synthetic import LABEL_NAMES, cameras_from_json, make_tiny_scene, scene_layout

P = TinySceneParams()


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_same_seed_gives_identical_bytes(tiny_scene: Path, tmp_path: Path) -> None:
    again = make_tiny_scene(tmp_path / "again", TinySceneParams())
    assert _files(again) == _files(tiny_scene)


def test_other_seed_differs(tiny_scene: Path, tmp_path: Path) -> None:
    other = make_tiny_scene(tmp_path / "other", TinySceneParams(seed=1, n_views=3))
    assert (other / "images" / "000.png").read_bytes() != (tiny_scene / "images" / "000.png").read_bytes()


def test_layout_and_sizes(tiny_scene: Path) -> None:
    images = list_images(tiny_scene / "images")
    masks = list_images(tiny_scene / "masks")
    assert len(images) == P.n_views
    assert [p.stem for p in images] == [p.stem for p in masks]
    for p in images:
        assert load_image(p).shape == (P.height, P.width, 3)
    for name in ("paint.png", "paint2.png"):
        assert load_image(tiny_scene / "styles" / name).shape[0] == P.style_height
    assert not list(tiny_scene.parent.glob(".tiny.*")), "atomic write left a temporary behind"


def test_masks_are_single_channel_with_all_labels(tiny_scene: Path) -> None:
    for p in list_images(tiny_scene / "masks"):
        raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        assert raw.ndim == 2, f"{p.name} is not single-channel"
        labels = set(np.unique(raw).tolist())
        assert labels == set(LABEL_NAMES), f"{p.name} has labels {labels}"


def test_style_labels_have_three_regions(tiny_scene: Path) -> None:
    paint = load_image(tiny_scene / "styles" / "paint.png")
    labels = load_labels(tiny_scene / "styles" / "paint_labels.png", expect_hw=paint.shape[:2])
    values, counts = np.unique(labels, return_counts=True)
    assert values.tolist() == [1, 2, 3]
    assert counts.min() > 0.1 * labels.size


def test_paintings_have_other_colour_statistics(tiny_scene: Path) -> None:
    def mean_saturation(img: np.ndarray) -> float:
        return float(cv2.cvtColor(img, cv2.COLOR_RGB2HSV)[..., 1].mean())

    scene = np.mean([mean_saturation(load_image(p)) for p in list_images(tiny_scene / "images")])
    for name in ("paint.png", "paint2.png"):
        assert mean_saturation(load_image(tiny_scene / "styles" / name)) > scene + 0.2


def test_cameras_json_matches_images_and_labels(tiny_scene: Path) -> None:
    cams = cameras_from_json(json.loads((tiny_scene / "cameras.json").read_text()))
    assert [c.name for c in cams] == [p.name for p in list_images(tiny_scene / "images")]
    sphere = scene_layout(P).sphere
    for cam in cams:
        R = cam.viewmat[:3, :3]
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) > 0
        assert (cam.width, cam.height) == (P.width, P.height)
        # The sphere's centre projects onto pixels labelled "sphere".
        x = cam.K @ (R @ sphere.center + cam.viewmat[:3, 3])
        u, v = (x[:2] / x[2]).astype(int)
        labels = load_labels(tiny_scene / "masks" / cam.name)
        assert labels[v, u] == 3


def test_params_reject_unknown_fields() -> None:
    with pytest.raises(ValidationError):
        TinySceneParams(n_view=3)
