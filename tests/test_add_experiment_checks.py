"""What the pipeline's stages (or DVC) would refuse later, refused by ``add-experiment`` and by the preflight on a
hand-written ``params.yaml``: labels outside 1 … 254 or absent from the label maps given as files, integers in
other digits than 0-9, and names that DVC or the file system cannot take (a pipeline output's, a stage's, a
scene's, longer than 100 characters). Each is one line on stderr with exit status 2, naming the argument or the
key, and nothing is written (docs/INPUTS.md lists the checks)."""

from __future__ import annotations

import copy
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT

from abcgs.__main__ import main as abcgs_main
from abcgs.add_experiment import KEEP_STRUCTURE_WEIGHT
from abcgs.io.images import save_image, save_labels
from abcgs.preflight import main as preflight_main

SECONDS = 20.0
"""Every refusal comes within this (the command's imports included, in a process of its own)."""


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A scene of photos with numbered masks of labels 1 and 2 (``s``), one without masks (``a``), a painting with
    a region map of regions 1 and 2 (``p``)."""
    root = tmp_path_factory.mktemp("inputs")
    rng = np.random.default_rng(0)
    labels = np.zeros((24, 32), np.int64)
    labels[:8], labels[8:16] = 1, 2
    for k in range(3):
        save_image(root / "s" / "images" / f"{k:03d}.png", rng.random((24, 32, 3)).astype(np.float32))
        save_labels(root / "s" / "masks" / f"{k:03d}.png", labels)
        save_image(root / "a" / "images" / f"{k:03d}.png", rng.random((24, 32, 3)).astype(np.float32))
    save_image(root / "p.png", rng.random((64, 64, 3)).astype(np.float32))
    regions = np.ones((64, 64), np.int64)
    regions[:, 32:] = 2
    save_labels(root / "p_labels.png", regions)
    return root


@pytest.fixture
def repo(tmp_path: Path, inputs: Path) -> Path:
    """A copy of the repository's ``params.yaml`` and ``dvc.yaml`` (the pipeline's stages and outputs), with the
    scenes ``s`` and ``a`` and the painting ``p`` added as add-scene and add-style write them."""
    root = tmp_path / "repo"
    root.mkdir()
    shutil.copy(REPO_ROOT / "dvc.yaml", root / "dvc.yaml")
    raw = yaml.safe_load((REPO_ROOT / "params.yaml").read_text())
    for scene in ("s", "a"):
        raw["data"]["scenes"][scene] = {"path": str(inputs / scene), "source": {"format": "photos"}}
    raw["data"]["styles"]["p"] = str(inputs / "p.png")
    raw["data"]["style_masks"]["p"] = str(inputs / "p_labels.png")
    (root / "params.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    return root


def _one_line(err: str) -> str:
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err.strip()


def refused(capsys, command, argv: list[str]) -> str:
    """``command(argv)`` (``abcgs``'s or the preflight's ``main``) exits 2 with one line on stderr within
    :data:`SECONDS`; returns the line."""
    capsys.readouterr()
    t0 = time.perf_counter()
    assert command(argv) == 2, capsys.readouterr()
    assert time.perf_counter() - t0 < SECONDS
    return _one_line(capsys.readouterr().err)


def refused_in_process(*argv: str, cwd: Path) -> str:
    """``python argv…`` in a process of its own exits 2 with one line on stderr (no traceback) within
    :data:`SECONDS`, imports included; returns the line."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, *argv], capture_output=True, text=True, timeout=120, cwd=cwd,
                          stdin=subprocess.DEVNULL)
    seconds = time.perf_counter() - t0
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert seconds < SECONDS, seconds
    return _one_line(proc.stderr)


def _add(repo: Path, *words: str, dry_run: bool = False) -> list[str]:
    return ["add-experiment", *words, "--params", str(repo / "params.yaml"), *(["--dry-run"] if dry_run else [])]


LONG = "a" * 300
DIGITS = "1" * 5000

# (add-experiment's words, the line it prints: a part of it)
CLI_CASES = {
    "keep a non-label": (["e1", "--scene", "a", "--styles", "1=p", "--keep", "face"],
                         "--keep face: the content label 'face' is not a number in the digits 0-9"),
    "label 255": (["e1", "--scene", "a", "--styles", "1=p", "255=p"],
                  "--styles 255=p: content label 255 is outside 1 … 254, the labels a label map holds (0 is no label, "
                  "255 a pixel left undecided); give a content label 1 … 254, e.g. 1=starry"),
    "label 256": (["e1", "--scene", "a", "--styles", "256=p"], "--styles 256=p: content label 256 is outside 1 … 254"),
    "label 10**9": (["e1", "--scene", "a", "--styles", f"{10**9}=p"],
                    "--styles 1000000000=p: content label 1000000000 is outside 1 … 254"),
    "label 0": (["e1", "--scene", "a", "--styles", "0=p"], "--styles 0=p: content label 0 is outside 1 … 254"),
    "region 255": (["e1", "--scene", "a", "--style", "p", "--binding", "1=255"],
                   "--binding 1=255: painting region 255 is outside 1 … 254, the labels a label map holds"),
    "region 999": (["e1", "--scene", "a", "--style", "p", "--binding", "1=999"],
                   "--binding 1=999: painting region 999 is outside 1 … 254"),
    "content 300 of a binding": (["e1", "--scene", "a", "--style", "p", "--binding", "300=1"],
                                 "--binding 300=1: content label 300 is outside 1 … 254"),
    "superscript label": (["e1", "--scene", "a", "--styles", "²=p"],
                          "--styles ²=p: the content label '²' is not a number in the digits 0-9; write a content "
                          "label 1 … 254, e.g. 1=starry"),
    "arabic-indic label": (["e1", "--scene", "a", "--styles", "٣=p"],
                           "--styles ٣=p: the content label '٣' is not a number in the digits 0-9"),
    "5000-digit label": (["e1", "--scene", "a", "--styles", f"{DIGITS}=p"],
                         "content label 111111… (5000 digits) is outside 1 … 254"),
    "superscript region": (["e1", "--scene", "a", "--style", "p", "--binding", "1=²"],
                           "--binding 1=²: the painting region '²' is not a number in the digits 0-9; write a painting "
                           "region 1 … 254, e.g. 1=3"),
    "5000-digit region": (["e1", "--scene", "a", "--style", "p", "--binding", f"1={DIGITS}"],
                          "painting region 111111… (5000 digits) is outside 1 … 254"),
    "label no mask holds (compositional)": (
        ["e1", "--scene", "s", "--styles", "1=p", "3=p"],
        "colormatches.e1.styles binds content label(s) [3], which the masks in "),
    "label no mask holds (semantic)": (
        ["e1", "--scene", "s", "--style", "p", "--binding", "3=1"],
        "colormatches.e1.binding.3: content label 3 is not in the masks in "),
    "region the map lacks": (["e1", "--scene", "s", "--style", "p", "--binding", "1=3"],
                             "colormatches.e1.binding.1: painting region 3 has no pixels in "),
    "name preflight.json": (["preflight.json", "--scene", "a", "--style", "p"],
                            "experiments.preflight.json: its outputs would lie in out/preflight.json/, but "
                            "out/preflight.json is the pipeline's own (stage preflight), so every dvc repro would stop "
                            "(output paths overlap, or a path is both a dependency and an output); choose another name"),
    "name styles": (["styles", "--scene", "a", "--style", "p"],
                    "experiments.styles: its outputs would lie in out/styles/, but out/styles is the pipeline's own "
                    "(stage styles)"),
    "name label_use": (["label_use", "--scene", "a", "--style", "p"],
                       "experiments.label_use: its outputs would lie in out/label_use/"),
    "name Preflight_Report.json": (["Preflight_Report.json", "--scene", "a", "--style", "p"],
                                   "out/preflight_report.json is the pipeline's own (stage preflight)"),
    "name of 300 characters": ([LONG, "--scene", "a", "--style", "p"],
                               f"experiments.{'a' * 40}…: the name has 300 characters, more than the 100 abcgs takes"),
    "a scene's name": (["s", "--scene", "a", "--style", "p"],
                       "experiments.s: its outputs would lie in out/s/, the folder of the scene data.scenes.s "
                       "(out/s/point_cloud.spz is written by export_scene@s and export@s)"),
    "a stage's name": (["fit", "--scene", "a", "--style", "p"],
                       "experiments.fit: fit is the name of a pipeline stage (dvc.yaml), so dvc repro fit would run "
                       "that stage, not this entry's; choose another name"),
    "an existing name in another case": (["Tiny_Single", "--scene", "a", "--style", "p"],
                                         "experiments.Tiny_Single and experiments.tiny_single differ only in case"),
    "a name made too long by --method": (["e" * 98, "--scene", "a", "--style", "p", "--method", "fast", "nnfm"],
                                         "the name has 103 characters, more than the 100 abcgs takes"),
    "a weight that is not a number": (["w", "--scene", "s", "--styles", "1=p", "--content-weight", "1=lots"],
                                      "--content-weight 1=lots: the weight is not a number >= 0"),
    "a negative weight": (["w", "--scene", "s", "--styles", "1=p", "--structure-weight", "1=-2"],
                          "--structure-weight 1=-2: the weight is not a number >= 0"),
    "a weight on label 0": (["w", "--scene", "s", "--styles", "1=p", "--content-weight", "0=1"],
                            "--content-weight 0=1"),
    "a weight past the bound": (["w", "--scene", "s", "--styles", "1=p", "--content-weight", "1=1e9"],
                                "--content-weight 1=1e9: the weight is outside [0, 10000]"),
}


@pytest.mark.parametrize("dry_run", [True, False], ids=["dry-run", "write"])
@pytest.mark.parametrize("case", CLI_CASES, ids=list(CLI_CASES))
def test_add_experiment_refuses_in_one_line(repo: Path, capsys, case: str, dry_run: bool) -> None:
    words, message = CLI_CASES[case]
    before = (repo / "params.yaml").read_text()
    line = refused(capsys, abcgs_main, _add(repo, *words, dry_run=dry_run))
    assert line.startswith("[add-experiment] error: ") and message in line, line
    assert len(line) < 600, line  # a 5000-character argument is not repeated
    assert (repo / "params.yaml").read_text() == before  # nothing written


def test_what_the_checks_take_still_passes_add_experiment_and_preflight(repo: Path, capsys) -> None:
    """Labels the masks and the region map hold, in any order and with leading zeros, names of up to 100
    characters; the file written passes the preflight."""
    params = str(repo / "params.yaml")
    for words in (["comp", "--scene", "s", "--styles", "1=p", "02=p"],
                  ["sem", "--scene", "s", "--style", "p", "--binding", "1=2", "2=1"],
                  ["x" * 100, "--scene", "a", "--style", "p"],
                  ["fit_a", "--scene", "a", "--style", "p", "--method", "fast", "nnfm"],
                  ["kept", "--scene", "s", "--styles", "1=p", "2=p", "--content-weight", "2=0.005",
                   "--structure-weight", "2=1", "1=0", "--method", "fast", "nnfm"],
                  ["face", "--scene", "s", "--styles", "1=p", "2=p", "--keep", "02"],
                  ["own", "--scene", "s", "--styles", "1=p", "2=p", "--keep", "1", "2", "--structure-weight", "2=5"]):
        assert abcgs_main(_add(repo, *words)) == 0, capsys.readouterr()
    written = yaml.safe_load(Path(params).read_text())
    for name in ("kept", "kept_nnfm"):  # every experiment of the colour match takes the label weights
        assert written["experiments"][name]["content_weights"] == {2: 0.005}
        assert written["experiments"][name]["structure_weights"] == {2: 1.0, 1: 0.0}
    assert "content_weights" not in written["experiments"]["fit_a"]
    assert written["experiments"]["face"]["structure_weights"] == {2: KEEP_STRUCTURE_WEIGHT}  # --keep: the measured λ
    assert written["experiments"]["own"]["structure_weights"] == {1: KEEP_STRUCTURE_WEIGHT, 2: 5.0}  # its own wins
    assert "content_weights" not in written["experiments"]["face"]
    assert written["colormatches"]["comp"]["styles"] == {1: "p", 2: "p"}
    assert written["colormatches"]["sem"]["binding"] == {1: 2, 2: 1}
    assert {"x" * 100, "fit_a", "fit_a_nnfm"} <= set(written["experiments"])
    capsys.readouterr()
    assert preflight_main([params]) == 0, capsys.readouterr().err


def test_hostile_arguments_are_refused_by_the_command_in_a_process_of_its_own(repo: Path) -> None:
    """The arguments that used to end in a ValueError traceback (``²``, 5000 digits) or took 48 s to write (a range
    of 20 000 labels), through ``python -m abcgs`` itself."""
    many = [f"{k}=p" for k in range(1, 20001)]
    for words, message in ((["e1", "--scene", "a", "--styles", *many], "--styles 255=p: content label 255 is outside"),
                           (["e1", "--scene", "a", "--styles", "²=p"], "the content label '²' is not a number"),
                           (["e1", "--scene", "a", "--styles", f"{DIGITS}=p"], "(5000 digits) is outside 1 … 254"),
                           (["e1", "--scene", "a", "--style", "p", "--binding", "1=²"],
                            "the painting region '²' is not a number")):
        line = refused_in_process("-m", "abcgs", *_add(repo, *words), cwd=repo)
        assert line.startswith("[add-experiment] error: ") and message in line, line


# ------------------------------------------------------------------------------------------ hand-written params


def _single(name: str = "m", scene: str = "a", experiment: str | None = None) -> dict:
    return {"colormatches": {name: {"scene": scene, "transfer": "single", "style": "p"}},
            "experiments": {experiment or name: {"scene": scene, "colormatch": name, "method": "fast"}}}


def _match(spec: dict) -> dict:
    return {"colormatches": {"m": spec}, "experiments": {"m": {"scene": spec["scene"], "colormatch": "m"}}}


# (entries merged into the params file, the line the preflight prints: a part of it)
PARAMS_CASES = {
    "label 255": (_match({"scene": "a", "transfer": "compositional", "styles": {1: "p", 255: "p"}}),
                  "colormatches.m.styles.255: content label 255 is outside 1 … 254, the labels a label map holds (0 "
                  "is no label, 255 a pixel left undecided); bind labels of the scene's label maps"),
    "label 256": (_match({"scene": "a", "transfer": "compositional", "styles": {256: "p"}}),
                  "colormatches.m.styles.256: content label 256 is outside 1 … 254"),
    "label 10**9": (_match({"scene": "a", "transfer": "compositional", "styles": {10**9: "p"}}),
                    "colormatches.m.styles.1000000000: content label 1000000000 is outside 1 … 254"),
    "label -1": (_match({"scene": "a", "transfer": "compositional", "styles": {-1: "p"}}),
                 "colormatches.m.styles.-1: content label -1 is outside 1 … 254"),
    "a range of 20000 labels": (_match({"scene": "a", "transfer": "compositional",
                                        "styles": {k: "p" for k in range(1, 20001)}}),
                                "colormatches.m.styles.255: content label 255 is outside 1 … 254"),
    "region 255": (_match({"scene": "a", "transfer": "semantic", "style": "p", "binding": {1: 255}}),
                   "colormatches.m.binding.1: painting region 255 is outside 1 … 254, the labels a label map holds "
                   "(0 is no label, 255 a pixel left undecided); bind painting regions of data.style_masks.p"),
    "region 999": (_match({"scene": "a", "transfer": "semantic", "style": "p", "binding": {1: 999}}),
                   "colormatches.m.binding.1: painting region 999 is outside 1 … 254"),
    "content 0 of a binding": (_match({"scene": "a", "transfer": "semantic", "style": "p", "binding": {0: 1}}),
                               "colormatches.m.binding.0: content label 0 is outside 1 … 254"),
    "label no mask holds (compositional)": (
        _match({"scene": "s", "transfer": "compositional", "styles": {1: "p", 3: "p"}}),
        "colormatches.m.styles binds content label(s) [3], which the masks in "),
    "label no mask holds (semantic)": (_match({"scene": "s", "transfer": "semantic", "style": "p", "binding": {3: 1}}),
                                       "colormatches.m.binding.3: content label 3 is not in the masks in "),
    "region the map lacks": (_match({"scene": "s", "transfer": "semantic", "style": "p", "binding": {1: 3}}),
                             "colormatches.m.binding.1: painting region 3 has no pixels in "),
    "name preflight.json": (_single(experiment="preflight.json"),
                            "experiments.preflight.json: its outputs would lie in out/preflight.json/, but "
                            "out/preflight.json is the pipeline's own (stage preflight)"),
    "name styles": (_single(experiment="styles"), "experiments.styles: its outputs would lie in out/styles/"),
    "name of 300 characters": (_single(experiment=LONG),
                               f"experiments.{'a' * 40}…: the name has 300 characters, more than the 100"),
    "colour match of 300 characters": (_single(name=LONG, experiment="e"),
                                       f"colormatches.{'a' * 40}…: the name has 300 characters"),
    "a scene's name": (_single(experiment="s"), "experiments.s: its outputs would lie in out/s/, the folder of the "
                                                "scene data.scenes.s"),
    "a stage's name": (_single(name="report", experiment="e"),
                       "colormatches.report: report is the name of a pipeline stage (dvc.yaml)"),
    "names that differ in case": (_single(experiment="TINY_SINGLE"),
                                  "experiments.TINY_SINGLE and experiments.tiny_single differ only in case: on a "
                                  "case-insensitive file system (macOS, Windows) their outputs are one file; rename one"),
    "a scene named as an output": ({"data": {"scenes": {"label_use": "a"}}},
                                   "data.scenes.label_use: its outputs would lie in out/label_use/"),
    "a painting named as a region map's copy": ({"data": {"styles": {"p.labels": "p"}}},
                                                "data.styles.p.labels: its copy out/styles/p.labels.png would be the "
                                                "region map of data.style_masks.p (out/styles/p.labels.png)"),
}


def _hand_written(repo: Path, entries: dict) -> Path:
    """The repository copy's params with ``entries`` put in, written as a hand would (a new file beside
    ``dvc.yaml``). In ``data``, a value naming another entry (a scene ``label_use: a``) takes that entry's."""
    raw = yaml.safe_load((repo / "params.yaml").read_text())
    for section, values in entries.items():
        if section == "data":
            for sub, named in values.items():
                for key, other in named.items():
                    raw["data"][sub][key] = copy.deepcopy(raw["data"][sub][other])
        else:
            raw[section].update(values)
    path = repo / "hand.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


@pytest.mark.parametrize("case", PARAMS_CASES, ids=list(PARAMS_CASES))
def test_preflight_refuses_hand_written_entries_in_one_line(repo: Path, capsys, case: str) -> None:
    entries, message = PARAMS_CASES[case]
    line = refused(capsys, preflight_main, [str(_hand_written(repo, entries))])
    assert line.startswith("[preflight] error: ") and message in line, line


def test_preflight_refuses_a_range_of_20000_labels_in_a_process_of_its_own(repo: Path) -> None:
    entries, message = PARAMS_CASES["a range of 20000 labels"]
    line = refused_in_process("-m", "abcgs.preflight", str(_hand_written(repo, entries)), cwd=repo)
    assert message in line, line


def test_a_label_no_mask_holds_is_refused_not_warned_where_the_masks_stage_lifts_the_masks(repo: Path,
                                                                                          capsys) -> None:
    """Refused, not a warning: where the scene's masks are numbered files and the ``masks`` stage lifts them
    (``masks.source`` auto or given), the Gaussians carry exactly their labels, and the ``colormatch`` stage refuses
    a binding to any other (:func:`abcgs.stylize.experiment.check_bindings`) after the reconstruct, fit and masks
    stages have run; the preflight says the same first. Where the scene's labels come from clustering instead,
    the mask files say nothing of them, and the binding is left to the colormatch stage."""
    entries = _match({"scene": "s", "transfer": "semantic", "style": "p", "binding": {3: 1}})
    for source in ("auto", "given"):
        raw = yaml.safe_load((repo / "params.yaml").read_text())
        raw["data"]["scenes"]["s"]["masks"] = {"source": source}
        (repo / "params.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
        line = refused(capsys, preflight_main, [str(_hand_written(repo, entries))])
        assert "colormatches.m.binding.3: content label 3 is not in the masks in" in line, line
    raw["data"]["scenes"]["s"]["masks"] = {"source": "clustering"}
    (repo / "params.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    capsys.readouterr()
    assert preflight_main([str(_hand_written(repo, entries))]) == 0, capsys.readouterr().err


def test_add_scene_and_add_style_refuse_names_the_pipeline_takes(repo: Path, inputs: Path, capsys) -> None:
    """The same names checks for the other add commands: a scene named as a pipeline output or as an experiment
    (their folders are one), a painting whose copy would be a region map's."""
    params = str(repo / "params.yaml")
    for argv, message in (
            (["add-scene", "styles", str(inputs / "a")], "data.scenes.styles: its outputs would lie in out/styles/"),
            (["add-scene", "tiny_single", str(inputs / "a")],
             "experiments.tiny_single: its outputs would lie in out/tiny_single/, the folder of the scene "
             "data.scenes.tiny_single"),
            (["add-scene", "b" * 101, str(inputs / "a")], "the name has 101 characters, more than the 100"),
            (["add-style", "p.labels", str(inputs / "p.png")],
             "data.styles.p.labels: its copy out/styles/p.labels.png would be the region map of data.style_masks.p")):
        line = refused(capsys, abcgs_main, [*argv, "--params", params, "--dry-run"])
        assert message in line, line
