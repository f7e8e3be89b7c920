"""The plausible ranges of the numbers in a params file (:class:`abcgs.sections.Bounded`): a step count, an interval, a
threshold or a size outside its range is refused naming the key, the range and why; a soft range is passed on purpose
by naming the key in the section's ``unbounded`` list; params.yaml, the defaults and every benchmark overlay keep
within them; a model built in code (a test's 5-step fit) is not held to them."""

from __future__ import annotations

import math
import subprocess
import sys
import types
import typing
from pathlib import Path

import annotated_types as at
import pytest
import yaml
from pydantic import BaseModel, ValidationError

import abcgs.params  # noqa: F401  (every section's model)
from abcgs.dotted import set_dotted
from abcgs.errors import ParamsError
from abcgs.fit.params import MAX_FIT_ITERATIONS, MIN_CHECKED_ITERATIONS, FitParams, StrategyParams
from abcgs.overlay import apply_overlay, read_overlay
from abcgs.params import Params, validate_params
from abcgs.sections import FILE_CONTEXT, Bound, Bounded
from abcgs.splats.params import SplatViewsParams
from abcgs.stylize.params import ColorMatchParams, StylizeOptim

REPO = Path(__file__).resolve().parents[1]
OVERLAYS = sorted((REPO / "eval" / "params").glob("*.yaml"))


def _params() -> dict:
    return yaml.safe_load((REPO / "params.yaml").read_text(encoding="utf-8"))


def _refusal(**sets) -> str:
    """The message of params.yaml with ``sets`` (dotted key → value) put in; it must be refused."""
    raw = _params()
    for key, value in sets.items():
        set_dotted(raw, key, value)
    with pytest.raises(ParamsError) as exc:
        validate_params(raw)
    return str(exc.value)


def _valid(**sets) -> None:
    raw = _params()
    for key, value in sets.items():
        set_dotted(raw, key, value)
    validate_params(raw)


# ------------------------------------------------------------------------------------------ what stays valid


def test_params_yaml_and_the_defaults_are_within_the_ranges() -> None:
    validate_params(_params())
    validate_params({"data": {"scenes": {"s": {"path": "data/s"}}}})  # every section's defaults


@pytest.mark.parametrize("overlay", OVERLAYS, ids=lambda p: p.name)
def test_every_benchmark_overlay_is_within_the_ranges(overlay: Path, tmp_path: Path) -> None:
    """As ``python -m eval run experiment`` and ``abcgs.cluster`` lay it over the workspace's params.yaml."""
    validate_params(apply_overlay(_params(), read_overlay(overlay, tmp_path)), str(overlay))


# ------------------------------------------------------------------------------------------ what is refused


@pytest.mark.parametrize("sets, expected", [
    ({"fit.iterations": 10**12}, ["fit.iterations: must be 35 .. 2000000 steps", "3DGS's 30000-step reference fit",
                                  "unbounded: [iterations]", "(got 1000000000000)"]),
    ({"fit.iterations": 1}, ["fit.iterations: must be 35 .. 2000000 steps", "fit check's PSNR floor",
                             "set fit.min_psnr: 0"]),
    ({"fit.iterations": 2}, ["fit.iterations: must be 35", "14.7 dB at 30"]),
    ({"fit.min_psnr": math.inf}, ["fit.min_psnr: must be a finite number, 0 .. 60 dB", "0 turns the floor off"]),
    ({"fit.min_psnr": 1e9}, ["fit.min_psnr: must be 0 .. 60 dB", "no fit can clear"]),
    ({"fit.import_min_psnr": math.inf}, ["fit.import_min_psnr: must be a finite number, 0 .. 60 dB"]),
    ({"fit.max_psnr_gap": 1e-9}, ["fit.max_psnr_gap: must be 1 .. 60 dB", "would refuse every fit"]),
    ({"fit.strategy.refine_every": 1}, ["fit.strategy.refine_every: must be 10 .. 2000000 steps",
                                        "470 409", "unbounded: [refine_every]"]),
    ({"fit.strategy.reset_every": 5}, ["fit.strategy.reset_every: must be 100 .. 2000000 steps", "regrow"]),
    ({"fit.lr_sh0": 5.0}, ["fit.lr_sh0: must be 0 .. 1: Adam moves each value"]),
    ({"fit.background": [2.0, 0.0, 0.0]}, ["fit.background: must be 0 .. 1: an RGB colour"]),
    ({"fit.seed": -1}, ["fit.seed: must be 0 .. 4294967295"]),
    ({"colormatch.refit_iterations": 10**9}, ["colormatch.refit_iterations: must be 0 .. 30000 steps",
                                              "3DGS's whole fit", "unbounded: [refit_iterations]"]),
    ({"colormatch.refine_every": 1}, ["colormatch.refine_every: must be 0 (off) or 10 .. 30000 steps",
                                      "54 773 Gaussians to 470 409", "unbounded: [refine_every]"]),
    ({"stylize.optim.iterations": 10**9}, ["stylize.optim.iterations: must be 0 .. 30000 steps",
                                           "50 times the authors' 600", "unbounded: [iterations]"]),
    ({"stylize.optim.color_pass_iterations": 10**9}, ["stylize.optim.color_pass_iterations: must be 0 .. 30000"]),
    ({"stylize.weights.style": 1e9}, ["stylize.weights.style: must be 0 .. 10000: a λ of Eq. 8"]),
    ({"stylize.style_height": 100_000}, ["stylize.style_height: must be 16 .. 4096 px"]),
    ({"stylize.fast.k": 10**6}, ["stylize.fast.k: must be 1 .. 256"]),
    ({"evaluate.raft_iterations": 10**6}, ["evaluate.raft_iterations: must be 1 .. 100"]),
    ({"viewer.max_gaussians": 10**9}, ["viewer.max_gaussians: must be 100 .. 10000000", "unbounded: [max_gaussians]"]),
    ({"reconstruct.max_image_size": 5}, ["reconstruct.max_image_size: must be -1 (off) or 100 .. 100000 px"]),
    ({"tiny.wall_depth": 1e9}, ["tiny.wall_depth: must be 1 .. 1000"]),
    ({"isolation.erode_px": 10**6}, ["isolation.erode_px: must be 0 .. 1024 px"]),
])
def test_a_number_outside_its_range_names_the_key_the_range_and_why(sets: dict, expected: list[str]) -> None:
    msg = _refusal(**sets)
    for part in expected:
        assert part in msg, msg


def test_a_scene_override_is_held_to_the_ranges_under_its_own_path() -> None:
    msg = _refusal(**{"data.scenes.tiny.fit": {"iterations": 10**12}})
    assert "data.scenes.tiny.fit.iterations: must be 35 .. 2000000 steps" in msg, msg
    _valid(**{"data.scenes.tiny.fit": {"iterations": 10**7, "unbounded": ["iterations"]}})


def test_a_bare_splats_views_are_held_to_the_ranges() -> None:
    scene = {"path": "data/s", "splat": "s.ply", "source": {"format": "splat", "views": {"elevation_deg": [0, 100]}}}
    msg = _refusal(**{"data.scenes.s": scene})
    assert "data.scenes.s.source.splat.views.elevation_deg: must be -90 .. 90 degrees" in msg, msg


def test_every_problem_is_listed_at_once() -> None:
    msg = _refusal(**{"fit.min_psnr": 1e9, "fit.max_psnr_gap": 1e-9})
    assert "(2 problem(s))" in msg and "fit.min_psnr:" in msg and "fit.max_psnr_gap:" in msg, msg


# ------------------------------------------------------------------------------------------ the override


@pytest.mark.parametrize("sets", [
    {"fit.iterations": 5_000_000, "fit.unbounded": ["iterations"]},
    {"fit.strategy.refine_every": 2, "fit.strategy.unbounded": ["refine_every"]},
    {"colormatch.refine_every": 1, "colormatch.unbounded": ["refine_every"]},
    {"colormatch.refit_iterations": 100_000, "colormatch.unbounded": ["refit_iterations"]},
    {"stylize.optim.iterations": 100_000, "stylize.optim.unbounded": ["iterations"]},
    {"viewer.max_gaussians": 20_000_000, "viewer.unbounded": ["max_gaussians"]},
    {"fit.iterations": 2, "fit.unbounded": ["iterations"]},
])
def test_naming_the_key_in_unbounded_passes_its_soft_range(sets: dict) -> None:
    _valid(**sets)


def test_unbounded_passes_only_the_keys_it_names() -> None:
    msg = _refusal(**{"fit.iterations": 10**12, "fit.max_gaussians": 10**9, "fit.unbounded": ["max_gaussians"]})
    assert "fit.iterations: must be" in msg and "fit.max_gaussians" not in msg, msg


def test_unbounded_refuses_a_key_without_a_soft_range() -> None:
    msg = _refusal(**{"fit.min_psnr": 1e9, "fit.unbounded": ["min_psnr", "iteratons"]})
    assert "fit.unbounded.0: 'min_psnr' is not a key of this section with a soft range" in msg, msg
    assert "fit.unbounded.1: 'iteratons'" in msg and "the keys it can name: iterations," in msg, msg
    assert "fit.min_psnr: must be 0 .. 60 dB" in msg, msg  # a hard range stays


def test_a_smoke_run_without_the_fit_checks_floor_may_be_short() -> None:
    _valid(**{"fit.iterations": 2, "fit.min_psnr": 0})  # the check passes any fit then
    _valid(**{"fit.iterations": MIN_CHECKED_ITERATIONS})
    assert "must be 1 .. 2000000 steps" in _refusal(**{"fit.iterations": 10**12, "fit.min_psnr": 0})


def test_the_message_names_the_override_in_the_preflight_line(tmp_path: Path) -> None:
    raw = _params()
    raw["fit"]["iterations"] = 10**12
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False), encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "abcgs.preflight", str(path)], capture_output=True, text=True,
                          timeout=120, cwd=REPO)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert "fit.iterations: must be 35 .. 2000000 steps" in proc.stderr and "unbounded: [iterations]" in proc.stderr


# ------------------------------------------------------------------------------------------ code is not bounded


def test_a_model_built_in_code_is_not_held_to_the_params_file_ranges() -> None:
    FitParams(iterations=5, strategy=StrategyParams(refine_every=1, reset_every=2))  # a unit test's fit
    ColorMatchParams(refit_iterations=6, refine_every=1)
    with pytest.raises(ValidationError, match="must be 35 .. 2000000 steps"):
        FitParams.model_validate({"iterations": 5}, context=FILE_CONTEXT)


# ------------------------------------------------------------------------------------------ the ranges themselves


def test_bound_describes_its_range_and_skips_what_it_does_not_judge() -> None:
    b = Bound(10, 100, "why", off=0, unit="steps")
    assert b.describe() == "0 (off) or 10 .. 100 steps"
    assert b.problem(0) is None and b.problem(None) is None and b.problem(True) is None and b.problem(10) is None
    assert b.problem(5) == "must be 0 (off) or 10 .. 100 steps: why"
    assert Bound(0.0, 1.0, "rgb").problem((0.5, 1.5, 0.0)) == "must be 0 .. 1: rgb"
    assert Bound(0.0, 1.0, "x", low="too low").problem(-1.0) == "must be 0 .. 1: too low"
    assert Bound(0.0, 1.0, "x").problem(math.nan).startswith("must be a finite number")
    assert Bound(lo=3).describe() == "at least 3" and Bound(hi=3.5).describe() == "at most 3.5"


def _models(model: type[BaseModel], seen: set[type[BaseModel]]) -> None:
    if model in seen:
        return
    seen.add(model)
    for f in model.model_fields.values():
        todo = [f.annotation]
        while todo:
            t = todo.pop()
            if isinstance(t, type) and issubclass(t, BaseModel):
                _models(t, seen)
            todo += list(typing.get_args(t))


def _numeric(annotation) -> bool:
    """Whether a field holds numbers: int or float, optional, or a tuple/list of them (not bool)."""
    args = [a for a in typing.get_args(annotation) if a is not type(None) and a is not Ellipsis]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return any(_numeric(a) for a in args)
    if typing.get_origin(annotation) in (tuple, list):
        return bool(args) and all(_numeric(a) for a in args)
    return annotation in (int, float)


OWN = {"abcgs.evaluation.params", "abcgs.features.params", "abcgs.fit.params", "abcgs.losses.params",
       "abcgs.scene.params", "abcgs.sfm.params", "abcgs.sources.params", "abcgs.splats.params", "abcgs.stylize.params",
       "abcgs.view.params"}
"""The schema modules whose numbers these ranges cover (``masks`` has its own)."""
CHECKED_ELSEWHERE = {("SceneParams", "background"): "its field validator: RGB in [0, 1]"}


def _section_models() -> list[type[BaseModel]]:
    seen: set[type[BaseModel]] = set()
    _models(Params, seen)
    _models(SplatViewsParams, seen)  # behind the sources' tagged union
    return sorted((m for m in seen if m.__module__ in OWN), key=lambda m: (m.__module__, m.__name__))


def test_every_number_of_the_schema_has_a_lower_and_an_upper_limit() -> None:
    missing = []
    for model in _section_models():
        bounds = model.BOUNDS if issubclass(model, Bounded) else {}
        for name, f in model.model_fields.items():
            if not _numeric(f.annotation) or (model.__name__, name) in CHECKED_ELSEWHERE:
                continue
            b = bounds.get(name)
            low = any(isinstance(m, (at.Ge, at.Gt)) for m in f.metadata) or (b is not None and b.lo is not None)
            high = any(isinstance(m, (at.Le, at.Lt)) for m in f.metadata) or (b is not None and b.hi is not None)
            if not (low and high):
                missing.append(f"{model.__name__}.{name}")
    assert not missing, missing
    assert {m.__module__ for m in _section_models()} == OWN


def test_the_ranges_name_real_keys_and_soft_sections_take_unbounded_last() -> None:
    for model in _section_models():
        if not issubclass(model, Bounded):
            continue
        assert set(model.BOUNDS) <= set(model.model_fields), model
        fields = list(model.model_fields)
        if any(b.soft for b in model.BOUNDS.values()):
            assert fields[-1] == "unbounded", model  # the keys come first in "allowed keys here: …"
        else:
            assert "unbounded" not in fields, model
        defaults = model.model_validate({}, context=FILE_CONTEXT)  # the defaults keep within the ranges
        assert all(b.problem(getattr(defaults, k)) is None for k, b in defaults.bounds().items()), model


def test_the_allowed_keys_of_a_section_still_start_with_its_own() -> None:
    raw = _params()
    raw["fit"]["iteratons"] = 3
    with pytest.raises(ParamsError, match="fit.iteratons: unknown key; allowed keys here: iterations, sh_degree"):
        validate_params(raw)


def test_the_sections_with_soft_ranges() -> None:
    soft = {m.__name__: sorted(k for k, b in m.BOUNDS.items() if b.soft) for m in _section_models()
            if issubclass(m, Bounded) and any(b.soft for b in m.BOUNDS.values())}
    assert soft == {
        "ColorMatchParams": ["refine_every", "refit_iterations"],
        "FitParams": ["eval_every", "import_max_gaussians", "iterations", "max_gaussians", "sh_degree_interval"],
        "StrategyParams": ["refine_every", "refine_start", "refine_stop", "reset_every"],
        "StylizeOptim": ["color_pass_iterations", "iterations"],
        "ViewerParams": ["max_gaussians"],
    }
    assert FitParams.BOUNDS["iterations"].hi == MAX_FIT_ITERATIONS
    # a re-fit no longer than a whole 3DGS fit; a stylization pass 50 times the authors' 600 steps at most
    assert ColorMatchParams.BOUNDS["refit_iterations"].hi == StylizeOptim.BOUNDS["iterations"].hi == 30_000
