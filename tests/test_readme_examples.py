"""Every README example is run: each shell command and YAML block has an entry in tests/readme_examples.py naming the
test that exercises it (or why it is exempt), and the ``python -m abcgs add-*`` commands and the YAML block are run
here, as written, with the README's ``/data/...`` paths replaced by generated data of that shape.

The YAML block's fit override is fitted on the tiny scene through the fit stage's code and must pass the stage's
plausibility check and hold out at least :data:`MIN_HELDOUT_DB`: a default schedule that destroys a fit of that
length fails here. The README's workflow from a bare splat to a stylized one: tests/test_readme_workflow.py.
"""

from __future__ import annotations

import ast
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import pytest
import yaml
from conftest import REPO_ROOT
from readme_examples import README, REGISTRY, Example, readme_examples
from test_add_scene import _run
from test_add_splat import _splat, colmap_scene  # noqa: F401  (colmap_scene: a fixture, used by name)
from test_sources import _copy_images, write_blender, write_colmap, write_llff, write_nerfstudio
from test_splats import make_model

from abcgs.fit.outputs import fit_and_save
from abcgs.params import load_params, validate_params
from abcgs.preflight import preflight
from abcgs.scene.synthetic import cameras_from_json
from abcgs.sfm.model import read_scene
from abcgs.splats.formats.splat import write_splat_file

EXAMPLES = readme_examples(README.read_text(encoding="utf-8"))
MIN_HELDOUT_DB = 28.0
"""The least held-out PSNR of the tiny scene fitted with the YAML block's fit override (dB). The fit benchmark holds the
tiny scene out at 34.7 dB after 3000 steps (docs/SCALING.md "The fit's schedule"); 3DGS's fixed steps, which reset
the opacities on the last of 3000, held it out near 7 dB."""


def _commands(prefix: str) -> list[Example]:
    """The README's commands that start with ``prefix`` and name real paths (the synopsis ``NAME PATH`` is not run)."""
    return [e for e in EXAMPLES if e.kind != "yaml" and e.text.startswith(prefix) and "NAME PATH" not in e.text]


# ------------------------------------------------------------------------------------------ the registry


def test_the_parser_finds_block_lines_inline_commands_and_yaml_blocks() -> None:
    text = ("Run `make run` or `python -m x.y --a 'b c'`; `make_tiny` and `dvc.yaml` are names.\n"
            "| a | `dvc exp run -S k=v` |\n```bash\nmake test   # a comment with `make quality`\n\ndvc repro -s x\n```\n"
            "```yaml\na: {b: 1}\n```\n")
    got = [(e.kind, e.text, e.line) for e in readme_examples(text)]
    assert got == [("inline", "make run", 1), ("inline", "python -m x.y --a b c", 1),
                   ("inline", "dvc exp run -S k=v", 2), ("bash", "make test", 4), ("bash", "dvc repro -s x", 6),
                   ("yaml", "a: {b: 1}\n", 9)]


def test_every_readme_example_has_exactly_one_exerciser() -> None:
    assert sum(e.kind == "yaml" for e in EXAMPLES) >= 1 and sum(e.kind == "bash" for e in EXAMPLES) >= 4
    missing = [f"README.md:{e.line}: {e.text[:80]!r}" for e in EXAMPLES if not any(r.matches(e) for r in REGISTRY)]
    assert not missing, ("README examples without an exerciser: add each to tests/readme_examples.py's REGISTRY "
                         "with the test that runs it:\n" + "\n".join(missing))
    twice = [e.text for e in EXAMPLES if sum(r.matches(e) for r in REGISTRY) > 1]
    assert not twice, f"examples matched by several registry entries: {twice}"


def test_every_registry_entry_matches_a_readme_example() -> None:
    stale = [e.pattern for e in REGISTRY if not any(e.matches(x) for x in EXAMPLES)]
    assert not stale, f"registry entries that match no README example (remove them): {stale}"


def _defines(path: Path, name: str) -> bool:
    return any(isinstance(n, ast.FunctionDef) and n.name == name for n in ast.walk(ast.parse(path.read_text())))


def test_every_exerciser_is_a_test_that_exists_and_exemptions_are_few_with_a_reason() -> None:
    for entry in REGISTRY:
        assert entry.note, entry.pattern
        if entry.test is not None:
            path, name = entry.test.split("::")
            assert name.startswith("test_") and _defines(REPO_ROOT / path, name), f"{entry.pattern}: {entry.test}"
    exempt = [e for e in REGISTRY if e.test is None]
    assert len(exempt) <= 5, [e.pattern for e in exempt]


# ------------------------------------------------------------------------------------------ generated data


@pytest.fixture(scope="module")
def data(tiny_scene: Path, colmap_scene, tmp_path_factory) -> Callable[[Example], list[str]]:  # noqa: F811
    """``argv(example)``: the example's words after ``python -m abcgs``, each ``/data/...`` path replaced by a
    generated file or folder of that path's shape (built once per module)."""
    import json

    cams = cameras_from_json(json.loads((tiny_scene / "cameras.json").read_text()))
    folder, scene, model = colmap_scene
    root = tmp_path_factory.mktemp("readme_data")
    styles = tiny_scene / "styles"

    def painting(dst: Path) -> None:
        dst.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(dst), cv2.imread(str(styles / "paint.png")), [cv2.IMWRITE_JPEG_QUALITY, 95])

    def photos(dst: Path) -> None:  # the tiny scene's photos and its label maps
        shutil.copytree(tiny_scene / "images", dst / "images")
        shutil.copytree(tiny_scene / "masks", dst / "masks")

    def colmap_quarter(dst: Path) -> None:  # Mip-NeRF 360's layout: the model, the photos and a ¼-size copy
        write_colmap(dst, cams)
        _copy_images(tiny_scene / "images", dst / "images")
        _copy_images(tiny_scene / "images", dst / "images_4", scale=0.25)

    def llff_eighth(dst: Path) -> None:  # poses_bounds.npy of an 8× capture beside its ⅛-size copy, images_8/
        write_llff(dst, tiny_scene, cams, full=8)
        (dst / "images").rename(dst / "images_8")

    def nerfstudio(dst: Path) -> None:
        dst.mkdir()
        write_nerfstudio(dst, tiny_scene, cams)

    def splat_renders(dst: Path) -> None:  # photos (no cameras) of the scene the INRIA folder was trained on
        shutil.copytree(folder / "images", dst / "images")

    builders: dict[str, Callable[[Path], object]] = {
        "/data/garden": photos,
        "/data/garden+splat": splat_renders,
        "/data/gs_out/garden": lambda dst: _splat("inria_folder", scene, model, dst),
        "/data/360_v2/bonsai": colmap_quarter,
        "/data/nerf_llff_data/fern": llff_eighth,
        "/data/nerfstudio/poster": nerfstudio,
        "/data/nerf_synthetic/lego": lambda dst: write_blender(dst, tiny_scene, cams),
        "/data/chair.splat": lambda dst: write_splat_file(dst, make_model(2500, 0, seed=3)),
        "/data/starry.jpg": painting,
        "/data/paintings/starry.jpg": painting,
        "/data/starry_labels.png": lambda dst: shutil.copy(styles / "paint_labels.png", dst),
        "/data/paintings/starry_labels.png": lambda dst: shutil.copy(styles / "paint_labels.png", dst),
    }
    built: dict[str, Path] = {}

    def path_for(word: str, with_splat: bool) -> str:
        key = f"{word}+splat" if with_splat and f"{word}+splat" in builders else word
        assert key in builders, f"README path {word}: no generated data of its shape; add a builder to this fixture"
        if key not in built:
            dst = root / key.lstrip("/").replace("+", "_")
            dst.parent.mkdir(parents=True, exist_ok=True)
            written = builders[key](dst)
            built[key] = written if isinstance(written, Path) and written.exists() else dst
        return str(built[key])

    def argv(example: Example) -> list[str]:
        words = example.argv
        assert words[:3] == ["python", "-m", "abcgs"], example.text
        with_splat = "--splat" in words
        return [path_for(w, with_splat) if w.startswith("/data/") else w for w in words[3:]]

    return argv


@pytest.fixture
def params_file(tmp_path: Path) -> Path:
    """A copy of params.yaml and dvc.yaml (the tiny scene's files are a stage's output), as the commands edit it."""
    for name in ("params.yaml", "dvc.yaml"):
        shutil.copy(REPO_ROOT / name, tmp_path / name)
    return tmp_path / "params.yaml"


def _run_example(capsys, argv: list[str], params_file: Path) -> str:
    rc, out, err = _run(capsys, *argv, "--params", str(params_file))
    assert rc == 0, f"python -m abcgs {' '.join(argv)}: exit {rc}\n{err}"
    return out


def _preflight(params_file: Path) -> None:
    raw = yaml.safe_load(params_file.read_text())
    preflight(validate_params(raw, str(params_file)), raw, params_file)


# ------------------------------------------------------------------------------------------ the commands


FORMATS = {"/data/garden": "photos", "/data/360_v2/bonsai": "colmap", "/data/nerf_llff_data/fern": "llff",
           "/data/nerfstudio/poster": "nerfstudio", "/data/nerf_synthetic/lego": "blender", "/data/chair.splat": "splat"}


@pytest.mark.parametrize("example", _commands("python -m abcgs add-scene "), ids=lambda e: e.text[16:])
def test_add_scene_example_runs_as_written(example: Example, data, params_file: Path, capsys) -> None:
    argv = data(example)
    out = _run_example(capsys, argv, params_file)
    name, words = argv[1], example.argv
    assert out.startswith(f"{name}: {FORMATS[words[5]]}\n") and f"wrote data.scenes in {params_file}:" in out, out
    spec = load_params(params_file).data.scenes[name]
    assert Path(spec.path) == Path(argv[2]).resolve() and spec.format == FORMATS[words[5]]
    for option, value in (("--images", spec.images), ("--background", spec.background)):
        if option in words:
            at = words.index(option) + 1
            given = words[at] if option == "--images" else [float(w) for w in words[at:at + 3]]
            assert (list(value) if option == "--background" else value) == given, (option, value)
    if "--splat" in words:
        assert spec.splat_path() == Path(argv[argv.index("--splat") + 1])
        assert "(inria): checked against the photos in the fit stage" in out, out
    _preflight(params_file)  # the file as written passes the checks every stage runs


@pytest.mark.parametrize("example", _commands("python -m abcgs add-style "), ids=lambda e: e.text[16:])
def test_add_style_example_runs_as_written(example: Example, data, params_file: Path, capsys) -> None:
    argv = data(example)
    out = _run_example(capsys, argv, params_file)
    params = load_params(params_file)
    assert params.data.styles[argv[1]] == argv[2] and "painting 341x256" in out, out
    if "--labels" in argv:
        assert params.data.style_masks[argv[1]] == argv[argv.index("--labels") + 1] and "region map 341x256" in out
    _preflight(params_file)


def _preceding(example: Example, command: str, name: str) -> Example:
    """The README's last ``python -m abcgs <command> <name> ...`` before ``example`` (what its text says was run)."""
    before = [e for e in _commands(f"python -m abcgs {command} {name} ") if e.line <= example.line
              and "--splat" not in e.argv]
    assert before, f"README.md:{example.line}: no {command} {name} before it"
    return before[-1]


def _option(words: list[str], option: str) -> str:
    return words[words.index(option) + 1]


@pytest.mark.parametrize("example", _commands("python -m abcgs add-experiment "), ids=lambda e: e.text[16:])
def test_add_experiment_example_runs_as_written(example: Example, data, params_file: Path, capsys) -> None:
    """After the README's own add-scene and add-style of the experiment's scene and painting."""
    words = example.argv
    scene, style = _option(words, "--scene"), _option(words, "--style")
    for before in (_preceding(example, "add-scene", scene), _preceding(example, "add-style", style)):
        _run_example(capsys, data(before), params_file)
    argv = data(example)
    out = _run_example(capsys, argv, params_file)
    params, name = load_params(params_file), argv[1]
    methods = words[words.index("--method") + 1:] if "--method" in words else ["fast"]
    names = [name] + [f"{name}_{m}" for m in methods[1:]]
    assert [(params.experiments[n].colormatch, params.experiments[n].method) for n in names] == [
        (name, m) for m in methods]
    match = params.colormatches[name]
    assert match.scene == scene and match.transfer == ("semantic" if "--binding" in words else "single")
    targets = " ".join(f"{stage}@{n}" for n in names for stage in ("evaluate", "export"))
    assert f'make repro ARGS="{targets}"' in out, out
    _preflight(params_file)


def test_pip_extras_named_by_the_readme_exist() -> None:
    """The extras as the installed package declares them (what pip resolves ``.[extra]`` against)."""
    from importlib.metadata import metadata, requires

    extras = metadata("abcgs").get_all("Provides-Extra")
    named = [e.text.split("[")[1].rstrip("]") for e in EXAMPLES if e.text.startswith("pip install -e .[")]
    assert named and set(named) <= set(extras), (named, extras)
    for extra in named:  # each brings at least one requirement of its own
        assert any(f'extra == "{extra}"' in r for r in requires("abcgs")), extra


# ------------------------------------------------------------------------------------------ the YAML block


def _yaml_block() -> dict:
    blocks = [e for e in EXAMPLES if e.kind == "yaml"]
    assert len(blocks) == 1, "one YAML block is exercised here; give a new one its own exerciser"
    return yaml.safe_load(blocks[0].text)


def test_yaml_block_validates_and_passes_preflight(data, params_file: Path, capsys) -> None:
    """The block says it is what the workflow's commands wrote, with a fit override added: run them, compare, then
    merge the block (its paths replaced by the generated ones) into the params copy and check it as preflight does."""
    block = _yaml_block()
    workflow = [e for e in EXAMPLES if e.kind == "bash" and e.text.startswith("python -m abcgs add-")]
    for example in workflow:
        _run_example(capsys, data(example), params_file)
    written = yaml.safe_load(params_file.read_text())
    for name, entry in block["data"]["scenes"].items():
        got = written["data"]["scenes"][name]
        generated = data(Example("bash", f"python -m abcgs add-scene {name} {entry['path']}", 0))[2]
        assert got["path"] == generated
        assert {k: v for k, v in got.items() if k != "path"} == {k: v for k, v in entry.items()
                                                                  if k not in ("path", "fit")}
        entry["path"] = generated
    for section in ("colormatches", "experiments"):
        assert {n: written[section][n] for n in block[section]} == block[section]
    for name, entry in block["data"]["scenes"].items():
        written["data"]["scenes"][name] = entry
    for section in ("colormatches", "experiments"):
        written[section].update(block[section])
    params_file.write_text(yaml.safe_dump(written, sort_keys=False))
    _preflight(params_file)


@pytest.mark.slow
def test_yaml_fit_override_fits_the_tiny_scene(tiny_scene: Path, tiny_colmap: Path, tmp_path: Path) -> None:
    """The block's ``fit`` override (with params.yaml's other fit settings) on the tiny scene's COLMAP layout, through
    the fit stage's code: its plausibility check passes (fit_and_save raises otherwise) and the held-out views score
    at least MIN_HELDOUT_DB."""
    raw = yaml.safe_load((REPO_ROOT / "params.yaml").read_text())
    (name, entry), = _yaml_block()["data"]["scenes"].items()
    raw["data"]["scenes"][name] = {**entry, "path": str(tiny_scene)}
    fit = validate_params(raw).scene_section(name, "fit")
    assert fit.iterations == entry["fit"]["iterations"]
    scene = read_scene(tiny_colmap)
    metrics = fit_and_save(scene, fit, tmp_path / "gs", progress=False).metrics()
    assert metrics["psnr"] >= MIN_HELDOUT_DB, metrics["psnr"]
    assert (tmp_path / "gs" / "point_cloud.ply").is_file()
