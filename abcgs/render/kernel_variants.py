"""The C++ kernels' build variants and build record, shared by ``setup.py`` and :mod:`abcgs.render.cpu`.

``setup.py`` loads this file by its path while abcgs itself is not importable yet, hence the standard library
only. A variant is one build of all of ``csrc/*.cpp`` into the module ``abcgs.render._kernels_<variant>``; on
x86-64 the install builds the portable variant and the best one the build machine runs, and
:func:`runnable_variants` orders them for the CPU at hand. The build record (``_kernels_build.json`` next to the
modules) says what was built, against which torch and from which sources; :func:`build_problem` checks it.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

RECORD_NAME = "_kernels_build.json"
MODULE_PREFIX = "_kernels_"

# -fno-trapping-math: lets GCC if-convert float compares (the rasterizer's per-row alpha loop only vectorises with
# it); FP exception flags are never read here, and values are unchanged (no reassociation, no contraction).
# -g0 -fno-wrapv undo what setuptools passes first from Python's own CFLAGS: debug info (27 MB per module) and
# wrapping signed overflow (which the optimiser's loop analysis may not assume).
COMMON_FLAGS = ["-O3", "-ffp-contract=off", "-fno-trapping-math", "-std=c++17", "-g0", "-fno-wrapv"]
# x86-64 micro-architecture levels, best first. vec_width.h and the kernels pick their SIMD code from the macros
# these define (__AVX512F__, __AVX2__, __FMA__, __AVX512BF16__). -mtune only changes scheduling, never results.
X86_FLAGS = {
    "x86_64_v4_bf16": ["-march=x86-64-v4", "-mavx512bf16", "-mtune=native"],  # + knn_cpu.cpp's bf16 dot kernel
    "x86_64_v4": ["-march=x86-64-v4", "-mtune=native"],  # AVX-512 F/BW/CD/DQ/VL
    "x86_64_v3": ["-march=x86-64-v3", "-mtune=native"],  # AVX2, FMA
    "portable": ["-march=x86-64"],  # SSE2: any x86-64 CPU
}

REBUILD = (
    "run `make install` in the abcgs checkout (or `pip install --no-build-isolation -e .` there, with the torch "
    "you run installed) to rebuild them"
)


def is_x86_64(machine: str) -> bool:
    return machine.lower() in ("x86_64", "amd64")


def variant_flags(variant: str, machine: str) -> list[str]:
    """Compiler flags of ``variant``; elsewhere than on x86-64 the one (portable) build uses the compiler's default
    target."""
    return COMMON_FLAGS + (X86_FLAGS[variant] if is_x86_64(machine) else [])


def runnable_variants(machine: str, capability: str, bf16: bool = False) -> list[str]:
    """The variants a CPU runs, best first. ``capability`` is ``torch.backends.cpu.get_cpu_capability()``
    ("AVX512", "AVX2", "DEFAULT", ...; it follows ``ATEN_CPU_CAPABILITY``, which so also selects a lower
    variant), ``bf16`` whether the CPU has AVX512-BF16."""
    if not is_x86_64(machine):
        return ["portable"]
    cap = capability.upper()
    levels = []
    if cap.startswith("AVX512"):
        levels += ["x86_64_v4_bf16"] * bool(bf16) + ["x86_64_v4"]
    if cap.startswith(("AVX512", "AVX2")):
        levels.append("x86_64_v3")
    return levels + ["portable"]


def variants_to_build(machine: str, capability: str, bf16: bool = False) -> list[str]:
    """The build machine's best variant and the portable fallback (the portable build alone where that is the best)."""
    best = runnable_variants(machine, capability, bf16)[0]
    return [best, "portable"] if best != "portable" else ["portable"]


def torch_cpu_features(torch) -> tuple[str, bool]:
    """This CPU as torch sees it: (``get_cpu_capability()``, AVX512-BF16 support)."""
    probe = getattr(torch.cpu, "_is_avx512_bf16_supported", None)
    return torch.backends.cpu.get_cpu_capability(), bool(probe()) if probe is not None else False


def sources_sha256(csrc: Path) -> str | None:
    """SHA-256 over the names and contents of ``csrc``'s ``*.cpp`` and ``*.h``; None where there are none."""
    files = sorted(p for p in Path(csrc).glob("*") if p.suffix in (".cpp", ".h"))
    if not files:
        return None
    h = hashlib.sha256()
    for p in files:
        data = p.read_bytes()
        h.update(f"{p.name}\0{len(data)}\0".encode())
        h.update(data)
    return h.hexdigest()


def build_problem(record: dict | None, csrc: Path, torch_version: str) -> str | None:
    """Why the kernels of ``record`` cannot serve the sources in ``csrc`` under ``torch_version``; None if they can.

    A build is usable when it has variants, was made against this very torch (extensions use its C++ ABI) and from
    these sources (an editable install keeps its modules in the source tree, where csrc may change afterwards).
    Where ``csrc`` has no sources (an install without them), only the torch version is checked.
    """
    bare = torch_version.split("+")[0]
    if record is None:
        return (
            f"the C++ kernels are not built: no {RECORD_NAME} in abcgs/render (abcgs was not installed from this "
            f"tree); {REBUILD}."
        )
    if not record.get("variants"):
        return (
            f"abcgs was installed without its C++ kernels ({record.get('error') or 'no variant built'}). Install "
            f"torch first (`pip install torch=={bare}`), then abcgs with `pip install --no-build-isolation .` "
            "(`-e .` in a checkout), or run `make install` in the checkout."
        )
    if record.get("torch") != torch_version:
        return (
            f"the C++ kernels were built against torch {record.get('torch')} but torch {torch_version} is running "
            f"(an extension only loads into the torch it was built with); {REBUILD}."
        )
    current = sources_sha256(csrc)
    if current is not None and record.get("sources_sha256") != current:
        return f"the compiled kernels are older than abcgs/render/csrc (its sources changed after the build); {REBUILD}."
    return None
