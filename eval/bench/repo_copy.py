"""A clean git + DVC copy of this working tree, for runs that must not touch the workspace (tests, benchmarks).

:func:`copy_repo` copies the tracked and untracked-not-ignored files, without pipeline outputs (``out/``,
``data/``, ``reports/``), so the copy starts like a fresh clone with an empty DVC cache; :func:`run_in` runs a
command there with this interpreter's ``bin/`` first on ``PATH`` (so ``dvc`` and ``python`` are the venv's).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
OUTPUTS = ("out/", "data/", "reports/")
IDENTITY = (["git", "config", "user.name", "abcgs-ci"], ["git", "config", "user.email", "ci@abcgs.invalid"])
"""A copy's own git identity (its .git/config): the commits that DVC makes there (experiments, the queue) need one,
and a fresh machine has none in its HOME."""


def venv_env(env: dict | None = None) -> dict:
    """``env`` (the process's environment by default) with this interpreter's ``bin/`` first on ``PATH`` (so ``dvc``
    and ``python`` are the venv's) and Python's output unbuffered."""
    full = dict(os.environ if env is None else env)
    full["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{full.get('PATH', '')}"
    full["PYTHONUNBUFFERED"] = "1"
    return full


def run_in(args: list[str], cwd: Path, timeout: int | None = 900, env: dict | None = None) -> subprocess.CompletedProcess:
    """Run ``args`` in ``cwd`` with :func:`venv_env`; output captured as text."""
    return subprocess.run(args, cwd=cwd, env=venv_env(env), capture_output=True, text=True, timeout=timeout)


def copy_repo(dst: Path, edit_params: Callable[[dict], None] | None = None, root: Path = ROOT,
              regenerate_dvc_yaml: bool = True) -> Path:
    """Copy ``root``'s working tree to ``dst`` and commit it in a new git repository; ``edit_params`` may change
    the parsed ``params.yaml`` first (it is written back with ``yaml.safe_dump``), and then ``dvc.yaml`` is
    regenerated for the edited params unless ``regenerate_dvc_yaml`` is false (a copy whose params are meant to be
    refused by the stages keeps the workspace's ``dvc.yaml``: the generator validates the params)."""
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=root,
                           capture_output=True, check=True).stdout.decode().split("\0")
    for rel in filter(None, files):
        src = root / rel
        if rel.startswith(OUTPUTS) or not src.is_file():
            continue
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst / rel)
    return _commit_copy(dst, edit_params, regenerate_dvc_yaml=regenerate_dvc_yaml and edit_params is not None)


def copy_revision(dst: Path, rev: str, edit_params: Callable[[dict], None] | None = None, root: Path = ROOT) -> Path:
    """Like :func:`copy_repo`, for the files of the git revision ``rev`` of ``root`` (``git archive``): a clean
    copy of an earlier state of the project, e.g. the baseline of a before/after benchmark."""
    import io
    import tarfile

    proc = subprocess.run(["git", "archive", "--format=tar", rev], cwd=root, capture_output=True)
    if proc.returncode != 0:
        raise ValueError(f"git archive {rev!r} failed: {proc.stderr.decode(errors='replace').strip()}")
    dst.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(proc.stdout)) as tar:
        members = [m for m in tar.getmembers() if m.isfile() and not m.name.startswith(OUTPUTS)]
        try:
            tar.extractall(dst, members=members, filter="data")
        except TypeError:  # Python < 3.10.12 / 3.11.4: no extraction filters (the archive is this repository's)
            tar.extractall(dst, members=members)
    return _commit_copy(dst, edit_params)


def _commit_copy(dst: Path, edit_params: Callable[[dict], None] | None, regenerate_dvc_yaml: bool = False) -> Path:
    """Apply ``edit_params`` to ``dst/params.yaml`` and commit ``dst`` as a new git repository; with
    ``regenerate_dvc_yaml``, ``dvc.yaml`` is written for the edited params first (the report stage's deps follow the
    experiments: ``python -m abcgs.dag --update``)."""
    import yaml

    if edit_params is not None:
        params = yaml.safe_load((dst / "params.yaml").read_text())
        edit_params(params)
        (dst / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
        if regenerate_dvc_yaml:
            from abcgs.dag import pipeline_yaml

            (dst / "dvc.yaml").write_text(pipeline_yaml(dst), encoding="utf-8")
    for cmd in (["git", "init", "-q"], *IDENTITY, ["git", "add", "-A"], ["git", "commit", "-qm", "copy"]):
        subprocess.run(cmd, cwd=dst, check=True, capture_output=True)
    return dst
