"""``stylize.grid_views``: which views ``grid.png`` shows (:func:`abcgs.stylize.outputs.grid_indices`)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from abcgs.cameras import Camera, look_at
from abcgs.errors import InputError
from abcgs.features.params import ALL_PIXELS
from abcgs.gaussians import GaussianModel
from abcgs.io.images import load_image
from abcgs.layout import StylizeDir
from abcgs.stylize.outputs import GRID_ROWS, grid_indices, write_stylized_scene
from abcgs.stylize.params import StylizeParams
from abcgs.types import MatchingGroup


def _cameras(n: int = 6, w: int = 40, h: int = 30) -> list[Camera]:
    K = np.array([[40.0, 0, w / 2], [0, 40.0, h / 2], [0, 0, 1]])
    out = []
    for i in range(n):
        a = np.radians(-60 + 120 * i / (n - 1))
        eye = np.array([4 * np.sin(a), -0.5, -4 * np.cos(a)])
        out.append(Camera(f"v{i}.jpg", K, look_at(eye, np.zeros(3)), w, h))
    return out


def test_default_is_the_first_views():
    cams = _cameras()
    assert grid_indices(cams, None) == list(range(GRID_ROWS))
    assert grid_indices(cams[:2], None) == [0, 1]


def test_names_and_stems_in_the_lists_order_once_each():
    cams = _cameras()
    assert grid_indices(cams, ["v5", "v0.jpg", "v3"]) == [5, 0, 3]
    assert grid_indices(cams, ["v4", "v4.jpg", "v1"]) == [4, 1]


def test_names_of_other_scenes_are_skipped_and_none_fails():
    cams = _cameras()
    assert grid_indices(cams, ["other_001", "v2", "other_017.png"]) == [2]
    with pytest.raises(InputError, match=r"names none of this scene's 6 views \(w1, w2\); its views are v0.jpg"):
        grid_indices(cams, ["w1", "w2"])


def test_param_is_a_non_empty_list_or_null():
    assert StylizeParams().grid_views is None
    assert StylizeParams(grid_views=["a", "b.jpg"]).grid_views == ["a", "b.jpg"]
    with pytest.raises(ValidationError):
        StylizeParams(grid_views=[])


def _model(n: int = 300, seed: int = 0) -> GaussianModel:
    g = torch.Generator().manual_seed(seed)
    return GaussianModel(
        means=torch.randn(n, 3, generator=g) * 0.8,
        quats=torch.randn(n, 4, generator=g),
        log_scales=torch.randn(n, 3, generator=g) * 0.3 - 2.5,
        opacity_logits=torch.randn(n, generator=g) + 1,
        sh0=torch.randn(n, 1, 3, generator=g),
        shN=torch.zeros(n, 0, 3),
    )


def test_grid_shows_the_named_views(tmp_path):
    """The grid of views 4 and 1 named is the grid of a scene whose cameras are those two, in that order."""
    cams = _cameras()
    labels = [np.full((c.height, c.width), i % 3 + 1, np.int32) for i, c in enumerate(cams)]
    style = np.random.default_rng(0).random((16, 16, 3)).astype(np.float32)
    groups = [MatchingGroup(ALL_PIXELS, "s", style.reshape(-1, 3), torch.zeros(1, 1), style)]
    model, stylized = _model(), _model(seed=1)
    kw = dict(backend="cpu", path_kind="orbit", path_frames=2)
    write_stylized_scene(tmp_path / "named", stylized, model, cams, labels, groups, grid_views=["v4", "v1.jpg"], **kw)
    pick = [4, 1]
    write_stylized_scene(tmp_path / "two", stylized, model, [cams[i] for i in pick], [labels[i] for i in pick], groups,
                         **kw)
    write_stylized_scene(tmp_path / "first", stylized, model, cams, labels, groups, **kw)
    named, two, first = (load_image(StylizeDir(tmp_path / d).grid) for d in ("named", "two", "first"))
    np.testing.assert_array_equal(named, two)
    assert named.shape[0] < first.shape[0]  # two rows, not three
