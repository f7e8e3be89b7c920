"""The evaluate stage end to end on a synthetic scene: output keys never claim official metrics for proxies,
bad inputs (missing runs, mismatched view counts) fail with clear errors."""

from __future__ import annotations

import json
import re
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.errors import InputError
from abcgs.evaluation.evaluate import evaluate_images, evaluate_scene
from abcgs.evaluation.params import EvalParams
from abcgs.gaussians import GaussianModel
from abcgs.io.metrics import EXPERIMENT_HEADLINE, experiment_headline
from abcgs.render.sh import rgb_to_sh0
from abcgs.runtime import torch_threads

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def _one_torch_thread():
    with torch_threads(1):
        yield


def eval_scene(n_views: int = 5):
    """A small random scene for the evaluation: ``n_views`` cameras round it, the scene, a recoloured copy (the
    "stylized" one) and a random style image."""
    rng = np.random.default_rng(0)
    pts = rng.uniform([-1.5, -1, 0.0], [1.5, 1, 0.6], (600, 3))
    model = GaussianModel.from_points(pts, rng.random((600, 3)), init_opacity=0.9)
    w, h = 64, 48
    cams = [Camera(f"v{k:02d}.png", intrinsics(60.0, w, h), look_at(np.array([-0.3 + 0.1 * k, 0, -3.0]), np.array([0, 0, 0.3])), w, h)
            for k in range(n_views)]
    styl = model.detach()
    styl.sh0 = rgb_to_sh0(torch.from_numpy(rng.random((600, 3))).float())[:, None, :]
    style = rng.random((80, 120, 3)).astype(np.float32)
    return cams, model, styl, style


@pytest.fixture(scope="module")
def scene():
    return eval_scene()


def walk_keys(obj, prefix=""):
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield f"{prefix}{k}", k
            yield from walk_keys(v, f"{prefix}{k}.")


PARAMS = EvalParams(fid_patches_per_image=2, fid_patch_size=32, fps_passes=1, long_term_gap=7, kid_subsets=5)


def test_evaluate_scene_names_proxies_as_proxies(scene, proxy) -> None:
    cams, model, styl, style = scene
    res = evaluate_scene(cams, model, styl, [style], PARAMS, perceptual=proxy,
                         stylize_info={"stylize_seconds": 12.0, "iterations": 3, "seconds_per_iteration": {"render": 1.0}})
    m = res.metrics
    keys = {k for _, k in walk_keys(m)}
    for bad in ("lpips", "artfid", "fid", "kid", "short_lpips", "long_lpips", "content_lpips"):
        assert bad not in keys, f"proxy written under the official name {bad!r}"
    for good in ("ssim", "ssim_impl", "content_lpips_proxy_vgg", "short_rmse", "short_lpips_proxy_vgg", "long_rmse",
                 "long_lpips_proxy_vgg", "fid_tf_inception", "kid_tf_inception", "artfid_proxy", "render_fps", "stylize_seconds"):
        assert good in m, good
    assert m["long_term_gap"] == 4 and m["n_views"] == 5  # 7 clipped to n − 1
    assert m["artfid_components"]["content_distance"]["name"] == "lpips_proxy_vgg"
    assert m["artfid_components"]["style_distance"]["name"] == "fid_tf_inception"
    assert m["artfid_proxy"] == pytest.approx((1 + m["content_lpips_proxy_vgg"]) * (1 + m["fid_tf_inception"]))
    assert m["provenance"]["perceptual"]["comparable_to_paper"] is False
    fk = m["provenance"]["fid_kid"]
    assert fk["n_stylized_patches"] == 10 and fk["n_style_patches"] == 10 and len(fk["inception"]["sha256"]) == 64
    assert 0 < m["ssim"] < 1 and m["render_fps"] > 0 and m["speed"]["backend"]
    assert len(res.per_view) == 5 and res.per_view[-1]["short_rmse"] is None
    # pose pairs (a dolly along x in file order: the same pairs), the floor and the valid fraction of every pair
    assert m["pairs"] == "pose" and m["consistency_pairs"]["order"] == ["v00", "v01", "v02", "v03", "v04"]
    short = m["consistency_pairs"]["short"]
    assert [(r["view"], r["pair_view"]) for r in short] == [("v00", "v01"), ("v01", "v02"), ("v02", "v03"), ("v03", "v04")]
    assert all(0 < r["valid_fraction"] <= 1 and np.isfinite(r["rmse_floor"]) for r in short)
    assert m["short_valid_fraction"] == pytest.approx(np.mean([r["valid_fraction"] for r in short]))
    assert 0 < m["short_rmse_floor"] < 1 and 0 < m["long_rmse_floor"] < 1
    assert res.per_view[0]["short_pair"] == "v01" and res.per_view[0]["short_valid_fraction"] == short[0]["valid_fraction"]
    json.dumps(m)  # serialisable


def test_identical_scenes_score_perfect_content(scene, proxy) -> None:
    cams, model, _, style = scene
    res = evaluate_scene(cams[:3], model, model, [style], PARAMS, perceptual=proxy)
    assert res.metrics["ssim"] == pytest.approx(1.0, abs=1e-9)
    assert res.metrics["content_lpips_proxy_vgg"] == pytest.approx(0.0, abs=1e-6)
    # the unstylized scene scores its own floor
    assert res.metrics["short_rmse"] == res.metrics["short_rmse_floor"]
    assert res.metrics["long_rmse"] == res.metrics["long_rmse_floor"]


def test_mismatched_counts_and_missing_inputs_fail_clearly(scene, proxy, tmp_path) -> None:
    img = [np.zeros((20, 24, 3), np.float32)] * 3
    with pytest.raises(InputError, match="3 original renders but 2 stylized"):
        evaluate_images(img, img[:2], [img[0]], PARAMS, perceptual=proxy)
    with pytest.raises(InputError, match="no style images"):
        evaluate_images(img, img, [], PARAMS, perceptual=proxy)
    with pytest.raises(InputError, match="pairs views by their cameras"):
        evaluate_images(img, img, [img[0]], PARAMS, perceptual=proxy)
    from abcgs.evaluation.evaluate import load_stylize_run
    from abcgs.layout import experiment

    run = experiment("exp", tmp_path)
    with pytest.raises(InputError, match="run the stylize stage"):
        load_stylize_run(run.stylize, run.stylize_record, "exp", ["a", "b", "c"])
    run.stylize.renders.mkdir(parents=True)
    run.stylize.ply.write_bytes(b"")
    run.stylize_record.write_text("{}")
    for s in ("a", "b"):
        (run.stylize.renders / f"{s}.png").write_bytes(b"")
    with pytest.raises(InputError, match="holds 2 renders but the scene has 3 views"):
        load_stylize_run(run.stylize, run.stylize_record, "exp", ["a", "b", "c"])
    with pytest.raises(InputError, match="no render for views"):
        load_stylize_run(run.stylize, run.stylize_record, "exp", ["a", "c"])
    cams, model, styl, style = scene
    with pytest.raises(InputError, match="saved stylize renders"):
        evaluate_scene(cams[:3], model, styl, [style], PARAMS, perceptual=proxy, saved_renders=[img[0]] * 2)


def test_eval_params_reject_unknown_keys() -> None:
    from abcgs.errors import ParamsError
    from abcgs.params import validate_params

    p = validate_params({"data": {"scenes": {"s": "x"}}, "evaluate": {"long_term_gap": 3}})
    assert p.evaluate.long_term_gap == 3 and p.evaluate.flow == "auto"
    with pytest.raises(ParamsError, match="evaluate.flow"):
        validate_params({"data": {"scenes": {"s": "x"}}, "evaluate": {"flow": "raf"}})
    with pytest.raises(ParamsError, match="evaluate.long_gap: unknown key"):
        validate_params({"data": {"scenes": {"s": "x"}}, "evaluate": {"long_gap": 3}})


def _numbers(m: dict, prefix: str = "") -> dict:
    """Every numeric leaf of a metrics record except timings/speed (they differ run to run)."""
    out = {}
    for k, v in m.items():
        if k in ("eval_timings_s", "speed", "render_fps", "provenance"):
            continue
        if isinstance(v, dict):
            out.update(_numbers(v, f"{prefix}{k}."))
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out[f"{prefix}{k}"] = v
    return out


def test_stored_reference_gives_the_same_metrics(scene, proxy, tmp_path) -> None:
    """The per-scene reference (original renders + flows, saved and loaded) changes no metric; it is checked
    against the views, the evaluate settings and the fitted scene it was made from."""
    from abcgs.evaluation.reference import compute_reference, load_reference, save_reference

    cams, model, styl, style = scene
    direct = evaluate_scene(cams, model, styl, [style], PARAMS, perceptual=proxy)
    ref = compute_reference(cams, model, PARAMS, model_digest="abc")
    assert ref.info["n_flows"] == 2 * (4 + 1)  # short pairs (i, i+1) and the long pair (0, 4), both directions
    save_reference(tmp_path / "ref", ref)
    loaded = load_reference(tmp_path / "ref", cams, PARAMS, model_digest="abc")
    stored = evaluate_scene(cams, model, styl, [style], PARAMS, perceptual=proxy, reference=loaded)
    assert _numbers(stored.metrics) == _numbers(direct.metrics)
    assert stored.metrics["provenance"]["flow"] == direct.metrics["provenance"]["flow"]
    assert stored.metrics["provenance"]["reference"]["n_flows"] == 10
    assert ref.info["floor"]["short"]["rmse"] == stored.metrics["short_rmse_floor"] == direct.metrics["short_rmse_floor"]
    with pytest.raises(InputError, match="other evaluate settings.*long_term_gap"):
        load_reference(tmp_path / "ref", cams, PARAMS.model_copy(update={"long_term_gap": 2}))
    with pytest.raises(InputError, match="other evaluate settings.*pairs"):
        load_reference(tmp_path / "ref", cams, PARAMS.model_copy(update={"pairs": "index"}))
    moved = [cams[0], cams[3], cams[2], cams[1], cams[4]]  # views 1 and 3 swap poses: other pairs
    moved = [Camera(c.name, m.K, m.viewmat, m.width, m.height) for c, m in zip(cams, moved)]
    with pytest.raises(InputError, match="other consistency pairs"):
        load_reference(tmp_path / "ref", moved, PARAMS)
    with pytest.raises(InputError, match="other views"):
        load_reference(tmp_path / "ref", cams[:4], PARAMS)
    with pytest.raises(InputError, match="another fit"):
        load_reference(tmp_path / "ref", cams, PARAMS, model_digest="def")
    with pytest.raises(InputError, match="no evaluation reference"):
        load_reference(tmp_path / "nothing", cams, PARAMS, scene="tiny")
    from abcgs.evaluation.reference import FLOW_SETTINGS, WarpFloor, settings_of

    assert tuple(settings_of(PARAMS)) == FLOW_SETTINGS  # what the reference stage tracks is what it stores
    assert WarpFloor.from_json(ref.floor.to_json()) == ref.floor == loaded.floor


def test_a_reference_folder_is_the_same_bytes_when_computed_again(scene, tmp_path) -> None:
    """The folder is a dep of every evaluation of its scene: no wall clock in it (timings, zip entry dates), so a
    re-run on another machine or a later day gives DVC the same hash. Zip dates have a 2 s resolution, hence the
    wait."""
    from abcgs.evaluation.reference import compute_reference, save_reference

    cams, model, _, _ = scene
    save_reference(tmp_path / "a", compute_reference(cams, model, PARAMS, model_digest="abc"))
    time.sleep(2.1)
    again = compute_reference(cams, model, PARAMS, model_digest="abc")
    assert set(again.timings_s) == {"render", "flow", "floor"}
    save_reference(tmp_path / "b", again)
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert files == ["flows.npz", "masks.npz", "reference.json", "renders.npz"]
    for name in files:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


def test_pair_workers_give_the_same_metrics(scene, proxy) -> None:
    """``evaluate.workers`` spreads the content and consistency pairs over threads: every metric is the same
    number as on one worker (each pair runs on the stage's torch threads either way)."""
    cams, model, styl, style = scene
    one = evaluate_scene(cams, model, styl, [style], PARAMS.model_copy(update={"workers": 1}), perceptual=proxy)
    two = evaluate_scene(cams, model, styl, [style], PARAMS.model_copy(update={"workers": 2}), perceptual=proxy)
    assert _numbers(two.metrics) == _numbers(one.metrics)
    assert one.metrics["speed"]["pair_workers"] == 1 and two.metrics["speed"]["pair_workers"] == 2


def _headline_table() -> set[str]:
    """The keys in the first column of docs/METRICS.md's per-experiment headline table."""
    text = (REPO / "docs" / "METRICS.md").read_text().split("Per experiment (`out/<exp>/metrics.json`):", 1)[1]
    rows = text.strip().splitlines()
    rows = rows[: next((k for k, line in enumerate(rows) if not line.startswith("|")), len(rows))]
    return {key for line in rows for key in re.findall(r"`([a-z_]+)`", line.split("|")[1])}


def test_the_record_gives_the_documented_headline_and_view_columns(scene, proxy) -> None:
    """``eval_record`` is the one mapping from the typed results to ``eval.json``: the headline picked from it has one
    key per :data:`EXPERIMENT_HEADLINE` name, the same keys as the committed tiny experiment's ``metrics.json`` and
    docs/METRICS.md's table; ``eval_views.csv`` the committed columns. With the official components (real LPIPS,
    art-Inception) the same fields go under the official names, and no proxy name is left."""
    from abcgs.evaluation.reference import render_views

    cams, model, styl, style = scene
    res = evaluate_scene(cams, model, styl, [style], PARAMS, perceptual=proxy, stylize_info={"stylize_seconds": 30.0},
                         saved_renders=render_views(styl, cams, "auto")[0])
    head = experiment_headline(res.metrics)
    committed = json.loads((REPO / "out" / "tiny_single" / "metrics.json").read_text())
    assert len(head) == len(EXPERIMENT_HEADLINE)
    assert set(head) == set(committed) == _headline_table()
    header = (REPO / "out" / "tiny_single" / "eval_views.csv").read_text().splitlines()[0].split(",")
    assert list(res.per_view[0]) == header and len(res.per_view) == len(cams)

    ev = res.images
    official = replace(res, images=replace(ev, content=replace(ev.content, perceptual_name="lpips"),
                                           artfid=replace(ev.artfid, official=True)))
    m = official.metrics
    assert set(experiment_headline(m)) == {k.replace("_proxy_vgg", "").replace("artfid_proxy", "artfid") for k in head}
    assert not [k for k in m if "proxy" in k] and m["artfid"] == res.metrics["artfid_proxy"]
    assert m["short_lpips"] == res.metrics["short_lpips_proxy_vgg"]
    assert m["consistency_pairs"]["short"][0]["lpips"] == res.metrics["consistency_pairs"]["short"][0]["lpips_proxy_vgg"]
    assert list(official.per_view[0]) == [c.replace("_proxy_vgg", "") for c in header]


def test_an_object_scene_adds_its_object_metrics_to_the_headline(scene, proxy) -> None:
    """An object scene's evaluation: the three keys of OBJECT_HEADLINE join the headline, documented in METRICS.md,
    and its per-view rows carry the object columns."""
    from abcgs.io.metrics import OBJECT_HEADLINE
    from abcgs.types import Background

    cams, model, styl, style = scene
    res = evaluate_scene(cams, model, styl, [style], PARAMS, perceptual=proxy, stylize_info={"stylize_seconds": 30.0},
                         background=Background(object=True))
    head = experiment_headline(res.metrics)
    assert set(OBJECT_HEADLINE) <= set(head) and len(head) == len(EXPERIMENT_HEADLINE) + len(OBJECT_HEADLINE)
    assert 0.0 <= head["background_change"] <= 1.0 and 0.0 <= head["silhouette_iou"] <= 1.0
    text = (REPO / "docs" / "METRICS.md").read_text()
    assert all(f"`{k}`" in text for k in OBJECT_HEADLINE)
    assert {"ssim_object", "background_change", "silhouette_iou"} <= set(res.per_view[0])
