"""What DVC itself costs around each stage: reading and rewriting ``dvc.lock``, ``dvc status``, one cheap stage.

    python -m eval run dvc_overhead --json docs/measurements/dvc_overhead.json
    python -m eval run dvc_overhead --work /tmp/dvc-overhead      # keep (and reuse) the copy it runs in

The working tree is copied into a fresh git + DVC repository (``eval/bench/repo_copy.py``) with the regression runs'
REDUCED schedule, keeping the committed ``dvc.lock`` (every stage's entry, as on a clone), and ``dvc repro
export_scene@tiny`` runs the stages that one needs. Then, each timed ``--repeats`` times after one untimed run (median):

- ``lock``: ruamel.yaml, which DVC uses, reading that ``dvc.lock`` the way DVC's checks do (``typ="safe"``: with the C
  loader of ``ruamel.yaml.clib`` where it is installed, and in pure Python) and the way DVC rewrites it after every
  stage it runs (round-trip load, which keeps comments and is pure Python, then dump);
- ``dvc status`` in the finished repository;
- ``export_scene@tiny`` (a tenth of a second of work) forced through ``dvc repro --force --single-item``, against
  its command from ``dvc.lock`` run alone (split with :func:`shlex.split`, no shell; ``DVC_STAGE`` set as DVC sets
  it, which names the stage's key): the difference is what DVC adds to every stage it runs.
"""

from __future__ import annotations

import io
import os
import shlex
import statistics
import subprocess
import tempfile
from collections.abc import Callable
from pathlib import Path

from abcgs.runtime import setup

setup()  # before anything that may load torch: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
from abcgs.pipeline import DVC_STAGE_ENV
from eval.bench.regression import reduce
from eval.bench.repo_copy import copy_repo, run_in
from eval.bench.timing import repeat_seconds
from eval.record import bench_parser, write_record

STAGE = "export_scene@tiny"
"""The stage timed through DVC and alone: it converts the fitted PLY (about 0.1 s of work)."""


def _median_s(fn: Callable[[], object], repeats: int) -> float:
    """Median seconds of ``repeats`` calls of ``fn`` after one untimed warm-up call (:func:`repeat_seconds`)."""
    return round(statistics.median(repeat_seconds(fn, repeats)), 3)


def lock_parse_seconds(text: str, repeats: int) -> dict:
    """Median seconds of ruamel.yaml reading ``text`` (a ``dvc.lock``) as DVC does: ``safe_c`` (None where
    ``ruamel.yaml.clib`` is missing), ``safe_pure``, ``round_trip_load`` and ``round_trip_dump``."""
    from ruamel.yaml import YAML
    from ruamel.yaml.main import CParser

    tree = YAML(typ="rt").load(text)
    return {
        "safe_c": _median_s(lambda: YAML(typ="safe").load(text), repeats) if CParser is not None else None,
        "safe_pure": _median_s(lambda: YAML(typ="safe", pure=True).load(text), repeats),
        "round_trip_load": _median_s(lambda: YAML(typ="rt").load(text), repeats),
        "round_trip_dump": _median_s(lambda: YAML().dump(tree, io.StringIO()), repeats),
    }


def _checked(proc: subprocess.CompletedProcess, what: str) -> None:
    if proc.returncode != 0:
        raise SystemExit(f"dvc_overhead: {what} failed (exit {proc.returncode}):\n{proc.stdout[-2000:]}\n"
                         f"{proc.stderr[-2000:]}")


def _status(repo: Path) -> None:
    proc = run_in(["dvc", "status", "-q"], repo)  # exit 1: some stage changed (the stages this copy did not run)
    if proc.returncode not in (0, 1):
        _checked(proc, "dvc status")


def prepare(work: Path) -> Path:
    """A reduced copy of the working tree under ``work`` in which :data:`STAGE` has run (reused when present)."""
    repo = work / "repo"
    if not (repo / "out" / "tiny" / "gs" / "point_cloud.ply").is_file():
        copy_repo(repo, reduce)
        print(f"dvc_overhead: dvc repro {STAGE} in {repo} (the reduced fit: about a minute)", flush=True)
        _checked(run_in(["dvc", "repro", STAGE], repo, timeout=1800), f"dvc repro {STAGE}")
    return repo


def measure(repo: Path, repeats: int) -> dict:
    """The record's numbers for the finished repository ``repo``."""
    import yaml

    lock_path = repo / "dvc.lock"
    text = lock_path.read_text(encoding="utf-8")
    stages = yaml.safe_load(text)["stages"]
    cmd = shlex.split(stages[STAGE]["cmd"])  # `python ...`: run_in puts this interpreter first on PATH, as DVC has it

    def through_dvc() -> None:
        _checked(run_in(["dvc", "repro", "--force", "--single-item", STAGE], repo), "dvc repro --force")

    def alone() -> None:
        _checked(run_in(cmd, repo, env={**os.environ, DVC_STAGE_ENV: STAGE}), f"{STAGE}'s command")

    stage = {"through_dvc": _median_s(through_dvc, repeats), "alone": _median_s(alone, repeats)}
    stage["dvc_adds"] = round(stage["through_dvc"] - stage["alone"], 3)
    return {
        "lock": {"bytes": len(text.encode()), "lines": text.count("\n"), "stages": len(stages),
                 "deps": sum(len(s.get("deps", [])) for s in stages.values())},
        "lock_seconds": lock_parse_seconds(text, repeats),
        "dvc_status_seconds": _median_s(lambda: _status(repo), repeats),
        "stage": STAGE, "stage_seconds": stage, "repeats": repeats,
    }


def main(argv: list[str] | None = None) -> int:
    ap = bench_parser(__doc__)
    ap.add_argument("--work", type=Path, default=None, help="folder for the repository copy (default: a temporary one)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="abcgs-dvc-overhead-") as tmp:
        result = measure(prepare(args.work or Path(tmp)), args.repeats)
    lock, sec, stage = result["lock"], result["lock_seconds"], result["stage_seconds"]
    print(f"dvc.lock: {lock['bytes'] / 1024:.0f} KiB, {lock['lines']} lines, {lock['stages']} stages, "
          f"{lock['deps']} deps")
    safe_c = "not installed" if sec["safe_c"] is None else f"{sec['safe_c']:.2f} s"
    print(f"  read (safe):  C loader {safe_c}, pure Python {sec['safe_pure']:.2f} s")
    print(f"  rewrite:      round-trip load {sec['round_trip_load']:.2f} s + dump {sec['round_trip_dump']:.2f} s")
    print(f"dvc status:     {result['dvc_status_seconds']:.2f} s")
    print(f"{STAGE}: {stage['through_dvc']:.2f} s through dvc repro, {stage['alone']:.2f} s alone, "
          f"DVC adds {stage['dvc_adds']:.2f} s")
    if args.json:
        write_record(args.json, result, argv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
