"""The benchmark records that a DVC pipeline of their own owns: ``docs/dvc.yaml``, generated from :data:`RECORDS`.

    python -m eval records --write            # write docs/dvc.yaml (tests/test_records.py checks it is current)
    python -m eval records --status           # which owned record is stale, one line each (`cd docs && dvc status`)
    cd docs && PATH=$PWD/../.venv/bin:$PATH dvc repro structure    # re-make one (all: no stage name)

``docs/`` is a DVC project of its own (``dvc init --subdir``): the repository's ``dvc repro`` and ``dvc status`` skip
it, so the pipeline's users never run a benchmark by accident, and a record's stage lives beside the record. Each
stage runs one benchmark of the suite (``python -m eval run NAME``, from the repository root) and writes its record
(``measurements/NAME.json``, not DVC-cached: git keeps it; ``persist``: DVC does not delete it before the run, so a
run that fails leaves the last record, and the test suite, which reads every record, runs with its own in place).
Its deps are the files the benchmark runs, each by name: its import closure through ``abcgs`` and ``eval``
(:func:`abcgs.dag.import_closure`), plus what it reads or runs beyond its imports (:attr:`Record.reads`: the params
file, the whole tree for the structure numbers and the test suite). Files are listed one by one, not as folders: DVC hashes a folder outside its project with everything in it,
bytecode and built kernels included, which would make every record stale on the next import.

The other records in ``docs/measurements/`` need a fitted real scene or a GPU; the command that made each is in its
``provenance``.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from abcgs.dag import import_closure, source_files
from eval.suite import discover, find

ROOT = Path(__file__).resolve().parents[1]
PROJECT = "docs"
"""The records' DVC project, relative to the repository root."""
TREE = ("abcgs", "stages", "eval", "tests", "params.yaml", "pyproject.toml", "setup.py", "Makefile", "README.md", ".ci")
"""What the whole tree's measurements read: the code, the tests and the files they check. ``dvc.yaml`` is left out:
DVC refuses a file of that name as a dependency, and it is generated from the stages and ``params.yaml``
(``python -m abcgs.dag``), which are deps."""


@dataclass(frozen=True)
class Record:
    """One record of ``docs/measurements`` and the benchmark run that makes it."""

    name: str
    """The stage's name; the record is ``measurements/<name>.json``."""
    bench: str
    """The suite's benchmark that writes it (``python -m eval run <bench>``)."""
    args: tuple[str, ...] = ()
    """The benchmark's arguments before ``--json``."""
    reads: tuple[str, ...] = ()
    """Files or folders (relative to the repository root) it reads or runs beyond its imports."""

    @property
    def out(self) -> str:
        return f"measurements/{self.name}.json"


RECORDS = (
    Record("structure", "structure", ("--label", "now"), reads=("abcgs", "stages", "eval", "params.yaml",
                                                                 "pyproject.toml")),
    Record("fuzz", "fuzz", ("--inputs", "500", "--jobs", "1")),
    Record("fit_schedule_300", "fit_schedule", ("--iterations", "300", "--scenes", "tiny", "--variant", "{}",
                                                "--variant", '{"strategy": {"refine_every": 20}}', "--variant",
                                                '{"strategy": {"refine_every": 30}}'), reads=("params.yaml",)),
    Record("test_suite", "test_suite", reads=TREE),
)
"""The owned records, in ``docs/dvc.yaml``'s order."""


def command(record: Record) -> str:
    """The stage's command, run from ``docs/``: every word quoted for the shell (none comes from a params file)."""
    words = ["python", "-m", "eval", "run", record.bench, *record.args, "--json", f"{PROJECT}/{record.out}"]
    return "cd .. && " + " ".join(shlex.quote(w) for w in words)


def deps(record: Record, root: Path = ROOT) -> list[str]:
    """The files the record's benchmark runs or reads, relative to ``docs/`` (``../abcgs/…``), sorted."""
    module = find(record.bench, discover()).module
    files = import_closure(root.joinpath(*module.split(".")).with_suffix(".py"), root, packages=("abcgs", "eval"))
    for path in record.reads:
        files |= set(source_files(root / path, root))
    return sorted(f"../{f.as_posix()}" for f in files)


def _flow(entries: list[str], indent: int, width: int = 120) -> str:
    """``entries`` as a YAML flow list, a folder's files on their own lines (wrapped at ``width``)."""
    lines: list[str] = []
    folder = None
    for e in entries:
        item = f"'{e}'" if any(c in e for c in "{}[],:#'\"") else e
        parent = e.rsplit("/", 1)[0]
        if lines and parent == folder and len(lines[-1]) + len(item) + 2 <= width - indent - 2:
            lines[-1] += f" {item},"
        else:
            lines.append(f"{item},")
        folder = parent
    return "[" + ("\n" + " " * (indent + 1)).join(lines).rstrip(",") + "]"


HEADER = """\
# Generated by `python -m eval records --write` from eval/records.py; tests/test_records.py checks it is current.
# The benchmark records this DVC project (docs/, apart from the repository's pipeline) owns: `dvc status` here names
# the stale ones, `dvc repro NAME` re-makes one. A stage's deps are the files its benchmark runs or reads.
"""


def records_yaml(root: Path = ROOT) -> str:
    """The text of ``docs/dvc.yaml``."""
    parts = [HEADER, "stages:\n"]
    for r in RECORDS:
        parts.append(f"  {r.name}:\n    cmd: {_quote_yaml(command(r))}\n")
        parts.append(f"    deps: {_flow(deps(r, root), len('    deps: '))}\n")
        parts.append(f"    outs:\n    - {r.out}:\n        cache: false\n        persist: true\n")
    return "".join(parts)


def _quote_yaml(text: str) -> str:
    """``text`` as a YAML double-quoted scalar."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def stale(status: dict) -> dict[str, str]:
    """Per stale stage of ``dvc status --json``'s answer, what changed: ``"3 deps, 1 out"``, ``"never run"``."""
    out = {}
    for name, changes in status.items():
        counts = {}
        for change in changes:
            if not isinstance(change, dict):  # "changed command" and the like
                counts[str(change)] = 0
                continue
            for kind, files in change.items():
                counts[kind.removeprefix("changed ")] = len(files) if isinstance(files, dict) else 0
        words = [f"{n} {kind}" if n else kind for kind, n in counts.items()]
        out[name] = ", ".join(words) or "changed"
    return out


def print_status(root: Path = ROOT) -> int:
    """Print each owned record and whether it is current; 1 when one is stale."""
    proc = subprocess.run([sys.executable, "-m", "dvc", "status", "--json"], cwd=root / PROJECT,
                          capture_output=True, text=True)
    if proc.returncode != 0:
        print(proc.stderr, file=sys.stderr)
        return 2
    changed = stale(json.loads(proc.stdout or "{}"))
    for r in RECORDS:
        state = f"stale ({changed[r.name]})" if r.name in changed else "current"
        print(f"{r.name:<18} {PROJECT}/{r.out:<36} {state}")
    return 1 if changed else 0


def main(argv: list[str] | None = None) -> int:
    """``python -m eval records [--write | --check | --status]``: print, write or check ``docs/dvc.yaml``, or say
    which owned record is stale."""
    ap = argparse.ArgumentParser(prog="python -m eval records", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help="write docs/dvc.yaml")
    mode.add_argument("--check", action="store_true", help="exit 1 when docs/dvc.yaml is not what --write writes")
    mode.add_argument("--status", action="store_true", help="each owned record, current or stale (exit 1: stale)")
    ap.add_argument("--root", type=Path, default=ROOT, help="the repository whose docs/ project --status reads")
    args = ap.parse_args(argv)
    if args.status:
        return print_status(args.root)
    text, path = records_yaml(), ROOT / PROJECT / "dvc.yaml"
    if args.check:
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            print(f"{path} is not current: run `python -m eval records --write`", file=sys.stderr)
            return 1
        return 0
    if args.write:
        from abcgs.io.atomic import write_text

        write_text(path, text)
        return 0
    print(text, end="")
    return 0
