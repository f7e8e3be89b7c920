"""``python -m eval run experiment run``: the experiment's ``dvc.yaml`` follows the overlaid params."""

from __future__ import annotations

import shutil
from pathlib import Path

import yaml

from abcgs.dag import pipeline_yaml
from abcgs.overlay import apply_overlay, read_overlay
from eval.bench import experiment

ROOT = Path(__file__).resolve().parents[1]


def _copy_repo(tmp_path: Path) -> Path:
    root = tmp_path / "repo"
    for sub in ("abcgs", "stages"):
        shutil.copytree(ROOT / sub, root / sub, ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    shutil.copy(ROOT / "params.yaml", root / "params.yaml")
    (root / "dvc.yaml").write_text(pipeline_yaml(root), encoding="utf-8")  # as `python -m abcgs.dag --write` makes it
    return root


def _report_deps(text: str) -> list[str]:
    return yaml.safe_load(text)["stages"]["report"]["deps"]


def test_pipeline_yaml_of_another_params_file(tmp_path: Path) -> None:
    """The report's deps come from the params file given; without one, from the repository's params.yaml."""
    raw = yaml.safe_load((ROOT / "params.yaml").read_text())
    raw["experiments"]["added_exp"] = dict(next(iter(raw["experiments"].values())))
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(raw, sort_keys=False))
    assert "out/added_exp/stylize.json" in _report_deps(pipeline_yaml(ROOT, tmp_path / "params.yaml"))
    assert "out/added_exp/stylize.json" not in _report_deps(pipeline_yaml(ROOT))


def test_the_experiment_starts_with_the_dvc_yaml_of_its_overlay(tmp_path: Path, monkeypatch) -> None:
    """While the experiment starts, the workspace's dvc.yaml names the overlay's experiments in the report's deps
    (the preflight refuses it otherwise); afterwards the workspace's own is back, also when the run fails. Params
    that need no other dvc.yaml leave the file alone."""
    root = _copy_repo(tmp_path)
    monkeypatch.setattr(experiment, "ROOT", root)
    base = yaml.safe_load((root / "params.yaml").read_text())
    (tmp_path / "shared").mkdir()
    overlay = read_overlay(ROOT / "eval" / "params" / "fern_strokes.yaml", tmp_path / "shared")
    own = (root / "dvc.yaml").read_text()
    with experiment.pipeline_for(apply_overlay(base, overlay)):
        during = (root / "dvc.yaml").read_text()
    assert "out/fern_strokes_semantic/stylize.json" in _report_deps(during)
    assert not any(d.startswith("out/tiny_") for d in _report_deps(during))
    assert (root / "dvc.yaml").read_text() == own
    try:
        with experiment.pipeline_for(apply_overlay(base, overlay)):
            raise RuntimeError("the run failed")
    except RuntimeError:
        pass
    assert (root / "dvc.yaml").read_text() == own
    with experiment.pipeline_for(base):
        assert (root / "dvc.yaml").read_text() == own
