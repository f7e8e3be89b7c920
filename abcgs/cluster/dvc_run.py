"""``dvc`` for the cluster: ``python abcgs/cluster/dvc_run.py [--keep-run-cache] repro TARGET ...``.

**dvc.lock once.** ``dvc repro`` rewrites ``dvc.lock`` after every stage, parsing and dumping the whole file each
time. Restoring a pipeline from the run cache is mostly that: 20 stages of the tiny pipeline spent 80 % of their
time in it, and the cost grows with the square of the number of stages. This wrapper writes the lock once, when the
reproduction ends (also when a stage failed: the stages that finished are recorded).

**Every stage in the run cache** (``--keep-run-cache``, the jobs). DVC leaves a stage out of its run cache when
the stage has an uncached output that is neither a metric nor a plot (``cache: false`` under ``outs``). This
pipeline's ``dvc.yaml`` has none (its records are cached outputs), but a cluster job must leave every stage it
finished restorable by the other jobs, by a retry of itself and by ``collect`` whatever a pipeline declares, so
this wrapper saves such stages too. DVC's run cache stores uncached outputs the way it stores
uncached metrics: it copies them into the cache, and restoring a stage checks them out again.

``python abcgs/cluster/dvc_run.py push-run-cache`` sends the run cache to the default DVC remote with the objects
of every entry (``dvc push --run-cache`` sends the entries, and the objects of cached outputs only through the
workspace, so a restore elsewhere would miss the uncached outputs).

The cluster job runs this file by path, not with ``-m``, so that it imports only DVC and not the ``abcgs``
package of the clone it runs in.

**Tested DVC versions.** The two changes replace private DVC functions (``Stage.save``, ``Stage.dump``,
``StageCache.restore``, ``dvc.repo.reproduce._reproduce``, ``dvcfile.dump_stages``, which DVC has since 3.63), so
they hold only for the DVC versions they were tested with, :data:`DVC_TESTED` (the ``cluster`` extra of
``pyproject.toml`` pins ``dvc`` to it). On another version this script exits with :func:`dvc_version_problem`'s
message before running anything, and
``python -m abcgs.cluster`` refuses to start (:func:`abcgs.cluster.run.check_dvc_version`).
"""

from __future__ import annotations

import re
import sys

DVC_TESTED = ((3, 67), (3, 68))
"""``[first, end)`` of the DVC ``major.minor`` versions this file was tested with; ``pyproject.toml``'s ``cluster``
extra says ``dvc>=3.67,<3.68``."""


def installed_dvc_version() -> str:
    """The version of the DVC installed with this interpreter (its package metadata; DVC is not imported)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("dvc")
    except PackageNotFoundError:
        return "not installed"


def dvc_version_problem(version: str | None = None) -> str | None:
    """Why DVC ``version`` (default: the installed one) cannot run the cluster code; None within :data:`DVC_TESTED`."""
    version = installed_dvc_version() if version is None else version
    (a, b), (c, d) = DVC_TESTED
    tested = f"{a}.{b}" if (c, d) == (a, b + 1) else f"{a}.{b}–{c}.{d - 1}"
    match = re.match(r"(\d+)\.(\d+)", version)
    if match and (a, b) <= (int(match[1]), int(match[2])) < (c, d):
        return None
    return (f"abcgs.cluster was tested with DVC {tested}; this is {version}: it replaces private DVC functions "
            f"(abcgs/cluster/dvc_run.py), which other versions may not have; install the tested one with "
            f"`pip install 'dvc>={a}.{b},<{c}.{d}'`")


def keep_every_stage_in_the_run_cache() -> None:
    """Make ``Stage.save`` write the run-cache entry of every stage that ran (a restored stage has one already)."""
    from dvc.stage import Stage
    from dvc.stage.cache import StageCache

    original_save, original_restore = Stage.save, StageCache.restore
    if getattr(original_save, "_abcgs_run_cache", False):
        return

    def restore(self, stage, *args, **kwargs):
        result = original_restore(self, stage, *args, **kwargs)
        if not kwargs.get("dry"):
            stage._abcgs_restored = True
        return result

    def save(self, allow_missing: bool = False, run_cache: bool = True):
        keep = run_cache or not getattr(self, "_abcgs_restored", False)
        return original_save(self, allow_missing=allow_missing, run_cache=keep)

    save._abcgs_run_cache = True  # type: ignore[attr-defined]
    Stage.save = save
    StageCache.restore = restore


def push_run_cache() -> int:
    """Push every run-cache entry of the repository in the current folder, and the objects it names, to the default
    remote; 1 when an object failed to upload."""
    from dvc.repo import Repo

    with Repo(".") as repo:
        entries = repo.stage_cache.push(None)
        objs: set = set()
        for hashes in repo.stage_cache.get_used_objs(entries).values():
            objs |= set(hashes)
        result = repo.cloud.push(objs)
        print(f"run cache: {len(entries)} entries, {len(result.transferred)} new objects pushed"
              + (f", {len(result.failed)} FAILED" if result.failed else ""), flush=True)
        return 1 if result.failed else 0


def write_the_lock_once() -> None:
    """Collect the per-stage ``dvc.lock`` updates of ``dvc repro`` and write them in one go when it ends."""
    import dvc.repo.reproduce as reproduce
    from dvc.stage import Stage

    if getattr(reproduce._reproduce, "_abcgs_lock_once", False):
        return
    pending: list = []
    original_dump, original_reproduce = Stage.dump, reproduce._reproduce

    def dump(self, **kwargs):
        if kwargs != {"update_pipeline": False}:  # only the lock update after a stage is deferred
            return original_dump(self, **kwargs)
        pending.append(self)

    def _reproduce(*args, **kwargs):
        try:
            return original_reproduce(*args, **kwargs)
        finally:
            files: dict[str, tuple] = {}
            for stage in pending:
                files.setdefault(stage.dvcfile.path, (stage.dvcfile, []))[1].append(stage)
            pending.clear()
            for dvcfile, stages in files.values():
                dvcfile.dump_stages(stages, update_pipeline=False)

    _reproduce._abcgs_lock_once = True  # type: ignore[attr-defined]
    Stage.dump = dump
    reproduce._reproduce = _reproduce


def main(argv: list[str]) -> int:
    problem = dvc_version_problem()
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    if argv[:1] == ["push-run-cache"]:
        return push_run_cache()
    write_the_lock_once()
    if argv[:1] == ["--keep-run-cache"]:
        argv = argv[1:]
        keep_every_stage_in_the_run_cache()
    from dvc.cli import main as dvc_main

    return dvc_main(argv)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
