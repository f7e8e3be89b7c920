"""The pipeline's DAG split into Slurm jobs: a pure function of ``dvc.yaml``'s stages and the params.

:func:`make_plan` expands every ``foreach`` stage of ``dvc.yaml`` over its collection in the params (as DVC does)
and assigns each stage to one job:

- **prep** (one job): the stages that need no stage of a scene or an experiment (``preflight``, ``make_tiny``, and
  ``styles`` / ``style_masks``: one per painting);
- **scene@S** (one per scene): the stages of ``data.scenes`` (``reconstruct``, ``fit``, ``masks``, ``reference``,
  ``export_scene``) and the colour matches of that scene (``colormatch@M`` with ``colormatches.M.scene == S``);
- **experiment@E** (one per experiment): the stages of ``experiments`` (``stylize``, ``evaluate``, ``export``);
  it waits for the job of its scene (``experiments.E.scene``);
- **report** (one job): the stages that read the outputs of the others (``report``, which depends on ``out``).

The jobs form Slurm job arrays (:class:`Array`): ``prep``, ``scenes`` (task i = the i-th scene, after
``afterok:<prep>_0``), ``experiments@S`` (one array per scene, its tasks wait for task i of ``scenes``:
``afterok:<scenes>_<i>``, so a scene's experiments start as soon as that scene is done, not when every scene is) and
``report`` (``afterany`` on every array: it runs once all have ended, and checks itself that they all succeeded;
Slurm counts a task's failure in an array's ``afterok`` even after the task was requeued and succeeded).
:func:`make_plan` checks every edge of the stage graph (an output of one stage overlapping a dependency of another)
against the job order, so a ``dvc.yaml`` change that the split no longer fits fails here, not on the cluster.

The module also holds the two inputs a plan is made from besides ``dvc.yaml``: the params (the workspace's, or a
benchmark overlay from ``eval/params`` merged over them: :func:`abcgs.overlay.apply_overlay`) and the per-kind Slurm resources
(:class:`Resources`, ``resources.yaml``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from abcgs.dotted import DVC_VARIABLE, interpolate, lookup, set_dotted
from abcgs.errors import AbcgsError

KINDS = ("prep", "scene", "experiment", "report")
"""Job kinds, in the order they run; each has its own resources (:class:`Resources`)."""
COLLECTIONS: dict[str, str] = {"data.scenes": "scene", "data.styles": "prep", "data.style_masks": "prep",
                               "colormatches": "scene", "experiments": "experiment"}
"""``foreach`` collection → the kind of job its stages go to."""
RESOURCES_FILE = Path(__file__).with_name("resources.yaml")


class PlanError(AbcgsError):
    """The pipeline cannot be split into jobs as described (the message says which stage or key)."""


@dataclass(frozen=True)
class Stage:
    """One expanded stage of ``dvc.yaml``: its address (``fit@tiny``) and resolved dependency / output paths."""

    name: str
    base: str
    collection: str | None
    key: str | None
    deps: tuple[str, ...]
    outs: tuple[str, ...]


@dataclass(frozen=True)
class Job:
    """A unit of work for one Slurm array task: ``dvc repro`` of ``targets`` (empty: the whole pipeline)."""

    name: str
    kind: str
    key: str | None
    stages: tuple[str, ...]
    targets: tuple[str, ...]
    after: tuple[str, ...]


@dataclass(frozen=True)
class Array:
    """A Slurm job array: task i runs ``jobs[i]``. It starts after ``after``, (array, task or None for all tasks),
    with the Slurm dependency type ``wait``: ``afterok`` (they succeeded) or ``afterany`` (they ended)."""

    name: str
    kind: str
    jobs: tuple[str, ...]
    after: tuple[tuple[str, int | None], ...]
    wait: str = "afterok"


@dataclass(frozen=True)
class Plan:
    """The jobs (by name) and the arrays they are submitted as, in submission order."""

    jobs: dict[str, Job]
    arrays: tuple[Array, ...]

    def array(self, name: str) -> Array:
        for arr in self.arrays:
            if arr.name == name:
                return arr
        raise KeyError(f"no array {name!r} in the plan; arrays: {[a.name for a in self.arrays]}")

    def to_dict(self) -> dict:
        return {"jobs": {n: asdict(j) for n, j in self.jobs.items()}, "arrays": [asdict(a) for a in self.arrays]}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Plan:
        jobs = {n: Job(**{k: tuple(v) if isinstance(v, list) else v for k, v in j.items()}) for n, j in d["jobs"].items()}
        arrays = tuple(Array(a["name"], a["kind"], tuple(a["jobs"]), tuple((x, i) for x, i in a["after"]),
                             a.get("wait", "afterok")) for a in d["arrays"])
        return cls(jobs, arrays)


# ------------------------------------------------------------------------------------------------ stages
def _interpolate(text: str, key: str | None, item: Any, params: Mapping[str, Any]) -> str:
    """``text`` with DVC's ``${...}`` filled in (:func:`abcgs.dotted.interpolate`)."""
    try:
        return interpolate(text, key, item, params)
    except KeyError as exc:
        raise PlanError(f"dvc.yaml: cannot resolve ${{{exc.args[0]}}} for key {key!r}") from None


def _paths(entries: Iterable[Any] | None) -> list[str]:
    """Paths of a ``deps``/``outs``/``metrics``/``plots`` list (entries are strings or ``{path: options}``)."""
    out: list[str] = []
    for e in entries or ():
        out += [str(e)] if not isinstance(e, Mapping) else [str(k) for k in e]
    return out


def _collection_of(spec: Mapping[str, Any], stage: str) -> str | None:
    foreach = spec.get("foreach")
    if foreach is None:
        if "matrix" in spec:
            raise PlanError(f"dvc.yaml stage {stage!r}: `matrix` stages are not supported by the cluster plan")
        return None
    m = DVC_VARIABLE.fullmatch(str(foreach).strip())
    if not m:
        raise PlanError(f"dvc.yaml stage {stage!r}: foreach must name a params collection (${{...}}), got {foreach!r}")
    if m.group(1) not in COLLECTIONS:
        raise PlanError(f"dvc.yaml stage {stage!r}: foreach over {m.group(1)!r}; the cluster plan knows "
                        f"{sorted(COLLECTIONS)}")
    return m.group(1)


def expand_stages(dvc_yaml: Mapping[str, Any], params: Mapping[str, Any]) -> list[Stage]:
    """Every stage of ``dvc_yaml`` as DVC expands it (``foreach`` over the params), with resolved paths."""
    stages: list[Stage] = []
    for base, spec in (dvc_yaml.get("stages") or {}).items():
        collection = _collection_of(spec, base)
        body = spec.get("do", {}) if collection else spec
        try:
            items = lookup(params, collection) if collection else {None: None}
        except KeyError:
            items = {}
        for key, item in (items or {}).items():
            def res(paths: list[str], key=key, item=item) -> tuple[str, ...]:
                return tuple(_interpolate(p, key, item, params) for p in paths)

            outs = res(_paths(body.get("outs")) + _paths(body.get("metrics")) + _paths(body.get("plots")))
            name = f"{base}@{key}" if collection else base
            stages.append(Stage(name, base, collection, None if key is None else str(key), res(_paths(body.get("deps"))),
                                outs))
    return stages


def _overlaps(a: str, b: str) -> bool:
    a, b = a.rstrip("/"), b.rstrip("/")
    return a == b or a.startswith(b + "/") or b.startswith(a + "/")


def stage_edges(stages: list[Stage]) -> set[tuple[str, str]]:
    """``(u, v)`` for each pair where an output of stage ``u`` is (or contains, or lies in) a dependency of ``v``."""
    return {(u.name, v.name) for u in stages for v in stages
            if u is not v and any(_overlaps(o, d) for o in u.outs for d in v.deps)}


# ------------------------------------------------------------------------------------------------ the plan
def _entry_scene(params: Mapping[str, Any], collection: str, key: str) -> str:
    """The ``scene`` of entry ``key`` of ``collection`` (``colormatches``, ``experiments``)."""
    entry = lookup(params, f"{collection}.{key}")
    scene = entry.get("scene") if isinstance(entry, Mapping) else None
    if scene is None:
        raise PlanError(f"{collection}.{key} names no scene: the plan puts its stages after that scene's job")
    return str(scene)


def _scene_of(stage: Stage, params: Mapping[str, Any]) -> str:
    """The scene a ``foreach`` stage belongs to: its key for ``data.scenes``, else its entry's ``scene``."""
    if stage.collection == "data.scenes":
        return str(stage.key)
    return _entry_scene(params, str(stage.collection), str(stage.key))


def _job_of(stage: Stage, params: Mapping[str, Any], downstream: set[str]) -> str:
    if stage.collection is None:
        return "report" if stage.name in downstream else "prep"
    if COLLECTIONS[stage.collection] == "prep":
        return "prep"
    if COLLECTIONS[stage.collection] == "scene":
        return f"scene@{_scene_of(stage, params)}"
    return f"experiment@{stage.key}"


def make_plan(dvc_yaml: Mapping[str, Any], params: Mapping[str, Any]) -> Plan:
    """Split the pipeline into :class:`Job` s and :class:`Array` s (module docstring); raise :class:`PlanError`
    when a stage needs the output of a job its own job does not wait for."""
    stages = expand_stages(dvc_yaml, params)
    edges = stage_edges(stages)
    fanned = {s.name for s in stages if s.collection}
    # a stage outside foreach that (transitively) needs a scene's or an experiment's output runs last
    downstream: set[str] = set()
    frontier = set(fanned)
    while frontier:
        nxt = {v for u, v in edges if u in frontier and v not in fanned and v not in downstream}
        downstream |= nxt
        frontier = nxt
    by_job: dict[str, list[str]] = {}
    job_of: dict[str, str] = {}
    for s in stages:
        job_of[s.name] = _job_of(s, params, downstream)
        by_job.setdefault(job_of[s.name], []).append(s.name)

    scenes = [str(k) for k in (params.get("data") or {}).get("scenes") or {}]
    for name in by_job:
        if name.startswith("scene@") and name.removeprefix("scene@") not in scenes:
            raise PlanError(f"{name}: stages name scene {name.removeprefix('scene@')!r}, which is not in data.scenes")
    experiments = [str(k) for k in params.get("experiments") or {}]
    exp_scene = {e: _entry_scene(params, "experiments", e) for e in experiments if f"experiment@{e}" in by_job}

    jobs: dict[str, Job] = {}

    def add(name: str, kind: str, key: str | None, after: tuple[str, ...], whole: bool = False) -> None:
        if name in by_job:
            jobs[name] = Job(name, kind, key, tuple(by_job[name]), () if whole else tuple(by_job[name]),
                             tuple(a for a in after if a in by_job))

    add("prep", "prep", None, ())
    for s in scenes:
        add(f"scene@{s}", "scene", s, ("prep",))
    for e, s in exp_scene.items():
        add(f"experiment@{e}", "experiment", e, (f"scene@{s}",) if f"scene@{s}" in by_job else ("prep",))
    add("report", "report", None, tuple(n for n in by_job if n != "report"), whole=True)
    _check_order(edges, job_of, jobs)
    return Plan(jobs, _arrays(jobs, scenes, exp_scene))


def _ancestors(jobs: dict[str, Job], name: str) -> set[str]:
    seen: set[str] = set()
    todo = list(jobs[name].after)
    while todo:
        j = todo.pop()
        if j not in seen:
            seen.add(j)
            todo += jobs[j].after
    return seen


def _check_order(edges: set[tuple[str, str]], job_of: dict[str, str], jobs: dict[str, Job]) -> None:
    for u, v in sorted(edges):
        ju, jv = job_of[u], job_of[v]
        if ju != jv and ju not in _ancestors(jobs, jv):
            raise PlanError(f"stage {v!r} (job {jv}) needs an output of {u!r} (job {ju}), and {jv} does not wait "
                            f"for {ju}: dvc.yaml no longer fits the scene / experiment split of abcgs.cluster.plan")


def _arrays(jobs: dict[str, Job], scenes: list[str], exp_scene: dict[str, str]) -> tuple[Array, ...]:
    arrays: list[Array] = []
    if "prep" in jobs:
        arrays.append(Array("prep", "prep", ("prep",), ()))
    prep_dep = (("prep", 0),) if "prep" in jobs else ()
    scene_jobs = tuple(f"scene@{s}" for s in scenes if f"scene@{s}" in jobs)
    if scene_jobs:
        arrays.append(Array("scenes", "scene", scene_jobs, prep_dep))
    for i, sj in enumerate(scene_jobs):
        scene = sj.removeprefix("scene@")
        exps = tuple(f"experiment@{e}" for e, s in exp_scene.items() if s == scene)
        if exps:
            arrays.append(Array(f"experiments@{scene}", "experiment", exps, (("scenes", i),)))
    orphans = tuple(f"experiment@{e}" for e, s in exp_scene.items() if f"scene@{s}" not in jobs)
    if orphans:  # experiments of a scene without stages of its own: they only wait for prep
        arrays.append(Array("experiments", "experiment", orphans, prep_dep))
    if "report" in jobs:  # afterany: the report job itself checks that every other job succeeded (job.py)
        arrays.append(Array("report", "report", ("report",), tuple((a.name, None) for a in arrays), "afterany"))
    return tuple(arrays)


# ------------------------------------------------------------------------------------------------ params
def apply_sets(params: dict, sets: Iterable[str]) -> dict:
    """``params`` with ``KEY=VALUE`` changes (dotted keys, YAML values) applied in place; returns ``params``."""
    for item in sets:
        key, eq, value = item.partition("=")
        if not eq or not key:
            raise PlanError(f"--set {item!r}: expected KEY=VALUE, e.g. stylize.optim.iterations=300")
        try:
            parsed = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            reason = " ".join(str(exc).split())
            raise PlanError(f"--set {item!r}: the value is not plain YAML ({reason})") from None
        try:
            set_dotted(params, key.strip(), parsed)
        except (AttributeError, TypeError):
            raise PlanError(f"--set {item!r}: {key.strip()} goes below a params value that is not a mapping") from None
    return params


# ------------------------------------------------------------------------------------------------ resources
@dataclass(frozen=True)
class Resources:
    """What one array task of a kind asks Slurm for."""

    cpus: int = 1
    mem: str = "4G"
    time: str = "01:00:00"
    gres: str | None = None
    partition: str | None = None
    account: str | None = None
    qos: str | None = None
    max_parallel: int | None = None
    extra: tuple[str, ...] = field(default_factory=tuple)

    @property
    def gpus(self) -> bool:
        return bool(self.gres) and "gpu" in str(self.gres)

    def sbatch_options(self) -> list[str]:
        """The ``#SBATCH`` options (without the prefix), e.g. ``--cpus-per-task=4``."""
        opts = [f"--cpus-per-task={self.cpus}", f"--mem={self.mem}", f"--time={self.time}"]
        opts += [f"--{k}={v}" for k, v in (("gres", self.gres), ("partition", self.partition),
                                           ("account", self.account), ("qos", self.qos)) if v]
        return opts + list(self.extra)

    def describe(self) -> str:
        gpu = f", {self.gres}" if self.gres else ""
        return f"{self.cpus} cpu{'s' if self.cpus != 1 else ''}, {self.mem}, {self.time}{gpu}"


def load_resources(path: Path | None = None) -> dict[str, Resources]:
    """Per-kind :class:`Resources` from a YAML file (``defaults:`` plus one mapping per kind of :data:`KINDS`)."""
    path = path or RESOURCES_FILE
    try:
        raw = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
    except OSError as exc:
        raise PlanError(f"--resources {path}: cannot be read ({exc.strerror or exc})") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise PlanError(f"--resources {path}: not YAML ({' '.join(str(exc).split())})") from None
    if not isinstance(raw, dict) or not all(isinstance(v, dict) or v is None for v in raw.values()):
        raise PlanError(f"--resources {path}: a mapping of `defaults:` and per-kind mappings ({', '.join(KINDS)})")
    allowed = {f for f in Resources.__dataclass_fields__}
    unknown = set(raw) - set(KINDS) - {"defaults"}
    if unknown:
        raise PlanError(f"{path}: unknown section(s) {sorted(unknown)}; allowed: defaults, {', '.join(KINDS)}")
    out: dict[str, Resources] = {}
    for kind in KINDS:
        merged = {**(raw.get("defaults") or {}), **(raw.get(kind) or {})}
        bad = set(merged) - allowed
        if bad:
            raise PlanError(f"{path}: {kind}: unknown key(s) {sorted(bad)}; allowed: {sorted(allowed)}")
        if "extra" in merged:
            merged["extra"] = tuple(merged["extra"] or ())
        out[kind] = Resources(**merged)
    return out


GPU_BACKENDS: dict[str, tuple[str, ...]] = {
    "scene": ("fit.backend", "masks.backend", "colormatch.backend"),
    "experiment": ("stylize.compute.backend", "evaluate.backend"),
}
"""Params keys of the rasterizer backend of each job kind's stages."""
CPU_ONLY_BACKENDS = ("cpu", "reference")


def gpu_overrides(resources: Mapping[str, Resources], params: Mapping[str, Any]) -> dict[str, str]:
    """``KEY: "auto"`` for each backend key of a kind that gets a GPU (``gres: gpu:...``) but is set to a CPU-only
    backend: with ``auto`` the stages use gsplat where CUDA is present."""
    out: dict[str, str] = {}
    for kind, keys in GPU_BACKENDS.items():
        if not resources[kind].gpus:
            continue
        for key in keys:
            try:
                value = lookup(params, key)
            except KeyError:
                continue
            if value in CPU_ONLY_BACKENDS:
                out[key] = "auto"
    return out
