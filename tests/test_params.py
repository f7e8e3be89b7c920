"""params.yaml schema: the shipped file validates; typos and wrong types fail with the key's path and the
allowed keys/values; cross-references (experiments → scenes/styles) are checked; stages exit 2 with the
message instead of a traceback."""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT

from abcgs.errors import ParamsError
from abcgs.params import load_params, validate_params


@pytest.fixture(scope="module")
def raw() -> dict:
    return yaml.safe_load((REPO_ROOT / "params.yaml").read_text())


def _error(raw: dict) -> str:
    with pytest.raises(ParamsError) as exc:
        validate_params(raw)
    return str(exc.value)


def test_shipped_params_validate() -> None:
    params = load_params(REPO_ROOT / "params.yaml")
    assert "tiny" in params.data.scenes
    assert {"tiny_single", "tiny_compositional", "tiny_semantic"} <= set(params.experiments)


def test_unknown_key_names_path_and_allowed_keys(raw) -> None:
    bad = copy.deepcopy(raw)
    bad["fit"]["iteratons"] = 10
    msg = _error(bad)
    assert "fit.iteratons: unknown key" in msg
    assert "iterations" in msg and "sh_degree" in msg  # the allowed keys are listed


def test_nested_unknown_key(raw) -> None:
    bad = copy.deepcopy(raw)
    bad["stylize"]["fast"] = {"kk": 3}
    assert "stylize.fast.kk: unknown key; allowed keys here: cosine, k, eps" in _error(bad)


def test_a_flat_stylize_key_names_its_section(raw) -> None:
    bad = copy.deepcopy(raw)
    bad["stylize"]["lambda_style"] = 3.0
    bad["stylize"]["lr_sh0"] = 0.01
    msg = _error(bad)
    assert "stylize.lambda_style moved to stylize.weights.style" in msg
    assert "stylize.lr_sh0 moved to stylize.optim.lr_sh0" in msg
    bad = copy.deepcopy(raw)
    bad["stylize"]["weights"]["lambda_style"] = 3.0
    assert "stylize.weights.lambda_style: unknown key; allowed keys here: style, content" in _error(bad)


def test_wrong_type_and_literal_values(raw) -> None:
    bad = copy.deepcopy(raw)
    bad["fit"]["sh_degree"] = "two"
    bad["isolation"]["method"] = "blur"
    msg = _error(bad)
    assert "fit.sh_degree" in msg and "'two'" in msg
    assert "isolation.method" in msg and "mirror" in msg and "translate" in msg and "fill" in msg


def test_the_modes_of_abcgs_types_list_their_values(raw) -> None:
    """Every backend setting takes one of the rasterizer's backends, and a scene's format is auto or a known one:
    a typo names the key and the values allowed there."""
    bad = copy.deepcopy(raw)
    bad["stylize"].setdefault("compute", {})["backend"] = "cuda"
    bad["masks"]["backend"] = "gsplatt"
    bad["data"]["scenes"]["tiny"] = {**bad["data"]["scenes"]["tiny"], "source": {"format": "colmapp"}}
    msg = _error(bad)
    for key, got in (("stylize.compute.backend", "cuda"), ("masks.backend", "gsplatt")):
        assert f"{key}: Input should be 'auto', 'reference', 'cpu' or 'gsplat' (got '{got}')" in msg
    assert ("data.scenes.tiny.source: Input tag 'colmapp' found using 'format' does not match any of the expected "
            "tags: 'auto', 'photos', 'colmap', 'nerfstudio', 'llff', 'blender', 'splat'") in msg


def test_a_formats_options_live_in_its_own_section(raw) -> None:
    """A scene's reading options are a tagged union on its format: each format takes its own keys, a key of another
    format is named with the formats that take it, and the flat keys of an entry name the section to write."""
    from abcgs.sources.formats.blender import BlenderSource
    from abcgs.sources.formats.llff import LlffSource
    from abcgs.sources.formats.splat import SplatSource
    from abcgs.sources.params import SceneParams

    entry = SceneParams.model_validate({"path": "d", "source": {"format": "llff", "images": "images_8"}})
    assert isinstance(entry.source, LlffSource) and (entry.format, entry.images, entry.views) == ("llff", "images_8", None)
    entry = SceneParams.model_validate({"path": "d", "source": {"format": "splat", "views": {"count": 5}}})
    assert isinstance(entry.source, SplatSource) and entry.views.count == 5 and entry.images is None
    assert isinstance(SceneParams.model_validate({"path": "d", "source": {"format": "blender"}}).source, BlenderSource)
    assert SceneParams.model_validate({"path": "d"}).format == "auto"
    bad = copy.deepcopy(raw)
    bad["data"]["scenes"]["lego"] = {"path": "data/lego", "source": {"format": "blender", "images": "images_2"}}
    bad["data"]["scenes"]["fern"] = {"path": "data/fern", "format": "llff", "images": "images_8"}
    bad["data"]["scenes"]["bare"] = {"path": "data/bare", "source": {"format": "colmap", "views": {"count": 5}}}
    msg = _error(bad)
    assert ("data.scenes.lego.source.blender.images: unknown key; allowed keys here: format; `images` is an option of "
            "format photos, colmap, nerfstudio, llff, not of blender: remove it, or set `source: {format: photos, "
            "images: ...}`") in msg
    assert ("data.scenes.fern: format, images: a format's options live in the scene's `source:` section, tagged by "
            "the format; write `source: {format: llff, images: images_8}` instead") in msg
    assert "data.scenes.bare.source.colmap.views: unknown key; allowed keys here: images, format; `views` is an " \
           "option of format splat, not of colmap" in msg


def test_out_of_range_value(raw) -> None:
    bad = copy.deepcopy(raw)
    bad["fit"]["sh_degree"] = 7
    assert "fit.sh_degree" in _error(bad)


def test_colormatch_must_name_known_scene_and_styles(raw) -> None:
    bad = copy.deepcopy(raw)
    bad["colormatches"]["x"] = {"scene": "nope", "transfer": "single", "style": "tiny_paint"}
    assert "colormatches.x.scene 'nope' is not in data.scenes" in _error(bad)
    bad["colormatches"]["x"] = {"scene": "tiny", "transfer": "single", "style": "nope"}
    assert "not in data.styles" in _error(bad)
    bad["colormatches"]["x"] = {"scene": "tiny", "transfer": "compositional"}
    assert "needs 'styles'" in _error(bad)
    del bad["colormatches"]["x"]
    bad["colormatches"]["x y"] = {"scene": "tiny", "transfer": "single", "style": "tiny_paint"}
    assert "becomes a folder name" in _error(bad)


def test_experiment_names_a_known_colormatch_on_its_scene(raw) -> None:
    bad = copy.deepcopy(raw)
    bad["experiments"]["x"] = {"scene": "tiny", "colormatch": "nope", "method": "nnfm"}
    assert "experiments.x.colormatch 'nope' is not in colormatches" in _error(bad)
    bad["data"]["scenes"]["other"] = {"path": "data/tiny"}
    bad["experiments"]["x"] = {"scene": "other", "colormatch": "tiny_single", "method": "nnfm"}
    assert "is on scene 'tiny'; make them the same" in _error(bad)
    bad["experiments"]["x"] = {"scene": "tiny", "colormatch": "tiny_single", "method": "adain"}
    assert "experiments.x.method" in _error(bad)


def test_the_old_experiment_layout_says_where_its_keys_went(raw) -> None:
    bad = copy.deepcopy(raw)
    bad["experiments"]["x"] = {"scene": "tiny", "transfer": "single", "style": "tiny_paint", "method": "fast"}
    msg = _error(bad)
    assert "moved to a `colormatches` entry" in msg and "colormatch: NAME" in msg


def test_experiments_differing_in_method_share_one_colormatch(raw) -> None:
    ok = copy.deepcopy(raw)
    ok["experiments"]["tiny_single_nnfm"] = {**ok["experiments"]["tiny_single"], "method": "nnfm"}
    params = validate_params(ok)
    assert params.transfer_of("tiny_single_nnfm") is params.transfer_of("tiny_single")
    spec = params.experiment_specs()["tiny_single_nnfm"]
    assert spec["transfer"] == "single" and spec["style"] == "tiny_paint" and spec["method"] == "nnfm"


def test_missing_section_and_non_mapping() -> None:
    assert "data: required key is missing" in _error({})
    with pytest.raises(ParamsError, match="mapping"):
        validate_params([1, 2])


def _run_fit_stage(tmp_path: Path, params: dict) -> subprocess.CompletedProcess:
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params))
    (tmp_path / "stamp.json").write_text("{}")
    return subprocess.run(
        [sys.executable, str(REPO_ROOT / "stages" / "fit.py"), "--params", str(path), "--scene", "tiny",
         "--preflight", str(tmp_path / "stamp.json"), "--colmap", str(tmp_path / "missing"), "--source", "{item.path}",
         "--out", str(tmp_path / "y"), "--headline", str(tmp_path / "z.json")],
        capture_output=True, text=True, timeout=120,
    )


def test_stage_reports_schema_error_without_traceback(tmp_path, raw) -> None:
    """A stage validates the sections it reads before any work: a mistake there is a message naming the key."""
    bad = copy.deepcopy(raw)
    bad["fit"]["backend"] = "vocab"
    proc = _run_fit_stage(tmp_path, bad)
    assert proc.returncode == 2
    assert "fit.backend" in proc.stderr and "gsplat" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_stage_validates_only_the_sections_it_reads(tmp_path, raw) -> None:
    """A mistake in a section the fit stage does not read is the preflight stage's to report (every stage runs after
    it): the fit stage gets past validation (and fails later, on its missing input folder)."""
    bad = copy.deepcopy(raw)
    bad["reconstruct"]["matcher"] = "vocab"
    with pytest.raises(ParamsError, match="reconstruct.matcher"):
        validate_params(bad)
    proc = _run_fit_stage(tmp_path, bad)
    assert "reconstruct.matcher" not in proc.stderr and "missing" in proc.stderr, proc.stderr


# ------------------------------------------------------------------------------------------------ per-scene overrides
def test_scene_overrides_merge_over_the_global_sections(raw) -> None:
    """data.scenes.<name> carries reconstruct/fit/masks overrides for that scene alone."""
    p = copy.deepcopy(raw)
    p["data"]["scenes"]["big"] = {"path": "data/big", "fit": {"iterations": 3000, "strategy": {"refine_start": 300}},
                                  "masks": {"source": "grabcut", "grabcut": {"box": [0.1, 0.1, 0.9, 0.9]}}}
    params = validate_params(p)
    tiny_fit, big_fit = params.scene_section("tiny", "fit"), params.scene_section("big", "fit")
    assert tiny_fit is params.fit and tiny_fit.iterations == raw["fit"]["iterations"]
    assert big_fit.iterations == 3000 and big_fit.strategy.refine_start == 300
    assert big_fit.strategy.refine_stop == params.fit.strategy.refine_stop  # nested keys merge one by one
    assert big_fit.sh_degree == params.fit.sh_degree and params.fit.iterations == raw["fit"]["iterations"]
    big_masks = params.scene_section("big", "masks")
    assert big_masks.source == "grabcut" and big_masks.grabcut.box == (0.1, 0.1, 0.9, 0.9)
    assert big_masks.lift == params.masks.lift
    assert params.scene_section("big", "reconstruct") is params.reconstruct
    assert params.scene_path("big") == "data/big"
    with pytest.raises(ParamsError, match="not in data.scenes"):
        params.scene_section("nope", "fit")


def test_scene_override_errors_name_the_key_path(raw) -> None:
    p = copy.deepcopy(raw)
    p["data"]["scenes"]["big"] = {"path": "data/big", "fit": {"iteratons": 3000}}
    msg = _error(p)
    assert "data.scenes.big.fit.iteratons: unknown key; allowed keys here: iterations" in msg
    p["data"]["scenes"]["big"] = {"path": "data/big", "fit": {"iterations": "many"}}
    assert "data.scenes.big.fit.iterations: Input should be a valid integer" in _error(p)
    p["data"]["scenes"]["big"] = {"path": "data/big", "stylize": {"iterations": 1}}
    assert "data.scenes.big.stylize: unknown key; allowed keys here: path, source, background, reconstruct, fit, masks" in _error(p)
    p["data"]["scenes"]["big"] = {"fit": {}}
    assert "data.scenes.big.path: required key is missing" in _error(p)
    p["data"]["scenes"]["big"] = "data/big"  # the library's shorthand
    assert validate_params(p).scene_path("big") == "data/big"
