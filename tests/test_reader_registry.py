"""A scene format is one module: a reader module written into a folder named by ``ABCGS_READERS`` (no file of the
repository edited) is detected at its priority, listed by ``add-scene --help``, validated as a ``source:`` of
``params.yaml`` with its own options model, read by the preflight stage's check with those options and written to the
layout every later stage reads by :func:`abcgs.sources.reconstruct.reconstruct_scene`; the built-in
formats are the modules of ``abcgs/sources/formats`` and nothing else names them."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Literal

import numpy as np
import pytest
from conftest import REPO_ROOT

from abcgs.errors import ParamsError
from abcgs.io.images import save_image
from abcgs.params import validate_params
from abcgs.sources.base import ReadOptions, SceneReader, Source
from abcgs.sources.params import SceneParams
from abcgs.sources.read import loaded
from abcgs.sources.registry import PLUGINS_ENV, formats, reader_of, register, registered, unregister

# A format of cameras on a ring around the origin: ring.json names the views (their images in images/), the scene
# entry's options say the ring's radius and whether the cameras look in (at the centre) or out.
RING_READER = '''
"""Format ``ring``: views on a ring around the origin (ring.json), their images in images/."""

import json
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.sources.base import ReadOptions, SceneReader, Source
from abcgs.types import SourceScene, View


class RingSource(Source):
    format: Literal["ring"] = "ring"
    radius: float = Field(4.0, gt=0, description="the ring's radius (scene units)")
    look: Literal["in", "out"] = Field("in", description="cameras look at the centre (in) or away from it (out)")


def read(folder: Path, options: ReadOptions) -> SourceScene:
    opts = options.source if isinstance(options.source, RingSource) else RingSource()
    names = json.loads((folder / "ring.json").read_text())["views"]
    views = []
    for i, name in enumerate(names):
        a = 2 * np.pi * i / len(names)
        eye = opts.radius * np.array([np.cos(a), 0.0, np.sin(a)])
        target = np.zeros(3) if opts.look == "in" else 2 * eye
        cam = Camera(name, intrinsics(40.0, 32, 24), look_at(eye, target, np.array([0.0, -1.0, 0.0])), 32, 24)
        views.append(View(name, folder / "images" / name, cam))
    return SourceScene.from_views(views, format="ring")


READER = SceneReader("ring", read, "ring.json", detect=lambda folder: (folder / "ring.json").is_file(), priority=5,
                     options=RingSource)
'''

PROBE = '''
import json, sys
from pathlib import Path
from abcgs.errors import InputError, ParamsError
from abcgs.params import validate_params
from abcgs.source_check import check_scene_sources
from abcgs.sources.detect import detect_format

root, scene = Path(sys.argv[1]), sys.argv[2]
out = {"detected": detect_format(root / scene)}
def params(source):
    return {"data": {"scenes": {"r": {"path": scene, "source": source}}}}
p = validate_params(params({"format": "ring", "radius": 3.0}))
out["options"] = p.data.scenes["r"].source.model_dump()
out["checked"] = check_scene_sources(p, root)
for key, source in (("bad_value", {"format": "ring", "radius": -1}), ("bad_key", {"format": "ring", "images": "x"})):
    try:
        validate_params(params(source))
    except ParamsError as exc:
        out[key] = str(exc)
try:
    check_scene_sources(validate_params(params({"format": "ring", "look": "out"})), root)
except InputError as exc:
    out["looking_out"] = str(exc)
from abcgs.sfm.model import read_scene
from abcgs.sources.reconstruct import reconstruct_scene
report = reconstruct_scene(p.data.scenes["r"], root / "layout", folder=root / scene)  # the reconstruct stage's call
back = read_scene(root / "layout")
out["layout"] = {"format": back.format, "views": back.cameras.names, "points": report.metrics()["points_method"],
                 "centre": [round(float(c), 3) for c in back.cameras[0].center]}
print(json.dumps(out))
'''


def _run(args: list[str], plugins: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, PLUGINS_ENV: str(plugins), "PYTHONPATH": str(REPO_ROOT)}
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def _ring_scene(folder: Path, n: int = 6) -> None:
    """A ring scene that also holds images/: a folder of photos to any reader but the ring's."""
    names = [f"{i:02d}.png" for i in range(n)]
    for i, name in enumerate(names):
        save_image(folder / "images" / name, np.full((24, 32, 3), 0.1 * i, np.float32))
    (folder / "ring.json").write_text(json.dumps({"views": names}))


def test_a_reader_module_in_a_plugin_folder_is_a_format_like_the_built_in_ones(tmp_path: Path) -> None:
    plugins = tmp_path / "readers"
    plugins.mkdir()
    (plugins / "ring.py").write_text(RING_READER)
    (plugins / "_notes.py").write_text("raise RuntimeError('a helper module is not imported')\n")
    _ring_scene(tmp_path / "scene")

    help_text = _run(["-m", "abcgs", "add-scene", "--help"], plugins, tmp_path)
    assert help_text.returncode == 0, help_text.stderr
    assert "{auto,photos,colmap,nerfstudio,llff,blender,splat,ring}" in help_text.stdout.replace("\n", "").replace(" ", "")

    probe = _run(["-c", PROBE, str(tmp_path), "scene"], plugins, tmp_path)
    assert probe.returncode == 0, probe.stderr
    out = json.loads(probe.stdout)
    assert out["detected"] == "ring"  # priority 5: before photos, whose images/ the folder also holds
    assert out["options"] == {"format": "ring", "radius": 3.0, "look": "in"} and out["checked"] == []
    assert "data.scenes.r.source.ring.radius: Input should be greater than 0 (got -1)" in out["bad_value"]
    assert ("data.scenes.r.source.ring.images: unknown key; allowed keys here: format, radius, look; `images` is an "
            "option of format photos, colmap, nerfstudio, llff, not of ring") in out["bad_key"]
    assert out["looking_out"].startswith("data.scenes.r: ") and "viewing axes meet behind" in out["looking_out"]
    # the one way in writes its layout with the entry's options (radius 3): the cameras the later stages read
    assert out["layout"]["format"] == "ring" and out["layout"]["views"] == [f"{i:02d}.png" for i in range(6)]
    assert out["layout"]["points"] == "random"  # flat images: nothing to triangulate
    assert np.allclose(out["layout"]["centre"], [3.0, 0.0, 0.0], atol=1e-3), out["layout"]

    without = subprocess.run([sys.executable, "-m", "abcgs", "add-scene", "--help"], cwd=tmp_path, capture_output=True,
                             text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(REPO_ROOT),
                                                          PLUGINS_ENV: ""})
    assert without.returncode == 0 and ",ring}" not in without.stdout.replace("\n", "").replace(" ", "")


def test_a_plugin_module_without_a_reader_or_a_missing_folder_is_named(tmp_path: Path) -> None:
    plugins = tmp_path / "readers"
    plugins.mkdir()
    (plugins / "half.py").write_text("X = 1\n")
    res = _run(["-m", "abcgs", "add-scene", "--help"], plugins, tmp_path)
    assert res.returncode != 0 and f"{PLUGINS_ENV}: {plugins / 'half.py'} defines no READER" in res.stderr
    res = _run(["-m", "abcgs", "add-scene", "--help"], tmp_path / "nowhere", tmp_path)
    assert res.returncode != 0 and f"{PLUGINS_ENV}: {tmp_path / 'nowhere'} is not a folder" in res.stderr


# ---- run-time registration: the same registry, in this process -----------------------------------------------------
class _DotSource(Source):
    format: Literal["dot"] = "dot"
    stride: int = 1


def _dot_read(folder: Path, options: ReadOptions):
    raise AssertionError("not read here")


@pytest.fixture
def dot():
    reader = SceneReader("dot", _dot_read, "scene.dot", detect=lambda folder: (folder / "scene.dot").is_file(),
                         options=_DotSource)
    register(reader)
    try:
        yield reader
    finally:
        unregister("dot")


def test_a_reader_registered_at_run_time_is_listed_validated_and_detected_last(dot, tmp_path: Path) -> None:
    assert formats()[-1] == "dot" and list(registered())[-1] == "dot"  # default order and priority: after built-ins
    entry = SceneParams.model_validate({"path": "d", "source": {"format": "dot", "stride": 2}})
    assert isinstance(entry.source, _DotSource) and entry.source.stride == 2 and entry.format == "dot"
    with pytest.raises(ParamsError, match=r"data\.scenes\.d\.source\.dot\.views: unknown key; allowed keys here: "
                                          r"format, stride; `views` is an option of format splat, not of dot"):
        validate_params({"data": {"scenes": {"d": {"path": "d", "source": {"format": "dot", "views": {}}}}}})
    unregister("dot")
    with pytest.raises(ParamsError, match="Input tag 'dot' found using 'format' does not match any of the expected "
                                          "tags: 'auto', 'photos', 'colmap', 'nerfstudio', 'llff', 'blender', 'splat'"):
        validate_params({"data": {"scenes": {"d": {"path": "d", "source": {"format": "dot"}}}}})
    register(dot)


def test_every_built_in_format_is_a_module_of_the_formats_package() -> None:
    modules = sorted(p.stem for p in (REPO_ROOT / "abcgs" / "sources" / "formats").glob("*.py") if p.stem != "__init__")
    assert modules == ["blender", "colmap", "llff", "nerfstudio", "photos", "splat"]
    assert formats()[:6] == ("photos", "colmap", "nerfstudio", "llff", "blender", "splat")
    code = {"splat": "bare_splat"}  # a module's name says what it reads: a bare splat, not a third splat.py
    for name in modules:  # each declared by its module, its reading code loaded from abcgs.sources.<name> on use
        reader = reader_of(name)
        assert reader.name == name and loaded(reader.read).__module__ == f"abcgs.sources.{code.get(name, name)}"
    assert [n for n, r in registered().items() if r.cameras != "read"] == ["photos", "splat"]
    assert reader_of("photos").reconstruct is not None and reader_of("splat").default_background().object


def test_a_reader_states_its_cameras_consistently() -> None:
    with pytest.raises(ValueError, match="a reconstruct is given exactly when cameras='sfm'"):
        SceneReader("odd", _dot_read, "x", cameras="sfm")
    with pytest.raises(ValueError, match="not auto"):
        SceneReader("auto", _dot_read, "x")


def test_no_stage_branches_on_a_scene_formats_name() -> None:
    """The stages and the viewer ask the reader (its cameras, reconstruct, background), not the format's name."""
    names = "|".join(formats())
    branch = re.compile(rf"""(fmt|format|resolved)\s*(==|!=|in)\s*\(?["']({names})["']""")
    hits = [f"{p.relative_to(REPO_ROOT)}:{i}" for folder in ("stages", "abcgs/view", "abcgs/add.py",
                                                             "abcgs/source_check.py", "abcgs/preflight.py",
                                                             "abcgs/masks/page/session.py", "abcgs/sources/params.py")
            for p in ([REPO_ROOT / folder] if folder.endswith(".py") else sorted((REPO_ROOT / folder).rglob("*.py")))
            for i, line in enumerate(p.read_text().splitlines(), 1) if branch.search(line)]
    assert hits == []
