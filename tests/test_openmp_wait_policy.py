"""abcgs asks GNU OpenMP for passive waiting before torch loads, and every stage imports it before torch."""

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


def test_importing_abcgs_first_makes_openmp_wait_passively():
    assert _policy_seen_by_torch("import abcgs", None) == "PASSIVE"


def test_a_policy_the_user_set_is_kept():
    assert _policy_seen_by_torch("import abcgs", "ACTIVE") == "ACTIVE"


def test_after_torch_is_loaded_abcgs_leaves_the_environment_alone():
    # libgomp has read its settings by then: setting the variable would only mislead child processes' readers
    assert _policy_seen_by_torch("import torch; import abcgs", None) == "<unset>"


def _first_heavy_import(path: Path) -> str | None:
    """The first top-level import of abcgs, torch or the eval package in a script (None: none of them)."""
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Import):
            names = [a.name.split(".")[0] for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module.split(".")[0]]
        else:
            continue
        for name in names:
            if name in ("abcgs", "torch", "eval"):
                return name
    return None


SCRIPTS = sorted(ROOT.glob("stages/*.py")) + sorted(ROOT.glob("eval/bench/*.py")) + sorted(ROOT.glob("eval/studies/*.py"))


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_stages_and_benchmarks_import_abcgs_before_torch(script: Path):
    first = _first_heavy_import(script)
    assert first in (None, "abcgs"), f"{script.relative_to(ROOT)} imports {first} before abcgs"
