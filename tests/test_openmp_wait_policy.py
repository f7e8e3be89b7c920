"""abcgs.runtime.setup() asks GNU OpenMP for passive waiting before torch loads; importing abcgs changes nothing;
every stage and benchmark script calls setup() before it imports torch."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROBE = "import os, sys; {first}; import torch; print(os.environ.get('OMP_WAIT_POLICY', '<unset>'))"


def _policy_seen_by_torch(first: str, env_value: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if env_value is not None:
        env["OMP_WAIT_POLICY"] = env_value
    out = subprocess.run([sys.executable, "-c", PROBE.format(first=first)], cwd=ROOT, env=env,
                         capture_output=True, text=True, check=True)
    return out.stdout.strip().splitlines()[-1]


def test_setup_before_torch_makes_openmp_wait_passively():
    assert _policy_seen_by_torch("from abcgs.runtime import setup; setup()", None) == "PASSIVE"


def test_importing_abcgs_changes_nothing():
    assert _policy_seen_by_torch("import abcgs, abcgs.runtime", None) == "<unset>"


def test_a_policy_the_user_set_is_kept():
    assert _policy_seen_by_torch("from abcgs.runtime import setup; setup()", "ACTIVE") == "ACTIVE"


def test_after_torch_is_loaded_setup_leaves_the_environment_alone():
    # libgomp has read its settings by then: setting the variable would only mislead child processes' readers
    assert _policy_seen_by_torch("import torch; from abcgs.runtime import setup; setup()", None) == "<unset>"


def _heavy_names(node: ast.stmt) -> list[str]:
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
        return [node.module]
    return []


def _setup_call(node: ast.stmt) -> bool:
    return (isinstance(node, ast.Expr) and isinstance(node.value, ast.Call)
            and getattr(node.value.func, "id", None) == "setup")


def setup_comes_first(source: str) -> str | None:
    """None when the script calls ``abcgs.runtime.setup()`` before any other import of abcgs, torch or the eval
    package (or imports none of them); else what it imports first."""
    for node in ast.parse(source).body:
        if _setup_call(node):
            return None
        for name in _heavy_names(node):
            if name == "abcgs.runtime":
                continue
            if name.split(".")[0] in ("abcgs", "torch", "eval"):
                return name
    return None


SCRIPTS = sorted(ROOT.glob("stages/*.py")) + sorted(ROOT.glob("eval/bench/*.py")) + sorted(ROOT.glob("eval/studies/*.py"))


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_stages_and_benchmarks_call_setup_before_importing_torch(script: Path):
    first = setup_comes_first(script.read_text())
    assert first is None, f"{script.relative_to(ROOT)} imports {first} before it calls abcgs.runtime.setup()"


def test_the_check_sees_an_import_before_setup():
    assert setup_comes_first("import torch\nfrom abcgs.runtime import setup\nsetup()\n") == "torch"
    assert setup_comes_first("import os\nfrom abcgs.runtime import setup\nsetup()\nimport torch\n") is None
    assert setup_comes_first("from abcgs import layout\n") == "abcgs"


MALLOC_PROBE = """
import ctypes, sys
{first}
class MallInfo2(ctypes.Structure):
    _fields_ = [(f, ctypes.c_size_t) for f in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
                                               "uordblks", "fordblks", "keepcost")]
libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = MallInfo2
libc.malloc.restype = ctypes.c_void_p
libc.free.argtypes = [ctypes.c_void_p]
before = libc.mallinfo2().hblkhd
p = libc.malloc(48 << 20)  # a (3 M, 4) float32 tensor's bytes
mapped = libc.mallinfo2().hblkhd - before
libc.free(p)
print(mapped, libc.mallinfo2().arena >= (48 << 20))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc settings")
@pytest.mark.parametrize("first, env, mapped", [
    ("from abcgs.runtime import setup; setup()", {}, False),
    ("import abcgs.runtime", {}, True),  # without setup: glibc's defaults
    ("from abcgs.runtime import setup; setup()", {"MALLOC_MMAP_THRESHOLD_": "1048576"}, True),  # the user's choice
])
def test_setup_has_glibc_keep_large_blocks_in_its_heap(first, env, mapped):
    """After setup() a 48 MB block comes from the heap, and stays there when freed (no fresh mmap whose pages fault
    in on every step); without setup, or with the user's own MALLOC_* setting, glibc's defaults map it."""
    out = subprocess.run([sys.executable, "-c", MALLOC_PROBE.format(first=first)], cwd=ROOT,
                         env={**os.environ, **env}, capture_output=True, text=True, check=True)
    got_mapped, kept = out.stdout.split()
    assert (int(got_mapped) > 0) == mapped
    assert (kept == "True") == (not mapped)


def test_release_free_memory_gives_the_kept_heap_back():
    """The blocks setup() keeps in the heap go back to the system at release_free_memory()."""
    probe = MALLOC_PROBE.format(first="from abcgs.runtime import setup, release_free_memory; setup()") + (
        "before = libc.mallinfo2().arena\nrelease_free_memory()\nprint(before - libc.mallinfo2().arena >= (32 << 20))\n")
    out = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.split()[-1] == "True"
