"""The benchmark suite: every benchmark (``eval/bench/``) and study (``eval/studies/``), listed and run by name.

    python -m eval list                         # name, room and the first line of each one's docstring
    python -m eval run fit_schedule --help      # one of them, with its own arguments
    python -m eval run bench.fit_schedule --iterations 1000 --scenes tiny

A benchmark is a module of ``eval/bench`` or ``eval/studies`` that runs as a script (``if __name__ ==
"__main__":``); the other modules there are helpers the benchmarks share (``timing``, ``regression``, ``browser``
...). Listing reads the modules' source (:mod:`ast`), so it imports neither torch nor the benchmarks; ``run`` runs
the module as ``python -m`` would, with the arguments after the name. A benchmark's ``--json`` record is written by
:mod:`eval.record`, with the run's provenance (the ``python -m eval run NAME ...`` command that reproduces it, the
machine, its load, the date).
"""

from __future__ import annotations

import argparse
import ast
import runpy
import sys
from dataclasses import dataclass
from pathlib import Path

from abcgs.dag import is_main_block

ROOT = Path(__file__).resolve().parent
ROOMS = ("bench", "studies")
"""The suite's folders under ``eval/``: measurements of the product, and one-off studies behind a doc's figure."""


@dataclass(frozen=True)
class Benchmark:
    """One runnable module of the suite."""

    room: str
    """``bench`` or ``studies``."""
    name: str
    """The module's name in its room (``fit_schedule``)."""
    summary: str
    """The first line of its docstring."""

    @property
    def module(self) -> str:
        return f"eval.{self.room}.{self.name}"


def discover() -> list[Benchmark]:
    """Every benchmark of the suite, by room and name, read from source without importing it."""
    found = []
    for room in ROOMS:
        for path in sorted((ROOT / room).glob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
            if path.stem.startswith("_") or not any(is_main_block(node) for node in tree.body):
                continue
            doc = (ast.get_docstring(tree) or "").strip()
            found.append(Benchmark(room, path.stem, doc.splitlines()[0] if doc else ""))
    return found


def find(name: str, benchmarks: list[Benchmark]) -> Benchmark:
    """The benchmark called ``name`` (``fit_schedule`` or ``bench.fit_schedule``); a clear error otherwise."""
    room, _, short = name.rpartition(".")
    hits = [b for b in benchmarks if b.name == short and room in ("", b.room)]
    if len(hits) == 1:
        return hits[0]
    if hits:
        raise SystemExit(f"eval: {name!r} names {len(hits)} benchmarks ({', '.join(h.module for h in hits)}); "
                         "give its room too, e.g. bench.NAME")
    raise SystemExit(f"eval: no benchmark {name!r}; `python -m eval list` shows them")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m eval", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="every benchmark and study, with what it measures")
    run = sub.add_parser("run", help="run one benchmark by name; the arguments after the name are its own")
    run.add_argument("name")
    run.add_argument("args", nargs=argparse.REMAINDER)
    args = ap.parse_args(argv)
    benchmarks = discover()
    if args.command == "list":
        width = max(len(b.name) for b in benchmarks)
        for b in benchmarks:
            print(f"{b.room:<8} {b.name:<{width}}  {b.summary}")
        return 0
    chosen = find(args.name, benchmarks)
    sys.argv = [chosen.module, *args.args]
    runpy.run_module(chosen.module, run_name="__main__", alter_sys=True)
    return 0
