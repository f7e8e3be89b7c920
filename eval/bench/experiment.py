"""Benchmarks as DVC experiments of the one pipeline: run a params overlay, show and publish its results.

    python -m eval run experiment run eval/params/quality_fern.yaml --name quality-fern --shared ../shared/data
    python -m eval run experiment show quality-fern --readme README.md --figure docs/img/quality/fern_overview.jpg

``run`` turns the overlay into ``dvc exp run --temp -n NAME -S ...`` overrides against the workspace's
``params.yaml``: the overlay's ``data``, ``colormatches`` and ``experiments`` replace the workspace's (keys it lacks
are removed with ``~key``), every other section is merged key by key (``++key=value``). ``${shared}`` in the overlay
becomes the absolute ``--shared`` folder. DVC runs the experiment in a temporary copy and keeps every finished
stage in its cache: run the same command again after an interruption and the finished stages are restored from
the run cache, not recomputed (``dvc exp show`` lists the runs with their headline columns).

``show`` checks the experiment's commit out into a temporary git worktree that shares this repository's DVC cache
(the one its config names: ``dvc cache dir``),
restores its outputs, prints the results table (the report stage's ``reports/results.md``) and, when asked, copies
the comparison figure to ``--figure`` (and any other output with ``--copy SRC=DST``) and writes the table between
README's ``<!-- results:begin -->`` and ``<!-- results:end -->`` lines, followed by the averages and comparisons
the README's text quotes (:func:`summary`, computed from the table). The workspace's params, dvc.lock and outputs
stay as they are.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs.errors import ParamsError
from abcgs.overlay import REPLACED, apply_overlay, read_overlay

ROOT = Path(__file__).resolve().parents[2]
BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"


def _leaves(tree: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(tree, dict) and tree:
        out: dict[str, Any] = {}
        for k, v in tree.items():
            out.update(_leaves(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: tree}


def _value(v: Any) -> str:
    """A value in DVC's (Hydra's) override grammar: strings single-quoted, the rest as YAML flow."""
    if isinstance(v, str):
        return "'" + v.replace("\\", "\\\\").replace("'", "\\'") + "'"
    if v is None:
        return "null"
    return json.dumps(v) if not isinstance(v, bool) else str(v).lower()


def _removed(old: Any, new: Any, prefix: str) -> list[str]:
    """The shallowest keys under ``prefix`` that ``old`` has and ``new`` lacks."""
    if not isinstance(old, dict):
        return []
    out: list[str] = []
    for k, v in old.items():
        key = f"{prefix}.{k}"
        if not isinstance(new, dict) or k not in new:
            out.append(key)
        else:
            out += _removed(v, new[k], key)
    return out


def overrides(base: dict, overlay: dict) -> list[str]:
    """``-S`` arguments that make ``base`` (the workspace's params) into ``base`` with ``overlay`` applied."""
    args: list[str] = []
    for section in REPLACED:
        if section in overlay:
            args += [f"~{k}" for k in _removed(base.get(section) or {}, overlay[section] or {}, section)]
            old = _leaves(base.get(section) or {}, section)
            args += [f"++{k}={_value(v)}" for k, v in sorted(_leaves(overlay[section] or {}, section).items())
                     if v != {} and old.get(k, object()) != v]
    for section, value in overlay.items():
        if section in REPLACED:
            continue
        for key, v in sorted(_leaves(value, section).items()):
            args.append(f"++{key}={_value(v)}")
    return args


def cmd_run(a: argparse.Namespace) -> int:
    base = yaml.safe_load((ROOT / "params.yaml").read_text(encoding="utf-8"))
    try:
        overlay = read_overlay(a.overlay, a.shared)
    except ParamsError as exc:
        raise SystemExit(str(exc)) from None
    args = overrides(base, overlay) + [f"++{s}" for s in a.set]
    cmd = [sys.executable, "-m", "dvc", "exp", "run", "--temp", "-n", a.name]
    for arg in args:
        cmd += ["-S", arg]
    print("$ " + " ".join(cmd[:7]) + f" … ({len(args)} overrides)", flush=True)
    if a.dry_run:
        print("\n".join(args))
        return 0
    with pipeline_for(apply_overlay(base, overlay)):
        return subprocess.run(cmd, cwd=ROOT).returncode


@contextlib.contextmanager
def pipeline_for(params: dict) -> Iterator[None]:
    """The workspace's ``dvc.yaml`` as the overlaid ``params`` need it while the experiment starts (the report
    stage's deps follow the experiments: :func:`abcgs.dag.pipeline_yaml`), so that ``dvc exp run`` takes it into
    the experiment; the workspace's own is put back afterwards."""
    from abcgs.dag import pipeline_yaml
    from abcgs.io.atomic import write_text

    dvc_yaml = ROOT / "dvc.yaml"
    with tempfile.TemporaryDirectory(prefix="abcgs-exp-params-") as tmp:
        params_path = Path(tmp) / "params.yaml"
        params_path.write_text(yaml.safe_dump(params, sort_keys=False), encoding="utf-8")
        text = pipeline_yaml(ROOT, params_path)
    own = dvc_yaml.read_text(encoding="utf-8")
    if text == own:
        yield
        return
    write_text(dvc_yaml, text)
    try:
        yield
    finally:
        write_text(dvc_yaml, own)


def _git(args: list[str], cwd: Path, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=cwd, check=check, capture_output=True, text=True)


def find_exp_commit(name: str) -> str:
    """The newest experiment ref named ``name`` (``refs/exps/<..>/<baseline>/<name>``)."""
    refs = _git(["for-each-ref", "--sort=-committerdate", "--format=%(objectname) %(refname)", "refs/exps"], ROOT)
    for line in refs.stdout.splitlines():
        sha, ref = line.split(" ", 1)
        if ref.rsplit("/", 1)[-1] == name:
            return sha
    raise SystemExit(f"no DVC experiment named {name!r}; `dvc exp list --all-commits` shows the ones that exist")


def replace_block(text: str, table: str) -> str:
    """``text`` with the lines between :data:`BEGIN` and :data:`END` replaced by ``table``."""
    pattern = re.compile(re.escape(BEGIN) + r".*?" + re.escape(END), re.S)
    if not pattern.search(text):
        raise SystemExit(f"the README has no {BEGIN} … {END} block to write the table into")
    return pattern.sub(lambda _: f"{BEGIN}\n{table.strip()}\n{END}", text, count=1)


def _rows(table: str) -> list[dict[str, str]]:
    """The rows of a markdown results table as ``{header: cell}``, an empty painting cell filled from the row above."""
    lines = [line.strip().strip("|").split("|") for line in table.strip().splitlines() if line.startswith("|")]
    if len(lines) < 3:
        return []
    head = [h.strip() for h in lines[0]]
    rows, painting = [], ""
    for cells in lines[2:]:
        row = dict(zip(head, (c.strip() for c in cells)))
        painting = row[head[0]] or painting
        rows.append({**row, head[0]: painting})
    return rows


def _column(rows: list[dict[str, str]], name: str) -> str | None:
    return next((h for h in (rows[0] if rows else {}) if name.lower() in h.lower()), None)


def summary(table: str) -> str:
    """The README's sentence of averages and comparisons, from the results table: FAST's mean content SSIM and warp
    RMSE over the paintings, the unstylized floor, FAST's SSIM below NNFM's and its Gram distance against NNFM's and
    the colour match's, painting by painting. Empty when the table lacks a column or a method this needs."""
    rows = _rows(table)
    cols = {k: _column(rows, k) for k in ("method", "content SSIM", "warp RMSE", "floor", "Gram")}
    if not rows or None in cols.values():
        return ""
    first = next(iter(rows[0]))

    def by(method: str) -> dict[str, dict[str, str]]:
        return {r[first]: r for r in rows if r[cols["method"]].lower().startswith(method)}

    def pair(cell: str) -> tuple[float, float]:
        a, b = (float(x) for x in cell.split("/"))
        return a, b

    fast, nnfm, colour = by("fast"), by("nnfm"), by("colour match")
    if not fast:
        return ""
    n = len(fast)
    ssim = sum(float(r[cols["content SSIM"]]) for r in fast.values()) / n
    rmse = [sum(pair(r[cols["warp RMSE"]])[i] for r in fast.values()) / n for i in (0, 1)]
    floor = pair(next(iter(fast.values()))[cols["floor"]])
    text = (f"Averaged over the {n} paintings, FAST: content SSIM {ssim:.3f}, short / long warp RMSE "
            f"{rmse[0]:.3f} / {rmse[1]:.3f}; the unstylized floor is {floor[0]:.3f} / {floor[1]:.3f}.")
    both = [p for p in fast if p in nnfm]
    if both:
        gap = [float(nnfm[p][cols["content SSIM"]]) - float(fast[p][cols["content SSIM"]]) for p in both]
        below = sum(float(fast[p][cols["Gram"]]) <= float(nnfm[p][cols["Gram"]]) for p in both)
        text += (f" Against NNFM, FAST's SSIM is {min(gap):.3f}–{max(gap):.3f} lower and its Gram distance at or "
                 f"below NNFM's on {below} of {len(both)} paintings.")
    done = [p for p in fast if p in colour]
    if done:
        past = sum(float(fast[p][cols["Gram"]]) < float(colour[p][cols["Gram"]]) for p in done)
        text += f" FAST's Gram distance is below the colour match alone's on {past} of {len(done)}."
    return text


def results_block(table: str) -> str:
    """What goes between the README's markers: the table, then :func:`summary`."""
    return table.strip() + (f"\n\n{summary(table)}" if summary(table) else "")


def _copy_arg(text: str) -> tuple[str, Path]:
    """``--copy SRC=DST``: SRC relative to the experiment's workspace, DST a path here."""
    src, sep, dst = text.partition("=")
    if not sep or not src or not dst:
        raise argparse.ArgumentTypeError(f"--copy takes SRC=DST (an output of the experiment = a path here), got {text!r}")
    return src, Path(dst)


def _publish(src: Path, dst: Path) -> None:
    """Copy an output picture to ``dst``; a ``.jpg`` destination of another format is re-encoded (quality 90)."""
    if not src.is_file():
        raise SystemExit(f"the experiment has no {src.name} at {src}; is it one of its outputs?")
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.suffix.lower() in (".jpg", ".jpeg") and src.suffix.lower() not in (".jpg", ".jpeg"):
        from abcgs.io.images import load_image, save_image

        save_image(dst, load_image(src))
    else:
        shutil.copy2(src, dst)


def cmd_show(a: argparse.Namespace) -> int:
    sha = find_exp_commit(a.name)
    with tempfile.TemporaryDirectory(prefix="abcgs-exp-") as tmp:
        wt = Path(tmp) / "wt"
        _git(["worktree", "add", "--detach", str(wt), sha], ROOT)
        try:
            dvc = [sys.executable, "-m", "dvc"]
            cache = subprocess.run(dvc + ["cache", "dir"], cwd=ROOT, check=True, capture_output=True,
                                   text=True).stdout.strip()  # the repository's own, wherever its config puts it
            subprocess.run(dvc + ["cache", "dir", "--local", cache], cwd=wt, check=True, capture_output=True)
            co = subprocess.run(dvc + ["checkout", "--quiet"], cwd=wt, capture_output=True, text=True)
            if co.returncode != 0:
                print(f"warning: dvc checkout restored only part of the outputs:\n{co.stderr.strip()[-2000:]}",
                      file=sys.stderr)
            results = wt / "reports" / "results.md"
            if not results.is_file():
                raise SystemExit(f"experiment {a.name} has no reports/results.md: did its report stage run?")
            table = results.read_text(encoding="utf-8")
            print(f"experiment {a.name} ({sha[:10]}):\n{table}")
            if a.readme:
                a.readme.write_text(replace_block(a.readme.read_text(encoding="utf-8"), results_block(table)),
                                    encoding="utf-8")
                print(f"wrote the table into {a.readme}")
            if a.figure and (wt / "reports" / "comparison.jpg").is_file():
                a.figure.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(wt / "reports" / "comparison.jpg", a.figure)
                print(f"copied the comparison figure to {a.figure}")
            for src, dst in a.copy:
                _publish(wt / src, dst)
                print(f"copied {src} to {dst}")
        finally:
            _git(["worktree", "remove", "--force", str(wt)], ROOT, check=False)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m eval run experiment", description=__doc__.strip().splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run a params overlay as a DVC experiment (resumable)")
    r.add_argument("overlay", type=Path)
    r.add_argument("--name", required=True, help="the experiment's name (dvc exp show lists it)")
    r.add_argument("--shared", type=Path, help="folder that ${shared} in the overlay stands for")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="one more override, e.g. stylize.optim.iterations=600")
    r.add_argument("--dry-run", action="store_true", help="print the overrides and stop")
    s = sub.add_parser("show", help="print an experiment's results table; optionally publish it")
    s.add_argument("name")
    s.add_argument("--readme", type=Path, help="write the table between the results markers of this file")
    s.add_argument("--figure", type=Path, help="copy the report's comparison figure here")
    s.add_argument("--copy", type=_copy_arg, action="append", default=[], metavar="SRC=DST",
                   help="copy one of the experiment's outputs (path in its workspace) here; repeatable")
    a = ap.parse_args(argv)
    return cmd_run(a) if a.cmd == "run" else cmd_show(a)


if __name__ == "__main__":
    sys.exit(main())
