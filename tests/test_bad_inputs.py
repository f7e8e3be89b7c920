"""Bad inputs a new user makes, each with the input that caused it: a clear error before the work, or a visible
warning — never a silent substitution. (Cases that need `dvc repro` itself are in tests/test_pipeline_e2e.py.)"""

from __future__ import annotations

import errno
import logging
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from abcgs.errors import InputError, ParamsError, ReconstructionError
from abcgs.features.matching import build_groups
from abcgs.features.params import TransferSpec
from abcgs.features.vgg import VGG16Features, random_state_dict
from abcgs.io.images import save_image, save_labels
from abcgs.params import validate_params
from abcgs.pipeline import StageSpec, run_stage, stage_parser
from abcgs.preflight import check_input_files, check_scene_images, check_scene_masks
from abcgs.sfm.colmap import check_registration
from abcgs.sfm.params import ReconstructParams


def _photo(path: Path, hw=(24, 32), seed=0, grey=False, alpha=False) -> None:
    rng = np.random.default_rng(seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    if grey or alpha:
        from PIL import Image

        arr = (rng.random(hw) * 255).astype(np.uint8)
        img = Image.fromarray(arr, "L") if grey else Image.fromarray(np.dstack([arr] * 4), "RGBA")
        img.save(path)
        return
    save_image(path, rng.random((*hw, 3)).astype(np.float32))


def _scene(root: Path, n=4, **kw) -> Path:
    for k in range(n):
        _photo(root / "images" / f"{k:03d}.png", seed=k, **kw)
    return root


# ------------------------------------------------------------------------------------------- names are identifiers
@pytest.mark.parametrize("section", ["experiments", "scenes", "colormatches"])
def test_names_with_shell_syntax_are_rejected_naming_the_key(section: str) -> None:
    bad = "e; touch /tmp/x #"
    raw = {"data": {"scenes": {"tiny": {"path": "data/tiny"}}, "styles": {"p": "p.png"}},
           "colormatches": {"m": {"scene": "tiny", "style": "p"}},
           "experiments": {"e": {"scene": "tiny", "colormatch": "m"}}}
    if section == "experiments":
        raw["experiments"][bad] = raw["experiments"].pop("e")
    elif section == "colormatches":
        raw["colormatches"][bad] = raw["colormatches"].pop("m")
        raw["experiments"]["e"]["colormatch"] = bad
    else:
        raw["data"]["scenes"][bad] = raw["data"]["scenes"].pop("tiny")
        raw["colormatches"]["m"]["scene"] = raw["experiments"]["e"]["scene"] = bad
    where = "data.scenes" if section == "scenes" else section
    with pytest.raises(ParamsError, match=rf"{where}.*'e; touch /tmp/x #'.* must"):
        validate_params(raw)


def test_an_experiment_naming_a_missing_colour_match_names_the_key() -> None:
    raw = {"data": {"scenes": {"tiny": {"path": "data/tiny"}}, "styles": {}},
           "experiments": {"e": {"scene": "tiny", "colormatch": "nope"}}}
    with pytest.raises(ParamsError, match=r"experiments\.e\.colormatch 'nope' is not in colormatches"):
        validate_params(raw)


# ------------------------------------------------------------------------------------------------- the views
def test_a_view_far_larger_than_the_capture_fails_with_the_knob(tmp_path: Path) -> None:
    images = _scene(tmp_path / "s").joinpath("images")
    _photo(images / "huge.png", hw=(24 * 3, 32 * 3))  # 9x the pixels
    with pytest.raises(InputError, match=r"huge\.png is 96×72, 9× the pixels .* reconstruct\.max_view_size_ratio"):
        check_scene_images("s", images, 4.0)
    assert check_scene_images("s", images, 0.0) == []  # the check can be turned off
    assert check_scene_images("s", images, 10.0) == []


def test_alpha_and_grey_views_are_used_with_a_warning(tmp_path: Path) -> None:
    images = _scene(tmp_path / "s").joinpath("images")
    _photo(images / "cutout.png", alpha=True)
    _photo(images / "grey.png", grey=True)
    warnings = check_scene_images("s", images, 4.0)
    assert any("alpha channel" in w and "cutout.png" in w for w in warnings)
    assert any("grey view" in w and "grey.png" in w for w in warnings)
    assert check_scene_images("s", _scene(tmp_path / "g", grey=True).joinpath("images"), 4.0) == []  # all grey: fine


def test_user_masks_that_match_no_view_are_an_error_not_a_fallback(tmp_path: Path) -> None:
    scene = _scene(tmp_path / "s")
    save_labels(scene / "masks" / "IMG_9999.png", np.ones((24, 32), np.int64))
    with pytest.raises(InputError, match=r"1 of 1 mask file\(s\) .* match no view in images/ \(IMG_9999\.png\)"):
        check_scene_masks("s", scene)
    (scene / "masks" / "IMG_9999.png").unlink()
    save_labels(scene / "masks" / "000.png", np.zeros((24, 32), np.int64))
    with pytest.raises(InputError, match="is all 0"):
        check_scene_masks("s", scene)
    save_labels(scene / "masks" / "000.png", np.eye(24, 32, dtype=np.int64))
    check_scene_masks("s", scene)


def test_unregistered_views_are_named_in_a_warning(caplog) -> None:
    names = [f"{k:03d}.png" for k in range(10)]
    images = {k: SimpleNamespace(name=n, has_pose=n != "007.png") for k, n in enumerate(names)}
    with caplog.at_level(logging.WARNING):
        missing = check_registration(SimpleNamespace(images=images), names, ReconstructParams())
    assert missing == ["007.png"]
    assert "1 of 10 views did not register" in caplog.text and "007.png" in caplog.text


def test_identical_photos_say_the_camera_never_moved(tmp_path: Path) -> None:
    images = tmp_path / "images"
    for k in range(6):
        _photo(images / f"{k:03d}.png", seed=0)
    names = sorted(p.name for p in images.iterdir())
    with pytest.raises(ReconstructionError, match="camera never moved"):
        check_registration(None, names, ReconstructParams(), images)
    for k in range(6):
        _photo(images / f"{k:03d}.png", seed=k)
    with pytest.raises(ReconstructionError, match="more overlap"):
        check_registration(None, names, ReconstructParams(), images)


# ---------------------------------------------------------------------------------------- paintings and weights
def test_paintings_and_weights_are_checked_before_any_fit(tmp_path: Path) -> None:
    _scene(tmp_path / "scene")
    _photo(tmp_path / "out" / "tiny" / "p.png", hw=(64, 64))
    with pytest.raises(InputError, match=r"data\.styles\.p: out/tiny/p\.png lies in out/"):
        check_input_files(validate_params({"data": {"scenes": {"s": "scene"}, "styles": {"p": "out/tiny/p.png"}}}),
                          tmp_path)
    _photo(tmp_path / "one.png", hw=(1, 1))
    with pytest.raises(InputError, match=r"one\.png is 1×1 pixels"):
        check_input_files(validate_params({"data": {"scenes": {"s": "scene"}, "styles": {"p": "one.png"}}}), tmp_path)
    with pytest.raises(InputError, match=r"vgg\.path: missing\.pth does not exist"):
        check_input_files(validate_params({"data": {"scenes": {"s": "scene"}}, "vgg": {"path": "missing.pth"}}),
                          tmp_path)


def test_semantic_auto_binding_with_an_empty_painting_region_is_an_error(tmp_path: Path) -> None:
    img = np.random.default_rng(0).random((64, 64, 3)).astype(np.float32)
    save_image(tmp_path / "p.png", img)
    labels = np.ones((64, 64), np.int64)
    labels[:, 32:] = 2
    save_labels(tmp_path / "p_labels.png", labels)
    vgg = VGG16Features(random_state_dict(0), ["relu3_1"])
    spec = TransferSpec(scene="s", transfer="semantic", style="p", binding="auto")
    paths, masks = {"p": str(tmp_path / "p.png")}, {"p": str(tmp_path / "p_labels.png")}
    with torch.no_grad():
        groups = build_groups(spec, paths, masks, {1, 2}, vgg, style_height=64, layers=["relu3_1"])
        assert [g.content_label for g in groups] == [1, 2]
        with pytest.raises(InputError, match=r"no region for content label\(s\) \[3\].*binding: \{3: 1\}"):
            build_groups(spec, paths, masks, {1, 2, 3}, vgg, style_height=64, layers=["relu3_1"])
        explicit = TransferSpec(scene="s", transfer="semantic", style="p", binding={1: 1, 2: 2, 3: 1})
        assert len(build_groups(explicit, paths, masks, {1, 2, 3}, vgg, style_height=64, layers=["relu3_1"])) == 3


# ---------------------------------------------------------------------------------------------- a full disk
def test_a_full_disk_is_a_message_not_a_traceback(tmp_path: Path, capsys) -> None:
    (tmp_path / "params.yaml").write_text("data: {scenes: {s: {path: s}}}\n")
    spec = StageSpec("fit")

    def main(args, params):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "out" / "point_cloud.ply"))

    (tmp_path / "stamp.json").write_text("{}")
    argv = ["--params", str(tmp_path / "params.yaml"), "--preflight", str(tmp_path / "stamp.json")]
    assert run_stage(spec, stage_parser(spec, "t"), main, argv) == 2
    err = capsys.readouterr().err
    assert "No space left on device writing" in err and "dvc gc" in err and "Traceback" not in err
