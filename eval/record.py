"""A benchmark's record: the command line every benchmark and study of the suite shares, and the JSON file it writes.

    ap = bench_parser(__doc__)           # the module's docstring as --help, and --json PATH
    ap.add_argument("--steps", type=int, default=20)
    args = ap.parse_args(argv)
    ...
    if args.json:
        write_record(args.json, {"steps": args.steps, "ms_per_step": ms}, argv)

:func:`write_record` adds the run's :func:`provenance` (the command that reproduces it, the machine, its load, the
Python and torch versions, the date) under ``"provenance"`` and writes the file atomically. Only the standard library
and :mod:`abcgs.runtime` / :mod:`abcgs.io.atomic` are imported here, so a benchmark may import this module right after
``abcgs.runtime.setup()`` without loading torch.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shlex
import sys
from datetime import datetime, timezone
from pathlib import Path

from abcgs.io.atomic import write_json
from abcgs.runtime import available_cores

CPUINFO = Path("/proc/cpuinfo")
KERNELS_PREFIX = "abcgs.render._kernels_"
"""The module name of a loaded variant of the C++ kernels, less its variant (:mod:`abcgs.render.kernel_variants`)."""
ISA_LIMITS = ("ATEN_CPU_CAPABILITY", "ONEDNN_MAX_CPU_ISA", "MKL_ENABLE_INSTRUCTIONS")
"""Environment variables that make torch's CPU kernels use less of the instruction set than the CPU has: ATen's own
kernels, oneDNN's (convolutions) and MKL's (matrix products)."""


def bench_parser(doc: str | None, json_help: str = "write the record here") -> argparse.ArgumentParser:
    """The parser a benchmark starts from: ``doc`` (its module docstring) as the description, kept as written, and
    ``--json PATH`` (default None: write no record; ``json_help`` is its help text)."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", type=Path, default=None, metavar="PATH", help=json_help)
    return ap


def _command(argv: list[str] | None) -> str:
    """``python -m <module> <args>`` for the running program (its script path when it was not run as a module);
    ``argv`` defaults to ``sys.argv[1:]``."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    program = f"-m {spec.name}" if spec is not None and spec.name else shlex.quote(sys.argv[0] if sys.argv else "?")
    args = list(sys.argv[1:] if argv is None else argv)
    return f"python {program}" + (" " + shlex.join(str(a) for a in args) if args else "")


def _cpu_model() -> str:
    """The CPU's ``model name`` from ``/proc/cpuinfo`` where that is readable, else :func:`platform.processor`."""
    try:
        found = re.search(r"^model name\s*:\s*(.+)$", CPUINFO.read_text(encoding="utf-8", errors="replace"), re.M)
    except OSError:
        found = None
    return found.group(1).strip() if found else platform.processor()


def provenance(argv: list[str] | None = None) -> dict:
    """Where and how a record was made: ``command`` (reproduces the run; ``argv`` are its arguments, default
    ``sys.argv[1:]``), ``machine`` (architecture), ``cpu`` (model), ``cores`` (this process may run on),
    ``loadavg`` (1, 5 and 15 min, rounded to 0.01; None where the OS has none), ``python``, ``torch``,
    ``torch_threads`` and ``cpu_capability`` (the SIMD level ATen's kernels run at, e.g. ``AVX512`` or ``AVX2``:
    ``ATEN_CPU_CAPABILITY`` lowers it; only when torch is already imported: this function does not load it),
    ``kernels`` (the variant of abcgs's C++ kernels the run loaded, e.g. ``x86_64_v3``; only when it loaded them),
    ``isa_limits`` (the environment variables that cap the instruction set of ATen, oneDNN or MKL, e.g.
    ``ONEDNN_MAX_CPU_ISA``; only those set) and ``date`` (UTC, ISO 8601 to the second)."""
    try:
        load: list[float] | None = [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):  # Windows
        load = None
    out = {"command": _command(argv), "machine": platform.machine(), "cpu": _cpu_model(), "cores": available_cores(),
           "loadavg": load, "python": platform.python_version()}
    torch = sys.modules.get("torch")
    if torch is not None:
        out.update(torch=torch.__version__, torch_threads=torch.get_num_threads(),
                   cpu_capability=torch.backends.cpu.get_cpu_capability())
    loaded = sorted(m for m in sys.modules if m.startswith(KERNELS_PREFIX))
    if loaded:
        out["kernels"] = loaded[0][len(KERNELS_PREFIX):]
    limits = {k: os.environ[k] for k in ISA_LIMITS if k in os.environ}
    if limits:
        out["isa_limits"] = limits
    out["date"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
    return out


def write_record(path: Path, record: dict, argv: list[str] | None = None) -> None:
    """Write ``record`` to ``path`` as JSON, atomically (its folder is made), with ``"provenance":
    provenance(argv)`` added unless the record already has that key (the record's own keys are never replaced)."""
    out = dict(record)
    if "provenance" not in out:
        out["provenance"] = provenance(argv)
    write_json(path, out)
