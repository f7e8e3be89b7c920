"""Mistakes that used to surface only after the upstream stages had run, now caught first (the ``preflight`` stage,
or the ``colormatch`` stage before any work), and warnings that reach the terminal of ``dvc repro``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import REPO_ROOT, copy_repo, run_in

from abcgs.errors import InputError
from abcgs.io.images import save_image, save_labels
from abcgs.params import validate_params
from abcgs.preflight import check_input_files, dvc_output_files, dvc_outputs
from abcgs.stylize.experiment import check_bindings

PRODUCED = dvc_outputs(REPO_ROOT / "dvc.yaml")
CONTENTS = dvc_output_files(REPO_ROOT / "dvc.yaml")


def _scene(root: Path, labels: list[set[int]] | None = None, grey: int | None = None) -> Path:
    """Four colour views (one grey when ``grey`` is its index) and, with ``labels``, numbered masks holding them."""
    from PIL import Image

    rng = np.random.default_rng(0)
    for k in range(4):
        (root / "images").mkdir(parents=True, exist_ok=True)
        if k == grey:
            Image.fromarray((rng.random((24, 32)) * 255).astype(np.uint8), "L").save(root / "images" / f"{k:03d}.png")
        else:
            save_image(root / "images" / f"{k:03d}.png", rng.random((24, 32, 3)).astype(np.float32))
    for k, values in enumerate(labels or []):
        lab = np.zeros((24, 32), np.int64)
        for i, v in enumerate(sorted(values)):
            lab[i * 4:(i + 1) * 4] = v
        save_labels(root / "masks" / f"{k:03d}.png", lab)
    return root


def _painting(path: Path, hw=(64, 64)) -> str:
    save_image(path, np.random.default_rng(1).random((*hw, 3)).astype(np.float32))
    return str(path)


def _params(tmp_path: Path, colormatch: dict, style_masks: dict | None = None, scene: str = "scene") -> object:
    return validate_params({"data": {"scenes": {"s": {"path": str(tmp_path / scene)}},
                                     "styles": {"p": _painting(tmp_path / "p.png")}, "style_masks": style_masks or {}},
                            "colormatches": {"m": {"scene": "s", **colormatch}}})


# ------------------------------------------------------------------------------------------------ the tiny scene
def test_a_missing_painting_inside_the_tiny_scene_names_its_key_before_the_scene_exists() -> None:
    raw = {"data": {"scenes": {"tiny": {"path": "data/tiny"}},
                    "styles": {"p": "data/tiny/styles/paint.png", "typo": "data/tiny/styles/paint3.png"}}}
    with pytest.raises(InputError, match=r"data\.styles\.typo: data/tiny/styles/paint3\.png is none of the files "
                                         r"the pipeline writes there .*data/tiny/styles/paint2\.png"):
        check_input_files(validate_params(raw), REPO_ROOT, PRODUCED, CONTENTS)
    raw["data"]["styles"].pop("typo")
    raw["data"]["style_masks"] = {"p": "data/tiny/styles/paint_labels.png"}
    assert check_input_files(validate_params(raw), REPO_ROOT, PRODUCED, CONTENTS) == []


def test_make_tiny_writes_the_files_preflight_expects(tiny_scene: Path) -> None:
    from abcgs.scene.params import TINY_STYLE_FILES

    assert sorted(p.relative_to(tiny_scene).as_posix() for p in (tiny_scene / "styles").iterdir()) == \
        sorted(TINY_STYLE_FILES)


# ------------------------------------------------------------------------------------------------ label bindings
def test_a_compositional_binding_to_a_label_no_mask_holds_fails_in_preflight(tmp_path: Path) -> None:
    _scene(tmp_path / "scene", labels=[{1, 2}, {1}])
    params = _params(tmp_path, {"transfer": "compositional", "styles": {1: "p", 3: "p"}})
    with pytest.raises(InputError, match=r"colormatches\.m\.styles binds content label\(s\) \[3\], which the masks in "
                                         r".*scene/masks does not hold \(labels present: \[1, 2\]\)"):
        check_input_files(params, tmp_path)
    check_input_files(_params(tmp_path, {"transfer": "compositional", "styles": {1: "p", 2: "p"}}), tmp_path)


def test_a_semantic_binding_to_an_empty_painting_region_fails_in_preflight(tmp_path: Path) -> None:
    _scene(tmp_path / "scene")
    regions = np.ones((64, 64), np.int64)
    regions[:, 32:] = 2
    save_labels(tmp_path / "p_labels.png", regions)
    masks = {"p": str(tmp_path / "p_labels.png")}
    params = _params(tmp_path, {"transfer": "semantic", "style": "p", "binding": {1: 1, 2: 5}}, masks)
    with pytest.raises(InputError, match=r"colormatches\.m\.binding\.2: painting region 5 has no pixels in "
                                         r".*p_labels\.png \(regions present: \[1, 2\]\)"):
        check_input_files(params, tmp_path)
    check_input_files(_params(tmp_path, {"transfer": "semantic", "style": "p", "binding": {1: 2}}, masks), tmp_path)


def test_the_colormatch_stage_checks_bindings_against_the_lifted_labels_first(tmp_path: Path) -> None:
    """Where preflight cannot know the labels (automatic masks, the tiny scene's), the colour match checks them
    against the masks stage's output before it loads VGG or the scene's views."""
    _scene(tmp_path / "scene")
    lifted = torch.tensor([0, 1, 1, 2, 2, 2])
    params = _params(tmp_path, {"transfer": "compositional", "styles": {1: "p", 4: "p"}})
    check_input_files(params, tmp_path)  # no mask files: nothing to check yet
    with pytest.raises(InputError, match=r"colormatches\.m\.styles binds content label\(s\) \[4\], which the "
                                         r"Gaussians' labels \(out/s/masks/gaussian_labels\.npy\)"):
        check_bindings("m", params.colormatches["m"], lifted, Path("out/s/masks/gaussian_labels.npy"), params.data.style_masks)
    save_labels(tmp_path / "p_labels.png", np.ones((64, 64), np.int64))
    semantic = _params(tmp_path, {"transfer": "semantic", "style": "p", "binding": {3: 1}},
                       {"p": str(tmp_path / "p_labels.png")})
    with pytest.raises(InputError, match=r"colormatches\.m\.binding\.3: content label 3 is not in"):
        check_bindings("m", semantic.colormatches["m"], lifted, Path("out/s/masks/gaussian_labels.npy"),
                       semantic.data.style_masks)
    source = (REPO_ROOT / "stages" / "colormatch.py").read_text()
    assert source.index("check_bindings(") < source.index("load_vgg(")


# ------------------------------------------------------------------------------------------------ said, not silent
def test_label_values_that_skip_numbers_and_resized_style_masks_are_warnings(tmp_path: Path) -> None:
    _scene(tmp_path / "scene", labels=[{1, 2, 7}, {1}])
    save_labels(tmp_path / "p_labels.png", np.ones((30, 90), np.int64))
    params = _params(tmp_path, {"transfer": "single", "style": "p"}, {"p": str(tmp_path / "p_labels.png")})
    warnings = check_input_files(params, tmp_path)
    assert any("label value(s) [1, 2, 7]" in w and "beyond 3 ([7])" in w for w in warnings), warnings
    # 255 is no label but a gap the page's cut left undecided (abcgs.masks.params.UNDECIDED): no warning for it
    _scene(tmp_path / "scene", labels=[{1, 2, 255}, {1}])
    assert not any("label value(s)" in w for w in check_input_files(params, tmp_path))
    assert any("data.style_masks.p" in w and "is 90×30 but its painting" in w and "64×64" in w and "stretched" in w
               for w in warnings), warnings


def test_a_file_size_limit_is_a_message_not_a_traceback(tmp_path: Path) -> None:
    """A real ``EFBIG``: the stage writes past ``ulimit -f`` (Python ignores SIGXFSZ, so the write fails)."""
    (tmp_path / "params.yaml").write_text("data: {scenes: {s: {path: s}}}\n")
    (tmp_path / "stamp.json").write_text("{}")
    code = f"""
import resource, sys
from pathlib import Path
from abcgs.io.atomic import write_text
from abcgs.pipeline import StageSpec, run_stage, stage_parser
resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
spec = StageSpec("fit")
sys.exit(run_stage(spec, stage_parser(spec, "t"), lambda a, p: write_text(Path({str(tmp_path)!r}) / "big.txt",
                   "x" * (1 << 20)), ["--params", {str(tmp_path / "params.yaml")!r},
                   "--preflight", {str(tmp_path / "stamp.json")!r}]))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "File too large" in proc.stderr and "ulimit -f" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "big.txt").exists()  # written atomically: no partial file


def test_preflight_warnings_are_printed_by_dvc_repro(tmp_path: Path) -> None:
    def edit(params: dict) -> None:
        params["data"]["scenes"]["greyish"] = {"path": "scenes/greyish"}

    repo = copy_repo(tmp_path / "repo", edit)
    _scene(repo / "scenes" / "greyish", grey=2)
    proc = run_in(["dvc", "repro", "preflight"], repo, timeout=300)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert "[preflight] warning: data.scenes.greyish: 1 grey view(s) among colour views" in out, out[-3000:]
    assert "greyish" in (repo / "out" / "preflight_report.json").read_text()  # and kept for the report
