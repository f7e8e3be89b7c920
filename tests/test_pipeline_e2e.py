"""End to end: `dvc repro` of the whole pipeline on the embedded tiny scene, in a copy of the repository.

Checks what a DVC user relies on: every stage runs and writes its artifacts for all three transfer
types; a second `dvc repro` does nothing; changing one fit parameter invalidates `fit` and what
follows, but not `make_tiny` or `reconstruct`. Iterations are reduced (see REDUCED) to keep it to a
few minutes on two cores.
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from conftest import REPO_ROOT, run_in

from abcgs.gaussians.ply import read_ply
from abcgs.io.metrics import numeric_leaves
from eval.bench.regression import REDUCED
from eval.bench.repo_copy import IDENTITY, venv_env

pytestmark = pytest.mark.slow

_run = run_in


@pytest.fixture(scope="module")
def repo(tiny_pipeline: dict) -> Path:
    """A git+DVC copy of the working tree with reduced params (:func:`conftest.tiny_pipeline`, shared with the
    cluster tests, which copy its cache before these tests change it)."""
    return tiny_pipeline["repo"]


@pytest.fixture(scope="module")
def first_repro(tiny_pipeline: dict) -> subprocess.CompletedProcess:
    """Its first `dvc repro`, each stage's reads recorded under ``reads/`` beside it."""
    return tiny_pipeline["repro"]


def test_each_stage_reads_under_out_only_its_declared_inputs(repo: Path, first_repro) -> None:
    """What a stage opened or listed under ``out/`` through Python (``abcgs.pipeline.READ_AUDIT_ENV``) lies under
    its deps or its own outputs in ``dvc.lock``: a stage cannot depend on an output DVC does not know it reads."""
    lock = yaml.safe_load((repo / "dvc.lock").read_text())["stages"]
    audits = sorted((repo.parent / "reads").glob("*.json"))
    assert {a.stem for a in audits} >= {"preflight", "masks@tiny", "stylize@tiny_single", "evaluate@tiny_single"}
    for audit in audits:
        entry = lock[audit.stem]
        allowed = [d["path"] for d in entry.get("deps", [])] + [o["path"] for o in entry.get("outs", [])]
        reads = json.loads(audit.read_text())
        stray = [r for r in reads if not any(r == a or r.startswith(a.rstrip("/") + "/") for a in allowed)]
        assert not stray, f"{audit.stem} read {stray} under out/, which are not among its deps {allowed}"
    stylize = json.loads((repo.parent / "reads" / "stylize@tiny_single.json").read_text())
    assert any(r.startswith("out/tiny/masks/") for r in stylize), "the audit saw none of stylize's reads"


def test_all_stages_write_their_artifacts(repo: Path, first_repro) -> None:
    out = repo / "out"
    rec = json.loads((out / "tiny" / "reconstruct.json").read_text())
    assert rec["registered"] == rec["total"] == 16
    fit = json.loads((out / "tiny" / "gs" / "metrics.json").read_text())
    assert fit["psnr"] > 18.0, fit  # 300 steps on 160×120, densifying every 20; ~25 dB seen
    masks = json.loads((out / "tiny" / "masks" / "masks.json").read_text())
    assert masks["source"] == "given" and masks["agreement_with_input_masks"] > 0.9
    assert masks["input_views"] == ["000.png"] and masks["refinement"]["views_recut"] == 15  # the other views re-cut
    reference = json.loads((out / "tiny" / "reference" / "reference.json").read_text())
    assert len(reference["view_names"]) == 16 and reference["n_flows"] == 2 * (15 + 9)  # (i, i+1), (i, i+7), both ways
    for exp in ("tiny_single", "tiny_compositional", "tiny_semantic"):
        d = out / exp / "stylize"
        for name in ("point_cloud.ply", "grid.png", "turntable.mp4"):
            assert (d / name).stat().st_size > 0, f"{exp}: {name} missing or empty"
        assert len(list((d / "renders").glob("*.png"))) == 16
        metrics = json.loads((out / exp / "stylize.json").read_text())
        assert metrics["iterations"] == REDUCED["stylize.optim.iterations"]
        assert numeric_leaves(metrics) == metrics  # names, paths, hashes live in the info file, not in the metric
        info = json.loads((out / exp / "stylize_info.json").read_text())
        assert info["vgg_weights"]["sha256"] and info["iterations"] == metrics["iterations"]
        ev = json.loads((out / exp / "eval.json").read_text())
        assert numeric_leaves(ev) == ev and "ssim" in ev
        ev_info = json.loads((out / exp / "eval_info.json").read_text())
        assert ev_info["provenance"]["fid_kid"]["inception"]["sha256"]
        history = (out / exp / "stylize_history.csv").read_text().splitlines()
        assert history[0].startswith("step,") and len(history) >= 3
        spz = json.loads((out / exp / "point_cloud.spz.json").read_text())
        assert spz["n_gaussians"] == read_ply(d / "point_cloud.ply").num_gaussians and spz["ply_over_spz"] > 2.5, spz
    assert json.loads((out / "tiny" / "point_cloud.spz.json").read_text())["colour_clipped_share"] < 0.05
    page = (repo / "reports" / "report.html").read_text()
    assert all(exp in page for exp in ("tiny_single", "tiny_compositional", "tiny_semantic"))
    assert page.count('id="abcgs-splat-') == 9  # original, stylized, labels for each experiment
    assert (repo / "reports" / "report.png").stat().st_size > 0


@pytest.mark.browser
def test_report_viewer_renders_every_experiment(repo: Path, first_repro) -> None:
    """reports/report.html from `dvc repro` opens from file:// in chromium, with no network, and
    shows each tiny experiment's stylized scene close to our own render of its first training camera."""
    import cv2
    import numpy as np
    from conftest import launch_chromium
    from test_viewer_browser import CHROMIUM_ARGS, _shot

    from abcgs.gaussians import render
    from abcgs.sfm.model import read_scene

    cams = read_scene(repo / "out/tiny/colmap").cameras
    with launch_chromium(CHROMIUM_ARGS) as browser:
        page = browser.new_page(viewport={"width": 400, "height": 700})
        remote = []
        page.on("request", lambda r: remote.append(r.url) if not r.url.startswith(("file:", "data:", "blob:")) else None)
        page.goto((repo / "reports" / "report.html").resolve().as_uri())
        page.wait_for_function("window.abcgsViewer && window.abcgsViewer.ready", timeout=180_000)
        page.evaluate("window.abcgsViewer.ready")
        for i, exp in enumerate(("tiny_single", "tiny_compositional", "tiny_semantic")):
            page.evaluate(f"window.abcgsViewer.setExperiment({i}).then(() => window.abcgsViewer.settle(10))")
            assert page.evaluate("window.abcgsViewer.state.error") is None
            assert page.evaluate("window.abcgsViewer.state.experiment") == exp
            shot = _shot(page)
            img, alpha, _ = render(read_ply(repo / "out" / exp / "stylize" / "point_cloud.ply"), cams[0])
            ours = (img + (1 - alpha)).clamp(0, 1).numpy()
            ours = cv2.resize(ours, (shot.shape[1], shot.shape[0]), interpolation=cv2.INTER_LINEAR)
            r = np.corrcoef(shot.reshape(-1), ours.reshape(-1))[0, 1]
            assert r > 0.8, f"{exp}: viewer vs our rasterizer, correlation {r:.3f}"
    assert remote == []


def _leaf_keys(d: dict, prefix: str = "") -> set[str]:
    keys: set[str] = set()
    for k, v in d.items():
        keys |= _leaf_keys(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k}
    return keys


def test_dvc_metrics_show_is_a_short_headline_table(repo: Path, first_repro) -> None:
    """at most 15 distinct keys across `dvc metrics show`; per-view numbers and timings are records."""
    proc = _run(["dvc", "metrics", "show", "--json"], repo)
    assert proc.returncode == 0, proc.stderr
    files = json.loads(proc.stdout)[""]["data"]
    assert sorted(files) == ["out/tiny/fit_metrics.json", "out/tiny_compositional/metrics.json",
                             "out/tiny_semantic/metrics.json", "out/tiny_single/metrics.json"], sorted(files)
    keys = set().union(*(_leaf_keys(f["data"]) for f in files.values()))
    assert len(keys) <= 15, sorted(keys)
    assert {"heldout_psnr", "heldout_ssim", "n_gaussians", "fit_minutes", "content_ssim", "short_rmse", "long_rmse",
            "short_rmse_floor", "long_rmse_floor", "gram_distance", "stylize_minutes"} <= keys, sorted(keys)
    assert not {"psnr", "ssim"} & keys  # one name, one meaning: the fit's and the stylization's SSIM differ
    assert not any("per_view" in k or "seconds_per_iteration" in k or "provenance" in k for k in keys)
    ev = json.loads((repo / "out" / "tiny_single" / "eval.json").read_text())
    head = files["out/tiny_single/metrics.json"]["data"]
    assert head["content_ssim"] == ev["ssim"] and head["short_rmse"] == ev["short_rmse"]  # the same numbers, fewer
    table = _run(["dvc", "metrics", "show"], repo).stdout
    assert max(len(line) for line in table.splitlines()) < 400, table


def test_dvc_plots_show_writes_the_loss_curves(repo: Path, first_repro, tmp_path: Path) -> None:
    proc = _run(["dvc", "plots", "show", "-o", str(tmp_path / "plots")], repo)
    assert proc.returncode == 0, proc.stderr
    page = (tmp_path / "plots" / "index.html").read_text()
    for name in ("out/tiny/gs/history.csv", "out/tiny_single/stylize_history.csv", "out/tiny_single/eval_views.csv"):
        assert name in page, name


def test_second_repro_is_a_no_op(repo: Path, first_repro) -> None:
    proc = _run(["dvc", "repro"], repo)
    assert proc.returncode == 0, proc.stderr
    assert "Running stage" not in proc.stdout, proc.stdout
    status = _run(["dvc", "status"], repo)
    assert "up to date" in status.stdout, status.stdout


def test_changing_a_fit_param_invalidates_fit_and_downstream_only(repo: Path, first_repro) -> None:
    params = yaml.safe_load((repo / "params.yaml").read_text())
    params["fit"]["iterations"] += 1
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    try:
        status = _run(["dvc", "status"], repo).stdout
        changed = {line.split(":")[0].strip() for line in status.splitlines() if line and not line.startswith("\t")}
        assert "fit@tiny" in changed
        assert not changed & {"make_tiny", "reconstruct@tiny"}, status
    finally:
        params["fit"]["iterations"] -= 1
        (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))


def test_quality_has_not_regressed(repo: Path, first_repro) -> None:
    """SSIM and consistency stay within 3 seed-to-seed standard deviations (floor 0.01) of the recorded
    baseline (tests/baselines/tiny_seed_spread.json, measured with eval/studies/seed_spread.py)."""
    baseline = json.loads((REPO_ROOT / "tests" / "baselines" / "tiny_seed_spread.json").read_text())["metrics"]
    failures = []
    for exp, metrics in baseline.items():
        ev = json.loads((repo / "out" / exp / "eval.json").read_text())
        for key, ref in metrics.items():
            tol = max(3.0 * ref["std"], 0.01)
            worse = ref["mean"] - ev[key] if key == "ssim" else ev[key] - ref["mean"]
            if worse > tol:
                failures.append(f"{exp}.{key} = {ev[key]:.4f}, baseline {ref['mean']:.4f} ± {tol:.4f}")
    assert not failures, "quality regressed:\n" + "\n".join(failures)


# ------------------------------------------------------------------------------------------------ bad params
def _with_params(repo: Path, edit) -> str:
    """Apply ``edit`` to the repo's params.yaml; returns the original text (restore it in ``finally``)."""
    text = (repo / "params.yaml").read_text()
    params = yaml.safe_load(text)
    edit(params)
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    return text


def test_a_params_typo_stops_plain_dvc_repro_before_any_output_is_lost(repo: Path, first_repro) -> None:
    ply = repo / "out" / "tiny" / "gs" / "point_cloud.ply"
    before = ply.read_bytes()
    original = _with_params(repo, lambda p: p["fit"].__setitem__("iteratons", p["fit"].pop("iterations")))
    try:
        t0 = time.perf_counter()
        proc = _run(["dvc", "repro"], repo)
        seconds = time.perf_counter() - t0
    finally:
        (repo / "params.yaml").write_text(original)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0 and "fit.iteratons" in out, out[-3000:]
    assert "Running stage 'fit@tiny'" not in out and ply.read_bytes() == before, "the fitted scene was touched"
    print(f"typo caught by the preflight stage in {seconds:.1f} s")
    assert seconds < 30, f"the typo took {seconds:.0f} s to report"


@pytest.mark.parametrize("where", ["experiment", "scene"])
def test_a_name_with_shell_syntax_runs_no_command(repo: Path, first_repro, tmp_path: Path, where: str) -> None:
    marker = tmp_path / "injected"
    bad = f"e; touch {marker} #"

    def edit(p: dict) -> None:
        if where == "experiment":
            p["experiments"][bad] = dict(p["experiments"]["tiny_single"])
        else:
            p["data"]["scenes"][bad] = dict(p["data"]["scenes"]["tiny"])

    original = _with_params(repo, edit)
    try:
        proc = _run(["dvc", "repro"], repo)
    finally:
        (repo / "params.yaml").write_text(original)
    assert not marker.exists(), "a command from a params name ran"
    assert proc.returncode != 0
    out = proc.stdout + proc.stderr
    assert ("a name must match" in out or "must be letters" in out) or "stage name" in out.lower(), out[-3000:]


def test_a_scene_folder_with_a_space_and_accents_reconstructs(repo: Path, first_repro) -> None:
    spaced = repo / "data" / "tiny copy ü"
    shutil.copytree(repo / "data" / "tiny", spaced)
    original = _with_params(repo, lambda p: p["data"]["scenes"].__setitem__("spaced", {"path": "data/tiny copy ü"}))
    try:
        proc = _run(["dvc", "repro", "reconstruct@spaced"], repo)
        assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
        assert json.loads((repo / "out" / "spaced" / "reconstruct.json").read_text())["registered"] == 16
    finally:
        (repo / "params.yaml").write_text(original)
        shutil.rmtree(spaced)
        shutil.rmtree(repo / "out" / "spaced", ignore_errors=True)
        _run(["dvc", "repro"], repo)  # back to the module's pipeline (restores the lock's view)


# ------------------------------------------------------------------------------------------------ at scale
# These run last in this module: they add a scene, commit, queue experiments and push to a remote.
def _changed_stages(repo: Path) -> set[str]:
    status = _run(["dvc", "status"], repo).stdout
    return {line[:-1] for line in status.splitlines() if line.endswith(":") and not line.startswith("\t")}


def test_a_scene_override_reruns_only_that_scenes_branch(repo: Path, first_repro) -> None:
    """A second scene with its own fit override: changing the override invalidates that scene's stages only."""
    original = (repo / "params.yaml").read_text()
    params = yaml.safe_load(original)
    params["data"]["scenes"]["tiny2"] = {"path": "data/tiny", "fit": {"iterations": 60, "min_psnr": 0}}  # a short fit
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    try:
        proc = _run(["dvc", "repro", "masks@tiny2"], repo)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        assert "Running stage 'fit@tiny2'" in proc.stdout and "Running stage 'fit@tiny'" not in proc.stdout
        fit2 = json.loads((repo / "out/tiny2/gs/metrics.json").read_text())
        assert fit2["iterations"] == 60  # the override, not the global fit.iterations
        params["data"]["scenes"]["tiny2"]["fit"]["iterations"] = 61
        (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
        changed = _changed_stages(repo)
        assert {"fit@tiny2", "masks@tiny2"} <= changed, changed
        assert not {c for c in changed if c.endswith("@tiny") or "tiny_" in c}, changed  # the tiny branch stays cached
        diff = _run(["dvc", "params", "diff"], repo).stdout
        assert "data.scenes.tiny2.fit.iterations" in diff, diff
    finally:
        (repo / "params.yaml").write_text(original)
        # the extra scene's outputs go too: the report stage depends on all of out/, so leftovers committed to
        # git would make a clone's out/ differ from the locked one (seen: clone B re-ran `report`)
        shutil.rmtree(repo / "out" / "tiny2", ignore_errors=True)


def test_a_densifying_colour_refit_carries_its_labels_through_stylize_and_the_viewer(repo: Path, first_repro) -> None:
    """``colormatch.refine_every`` set: the re-fit grows Gaussians, ``fitted_rows.npy`` maps each onto the
    fitted scene, stylize reads it (labels, SH bands) and the viewer gives every stylized Gaussian its label."""
    from abcgs.view.outputs import load_experiment

    original, lock = (repo / "params.yaml").read_text(), (repo / "dvc.lock").read_text()
    # metrics and plots are cache: false, so `dvc checkout` cannot bring them back: keep the whole of out/
    kept = repo.parent / "out-before-refine"
    shutil.copytree(repo / "out", kept)
    params = yaml.safe_load(original)
    params["colormatch"]["refine_every"] = 10
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    try:
        proc = _run(["dvc", "repro", "stylize@tiny_compositional"], repo)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        import numpy as np

        fitted = read_ply(repo / "out/tiny/gs/point_cloud.ply").num_gaussians
        rows = np.load(repo / "out/tiny/colormatch/tiny_compositional/fitted_rows.npy")
        counts = np.bincount(rows, minlength=fitted)
        assert (counts > 1).sum() > 0  # clones and split children name their parent's row
        assert len(rows) == read_ply(repo / "out/tiny_compositional/stylize/point_cloud.ply").num_gaussians
        labels = np.load(repo / "out/tiny/masks/gaussian_labels.npy")
        exp = load_experiment(repo / "out/tiny_compositional", scene="tiny", max_gaussians=10 ** 9)
        assert "labels" in exp.layers  # every stylized Gaussian has its fitted row's label
        assert len(set(labels[rows])) > 1
    finally:  # the locked outputs back, for the tests that follow (a clone of this repo must find them up to date)
        (repo / "params.yaml").write_text(original)
        (repo / "dvc.lock").write_text(lock)
        shutil.rmtree(repo / "out")
        shutil.move(kept, repo / "out")
    changed = _changed_stages(repo) - {"preflight"}  # the input checks re-run on any params edit of earlier tests
    assert not changed, changed


def test_experiments_of_one_scene_share_its_stages(repo: Path, first_repro) -> None:
    """a second experiment on the tiny scene (same painting, NNFM) runs only its own stylize and
    evaluate: not the scene's stages (fit, masks, the evaluation reference of original renders and flows) and
    not the colour match of its painting, which it shares with the FAST experiment. The reference follows the
    flow settings, not the metric settings; the colour match follows the fit, not `stylize`."""
    original = (repo / "params.yaml").read_text()
    params = yaml.safe_load(original)
    params["experiments"]["tiny_single_nnfm"] = {**params["experiments"]["tiny_single"], "method": "nnfm"}
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    try:
        proc = _run(["dvc", "repro", "evaluate@tiny_single_nnfm"], repo)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        ran = set(re.findall(r"Running stage '([^']+)'", proc.stdout)) - {"preflight"}  # params changed: it checks them
        assert ran == {"stylize@tiny_single_nnfm", "evaluate@tiny_single_nnfm"}, ran
        info = json.loads((repo / "out/tiny_single_nnfm/eval_info.json").read_text())
        assert info["method"] == "nnfm" and info["provenance"]["reference"]["n_flows"] > 0
        params["evaluate"]["fid_patch_size"] += 8  # a metric setting: every evaluate, not the reference
        (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
        changed = _changed_stages(repo)
        assert "evaluate@tiny_single" in changed and "reference@tiny" not in changed, changed
        params["evaluate"]["long_term_gap"] += 1  # a flow setting: the reference too
        (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
        assert "reference@tiny" in _changed_stages(repo)
        params["stylize"]["weights"]["style"] *= 2  # a stylization setting: the stylize runs, not their colour match
        (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
        changed = _changed_stages(repo)
        assert "stylize@tiny_single_nnfm" in changed and "colormatch@tiny_single" not in changed, changed
        params["fit"]["iterations"] += 1  # the fit: re-run, and the colour matches of its scene downstream of it
        (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
        assert "fit@tiny" in _changed_stages(repo)
        dag = _run(["dvc", "dag", "--dot", "stylize@tiny_single_nnfm"], repo).stdout
        assert '"fit@tiny" -> "colormatch@tiny_single";' in dag, dag
        assert '"colormatch@tiny_single" -> "stylize@tiny_single_nnfm";' in dag, dag
    finally:
        (repo / "params.yaml").write_text(original)
        shutil.rmtree(repo / "out" / "tiny_single_nnfm", ignore_errors=True)  # see the scene-override test


def _exp_rows(repo: Path) -> dict[str, dict[str, str]]:
    """`dvc exp show --csv --only-changed` as experiment name → {column: value}; DVC prefixes the first column of
    each file with the file's path (``out/tiny_single/metrics.json:ssim``), so columns are also keyed by the bare
    name after the last colon."""
    table = _run(["dvc", "exp", "show", "--csv", "--only-changed"], repo).stdout
    rows = {}
    for r in csv.DictReader(io.StringIO(table)):
        if r.get("Experiment"):
            rows[r["Experiment"]] = {**r, **{k.rsplit(":", 1)[-1]: v for k, v in r.items() if k}}
    return rows


@pytest.fixture(scope="module")
def shared(repo: Path, first_repro, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The copy as clone A of a team: a git remote (bare repository) and a DVC remote (a local directory: the
    same code path as an NFS share), configured and committed before any experiment, then `dvc push`."""
    root = tmp_path_factory.mktemp("shared")
    store, origin = root / "dvc-store", root / "origin.git"
    store.mkdir()
    git = ["git", "-c", "user.name=ci", "-c", "user.email=ci@example.invalid"]
    subprocess.run(["git", "init", "-q", "--bare", str(origin)], check=True)
    for cmd in (["dvc", "remote", "add", "-d", "shared", str(store)], ["git", "add", "-A"],
                git + ["commit", "-qm", "pipeline results and the shared remote"],
                ["git", "remote", "add", "origin", str(origin)]):
        proc = _run(cmd, repo)
        assert proc.returncode == 0, proc.stderr
    branch = _run(["git", "rev-parse", "--abbrev-ref", "HEAD"], repo).stdout.strip()
    assert _run(["git", "push", "-q", "origin", f"HEAD:{branch}"], repo).returncode == 0
    push = _run(["dvc", "push"], repo)
    assert push.returncode == 0, push.stderr
    return {"store": store, "origin": origin, "branch": branch}


@pytest.fixture(scope="module")
def queued(repo: Path, shared: dict) -> dict[str, str]:
    """A queued sweep of two experiments, run two at a time: experiment name → lambda_style."""
    proc = _run(["dvc", "exp", "run", "--queue", "-S", "stylize.weights.style=1,4", "evaluate@tiny_single"], repo)
    assert proc.returncode == 0 and proc.stdout.count("Queued experiment") == 2, proc.stdout + proc.stderr
    # `dvc queue start` can outlive its queue: a worker that never shuts down keeps it (and any pipe it writes to)
    # open, so it writes to a file, is not waited for, and is stopped once the queue's status says both are done
    with open(repo.parent / "queue-start.log", "w") as log:
        starter = subprocess.Popen(["dvc", "queue", "start", "-j", "2"], cwd=repo, env=venv_env(), stdout=log,
                                   stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 1800
        while time.monotonic() < deadline:
            status = _run(["dvc", "queue", "status"], repo).stdout
            if "Queued" not in status and "Running" not in status and status.count("Success") + status.count("Failed") >= 2:
                break
            time.sleep(10)
    finally:
        _run(["dvc", "queue", "stop", "--kill"], repo)
        if starter.poll() is None:  # the starter and its workers share its session's process group
            os.killpg(starter.pid, signal.SIGKILL)
        starter.wait(60)
    assert status.count("Success") == 2, status
    return {name: r["stylize.weights.style"] for name, r in _exp_rows(repo).items()}


def test_a_queued_sweep_runs_two_experiments_at_once(repo: Path, queued: dict) -> None:
    """`dvc exp run --queue -S stylize.weights.style=1,4` then `dvc queue start -j 2`: both in `dvc exp show`,
    each with its own headline metrics."""
    assert sorted(queued.values()) == ["1", "4"], queued
    rows = _exp_rows(repo)
    ssims = {float(rows[name]["content_ssim"]) for name in queued}
    assert len(ssims) == 2 and all(0.0 < s <= 1.0 for s in ssims)  # two different stylizations, both measured


def test_a_second_clone_pulls_instead_of_recomputing(repo: Path, shared: dict, queued: dict, tmp_path: Path) -> None:
    """Clone B: `dvc pull` then `dvc repro` is a no-op; `dvc exp push/pull` moves an experiment from A to B."""
    clone = tmp_path / "B"
    subprocess.run(["git", "clone", "-q", "-b", shared["branch"], str(shared["origin"]), str(clone)], check=True)
    for cmd in IDENTITY:  # `dvc exp apply` commits; a fresh machine has no identity in its HOME
        subprocess.run(cmd, cwd=clone, check=True)
    pull = _run(["dvc", "pull"], clone)
    assert pull.returncode == 0, pull.stderr
    proc = _run(["dvc", "repro"], clone)
    ran = set(re.findall(r"Running stage '([^']+)'", proc.stdout))
    assert proc.returncode == 0 and ran <= {"preflight"}, proc.stdout  # at most the seconds of the input checks
    assert "up to date" in _run(["dvc", "status"], clone).stdout
    name = next(n for n, lam in queued.items() if lam == "4")
    assert _run(["dvc", "exp", "push", "origin", name], repo).returncode == 0
    got = _run(["dvc", "exp", "pull", "origin", name], clone)
    assert got.returncode == 0, got.stderr
    applied = _run(["dvc", "exp", "apply", name], clone)
    assert applied.returncode == 0, applied.stdout + applied.stderr
    assert yaml.safe_load((clone / "params.yaml").read_text())["stylize"]["weights"]["style"] == 4
    assert (clone / "out/tiny_single/stylize/point_cloud.ply").stat().st_size > 0  # its outputs came from the store
    here = json.loads((clone / "out/tiny_single/metrics.json").read_text())["content_ssim"]
    assert abs(here - float(_exp_rows(repo)[name]["content_ssim"])) < 1e-9
