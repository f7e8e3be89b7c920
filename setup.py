"""Builds abcgs's C++ kernels (``abcgs/render/csrc``) when the package is installed; the metadata is in pyproject.toml.

The build compiles against the torch of the build environment, so torch must be installed first and abcgs
installed with ``pip install --no-build-isolation`` (``make install`` does both). On x86-64 it builds two variants
(``abcgs/render/kernel_variants.py``): the best level this machine runs and a portable one. A variant that fails
to compile is left out; without torch or a compiler none is built. The install succeeds either way and
``abcgs/render/_kernels_build.json`` records what was built or why nothing was, which
``abcgs.render.cpu.load_extension`` reports (the rasterizer then falls back to its reference backend).
``ABCGS_KERNEL_VARIANTS=portable,x86_64_v3`` builds the listed variants instead. With ninja (the Makefile installs
it) the variants build side by side, each in its own folder, and ``MAX_JOBS`` caps the parallel compiles of one
variant (default: this machine's cores + 2, shared among the variants); without ninja, one file after the other.
"""

from __future__ import annotations

import copy
import importlib.util
import json
import os
import platform
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
RENDER = ROOT / "abcgs" / "render"
_spec = importlib.util.spec_from_file_location("_abcgs_kernel_variants", RENDER / "kernel_variants.py")
kv = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(kv)

SOURCES = [(RENDER / "csrc" / "kernels.cpp").relative_to(ROOT).as_posix()]  # includes the other *.cpp (one unit)


def write_record(build_lib: str, in_source: bool, record: dict) -> None:
    """The build record into the build (it goes into the wheel) and, for an editable or ``--inplace`` build, next
    to the sources, where the built modules are copied too; modules of variants it does not list are removed."""
    dirs = [Path(build_lib) / "abcgs" / "render"] + [RENDER] * in_source
    record = {"machine": platform.machine(), "python": sys.version.split()[0],
              "sources_sha256": kv.sources_sha256(RENDER / "csrc"), **record}
    for d in dirs:
        d.mkdir(parents=True, exist_ok=True)
        for old in d.glob(f"{kv.MODULE_PREFIX}*.so"):  # of an earlier build (setuptools keeps build/ between builds)
            if old.name.split(".")[0].removeprefix(kv.MODULE_PREFIX) not in record["variants"]:
                old.unlink()
        tmp = d / f".{kv.RECORD_NAME}.{os.getpid()}"
        tmp.write_text(json.dumps(record, indent=1) + "\n")
        os.replace(tmp, d / kv.RECORD_NAME)  # a process starting meanwhile reads the old record or the new one


def reason(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {str(exc).strip()[-1500:]}"


class RecordNoKernels(build_py):
    """Where torch is missing: no kernels, and the build record says why."""

    def run(self):
        super().run()
        write_record(self.build_lib, self.editable_mode, {"variants": [], "torch": None, "error": TORCH_ERROR})


try:
    import torch
    from torch.utils.cpp_extension import BuildExtension, CppExtension
except Exception as exc:  # plain `pip install .` builds in an isolated environment without torch
    torch = None
    TORCH_ERROR = f"torch was not importable when abcgs was built, e.g. under pip's build isolation ({reason(exc)})"

if torch is None:
    setup(cmdclass={"build_py": RecordNoKernels})
else:
    try:  # the ninja wheel ships the build tool; BuildExtension looks for it on PATH (else compiles file by file)
        import ninja

        os.environ["PATH"] = f"{ninja.BIN_DIR}{os.pathsep}{os.environ.get('PATH', '')}"
    except (ImportError, AttributeError):
        pass

    MACHINE = platform.machine()
    VARIANTS = [v for v in os.environ.get("ABCGS_KERNEL_VARIANTS", "").split(",") if v] or kv.variants_to_build(
        MACHINE, *kv.torch_cpu_features(torch)
    )

    class BuildKernels(BuildExtension):
        """torch's BuildExtension, each variant compiled in a temp folder of its own (same sources, other flags);
        a variant that fails is left out instead of failing the install, and the build record is written."""

        def run(self):
            self.failed: dict[str, str] = {}
            exts = self.distribution.ext_modules
            in_source = bool(self.inplace or self.editable_mode)  # setuptools unsets inplace while building
            try:
                super().run()
            except Exception as exc:  # before or after the per-variant builds (compiler checks, copying)
                self.failed.update({e.name: reason(exc) for e in exts if e.name not in self.failed})
            variant = {e.name: e.name.rsplit(kv.MODULE_PREFIX, 1)[1] for e in exts}
            built = [variant[e.name] for e in exts if e.name not in self.failed]
            failed = {variant[n]: r for n, r in self.failed.items()}
            for v, r in failed.items():
                print(f"warning: abcgs kernel variant {v} did not build: {r}", file=sys.stderr)
            write_record(self.build_lib, in_source, {
                "variants": built, "torch": torch.__version__,
                "flags": {v: kv.variant_flags(v, MACHINE) for v in variant.values()}, "failed": failed,
                "error": None if built else "; ".join(f"{v}: {r}" for v, r in failed.items()) or "nothing built",
            })

        def build_extensions(self):
            if self.use_ninja and len(self.extensions) > 1:
                # the variants side by side (setuptools' thread pool; ninja compiles each in its own folder), the
                # cores shared among them. Without ninja, torch swaps compiler flags on the shared compiler per file,
                # so the variants build one after the other.
                self.parallel = len(self.extensions)
                cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
                os.environ.setdefault("MAX_JOBS", str(max(1, -(-(cores + 2) // len(self.extensions)))))
            super().build_extensions()  # torch's flag setup, then build_extension() per variant
            # later steps (copying into the source tree, the wheel's file list) only see what was built
            self.extensions = [e for e in self.extensions if e.name not in self.failed]

        def build_extension(self, ext):
            # a shallow copy with this variant's temp folder: the variants may build in parallel threads, which
            # share the compiler and self.failed but not build_temp
            one = copy.copy(self)
            one.build_temp = os.path.join(self.build_temp, ext.name)
            try:
                super(BuildKernels, one).build_extension(ext)
            except Exception as exc:  # compiler missing or rejecting the flags, build error
                self.failed[ext.name] = f"{reason(exc)} (`pip install -v` shows the compiler's messages)"

    setup(
        ext_modules=[
            CppExtension(
                f"abcgs.render.{kv.MODULE_PREFIX}{v}", SOURCES, extra_compile_args={"cxx": kv.variant_flags(v, MACHINE)}
            )
            for v in VARIANTS
        ],
        cmdclass={"build_ext": BuildKernels},
    )
