"""SourceScene readers by registry: every built-in format's module brings a ``READER`` with one signature, found by its
name; :func:`abcgs.sources.read.load` detects, reads and checks; a reader registered at run time is detected, read
and checked like the built-in ones."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from abcgs.cameras import Camera
from abcgs.errors import InputError
from abcgs.sources.base import ReadOptions, SceneReader
from abcgs.sources.read import load, resolve_format
from abcgs.sources.registry import formats, reader_of, register, unregister
from abcgs.types import SourceScene, View


@pytest.mark.parametrize("fmt", formats())
def test_every_built_in_format_has_a_reader_named_like_it(fmt: str):
    reader = reader_of(fmt)
    assert isinstance(reader, SceneReader) and reader.name == fmt and reader.marker


def test_an_unknown_format_names_the_known_ones():
    with pytest.raises(InputError, match="is not one of .*colmap"):
        reader_of("nope")


# ---- a toy format: a JSON list of cameras, one module's worth of code ---------------------------------------------
def _toy_read(folder: Path, options: ReadOptions) -> SourceScene:
    views = []
    for v in json.loads((folder / "toy.json").read_text()):
        K = np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
        viewmat = np.eye(4)
        viewmat[2, 3] = v["z"]
        cam = Camera(v["name"], K, viewmat, 64, 48)
        views.append(View(v["name"], folder / v["name"], cam))
    return SourceScene.from_views(views, format="toy")


TOY = SceneReader("toy", _toy_read, "toy.json", detect=lambda folder: (folder / "toy.json").is_file())


@pytest.fixture
def toy():
    register(TOY)
    try:
        yield TOY
    finally:
        unregister("toy")


def test_a_registered_reader_is_detected_read_and_checked(toy, tmp_path: Path):
    (tmp_path / "toy.json").write_text(json.dumps([{"name": f"{i:03d}.png", "z": 4.0 + i} for i in range(3)]))
    assert resolve_format(tmp_path) == "toy" and "toy" in formats()
    scene = load(tmp_path)
    assert scene.format == "toy" and [v.name for v in scene.views] == ["000.png", "001.png", "002.png"]
    assert [v.name for v in load(tmp_path, "toy").views] == [v.name for v in scene.views]


def test_a_built_in_format_cannot_be_replaced(toy):
    with pytest.raises(ValueError, match="already registered"):
        register(SceneReader("colmap", _toy_read, "x"))
    with pytest.raises(ValueError, match="already registered"):
        register(TOY)


def test_after_unregistering_the_toy_format_is_unknown(tmp_path: Path):
    with pytest.raises(InputError, match="'toy' is not one of"):
        resolve_format(tmp_path, "toy")
