"""Fuzzing the readers of files made by other people's tools: every result is a scene or a one-line refusal.

    python -m eval run fuzz --inputs 10000 --json docs/measurements/fuzz.json
    python -m eval run fuzz --inputs 200 --formats spz ply          # a quick look at two formats

For each format a small valid input is made the way the project makes it (:func:`make_targets`): a 3DGS PLY, a
SuperSplat compressed PLY, a ``.splat``, a ``.spz``, a COLMAP model (binary and text) with its images, a nerfstudio ``transforms.json``, an LLFF
``poses_bounds.npy``, the masks page's request body (``Content-Length`` and JSON, plus an image index), and
(:mod:`eval.bench.fuzz_inputs`) a photo read by its header, a gsplat checkpoint, an INRIA ``cameras.json``, a
splatfacto ``dataparser_transforms.json``, a ``params.yaml``, a stylized scene's ``fitted_rows.npy``, a
reconstructed scene's ``scene.json`` and a scene whose files become special files. Each
input is one seeded mutation of it (:data:`eval.bench.fuzz_mutations.MUTATIONS`): truncated, bytes flipped or inserted, a count or size field
inflated, a number replaced by 0, -1, NaN, infinity or a huge value, a record repeated, the JSON nested deeply, a
gzip stream padded to a bomb, a PNG header claiming 10⁹ × 10⁹ pixels, a checkpoint field made 0-d, complex or
empty, a YAML alias bomb, a FIFO or ``/dev/zero`` in a file's place. Its reader must return a scene, or refuse with
:class:`~abcgs.errors.InputError` (the masks page: :class:`~abcgs.masks.page.requests.Refused`, a 4xx; ``params.yaml``:
:class:`~abcgs.errors.ParamsError`); any other exception, or an input slower than
:data:`SLOW_S`, is a finding. Each format runs in a child process, so a reader that crashes the interpreter (a native
abort) is reported with the input that did it instead of ending the run.

Prints a table per format (inputs, read, refused, findings, slowest input, peak memory) and, with ``--json``, writes
the record. ``tests/test_fuzz_readers.py`` runs the same targets with a few hundred inputs each.
"""

from __future__ import annotations

import io
import json
import multiprocessing as mp
import resource
import tempfile
import time
import traceback
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np
import torch

from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.errors import InputError
from eval.bench import fuzz_inputs
from eval.bench.fuzz_mutations import MUTATIONS
from eval.record import bench_parser, write_record

FORMATS = ("ply", "supersplat", "splat", "spz", "colmap_bin", "colmap_txt", "transforms", "llff", "paint", "image",
           "gsplat_ckpt", "inria_cameras", "splatfacto", "params", "fitted_rows", "scene_record", "special")
SLOW_S = 5.0
"""An input whose reader takes longer than this (seconds) is a finding."""
# ------------------------------------------------------------------------------------------ valid inputs


def sample_model(n: int = 64, degree: int = 1, seed: int = 0):
    """``n`` random Gaussians of SH degree ``degree`` round the origin (the same for the same ``seed``)."""
    from abcgs.gaussians import GaussianModel

    g = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2 - 1
    return GaussianModel(
        means=(torch.rand(n, 3, generator=g) - 0.5) * 2, quats=torch.randn(n, 4, generator=g),
        log_scales=torch.rand(n, 3, generator=g) * 2 - 5, opacity_logits=torch.randn(n, generator=g),
        sh0=torch.rand(n, 1, 3, generator=g) - 0.5, shN=(torch.rand(n, k, 3, generator=g) - 0.5) * 0.2)


def sample_cameras(n: int = 5, w: int = 32, h: int = 24) -> list[Camera]:
    """``n`` cameras on an arc 4 units from the origin, looking at it."""
    cams = []
    for i in range(n):
        a = -0.5 + i / max(n - 1, 1)
        eye = np.array([4 * np.sin(a), -0.3, -4 * np.cos(a)])
        cams.append(Camera(f"view{i:02d}.png", intrinsics(30.0, w, h), look_at(eye, np.zeros(3)), w, h))
    return cams


def _images(folder: Path, cams: list[Camera]) -> None:
    from abcgs.io.images import save_image

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for c in cams:
        save_image(folder / c.name, rng.random((c.height, c.width, 3)).astype(np.float32))


def sample_points(n: int = 60) -> np.ndarray:
    """``n`` fixed random points ``(n, 3)`` in the cube of side 1 round the origin."""
    return np.random.default_rng(1).uniform(-0.5, 0.5, (n, 3))


def _colmap(folder: Path, cams: list[Camera], text: bool) -> Path:
    from abcgs.cameras import Cameras
    from abcgs.io.colmap import write_model

    model = folder / "sparse" / "0"
    points = sample_points()
    write_model(model, Cameras.from_list(cams), points, np.full((len(points), 3), 128 / 255), text=text)
    return model


def _transforms(folder: Path, cams: list[Camera]) -> Path:
    frames = []
    for c in cams:
        c2w = np.linalg.inv(c.viewmat) @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV → nerfstudio's OpenGL axes
        frames.append({"file_path": f"images/{c.name}", "transform_matrix": c2w.tolist()})
    c = cams[0]
    meta = {"camera_model": "PINHOLE", "fl_x": c.K[0, 0], "fl_y": c.K[1, 1], "cx": c.K[0, 2], "cy": c.K[1, 2],
            "w": c.width, "h": c.height, "frames": frames}
    path = folder / "transforms.json"
    path.write_text(json.dumps(meta, indent=1))
    return path


def _poses_bounds(folder: Path, cams: list[Camera]) -> Path:
    rows = []
    for c in cams:
        c2w = np.linalg.inv(c.viewmat)
        pose = np.stack([c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3]], axis=1)  # LLFF's (down, right, back)
        hwf = np.array([[c.height], [c.width], [c.K[0, 0]]])
        rows.append(np.concatenate([np.concatenate([pose, hwf], axis=1).reshape(-1), [2.0, 6.0]]))
    path = folder / "poses_bounds.npy"
    np.save(path, np.array(rows))
    return path


@dataclass
class Target:
    """One format's valid input and its reader.

    Attributes:
        name: the format (:data:`FORMATS`).
        files: the files a mutation may change (the first is changed most often).
        read: reads the input as the pipeline does; returns what it read (anything), raises on refusal.
        kind: ``bytes`` (binary), ``text`` or ``json``: which mutations apply.
        refusal: the exception type that is a clear refusal.
    """

    name: str
    files: list[Path]
    read: Callable[[], object]
    kind: str
    refusal: type[Exception] = InputError
    originals: dict[Path, bytes] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.originals = {p: p.read_bytes() for p in self.files}

    def restore(self) -> None:
        for p, data in self.originals.items():
            fuzz_inputs.clear(p)  # a special file a mutation left (writing to a FIFO would wait for a reader)
            p.write_bytes(data)


def make_targets(work: Path, formats: tuple[str, ...] = FORMATS) -> dict[str, Target]:
    """A valid input of each format under ``work`` and its reader (module docstring); each reads as made."""
    from abcgs.gaussians.ply import write_ply
    from abcgs.sources.read import read_source
    from abcgs.splats.formats.splat import write_splat_file
    from abcgs.splats.formats.spz import write_spz
    from abcgs.splats.registry import read_splat

    out: dict[str, Target] = {}
    cams = sample_cameras()
    if "ply" in formats:
        p = work / "ply" / "point_cloud.ply"
        p.parent.mkdir(parents=True)
        write_ply(p, sample_model())
        out["ply"] = Target("ply", [p], lambda p=p: read_splat(p, "auto"), "bytes")
    if "supersplat" in formats:
        from abcgs.splats.formats.supersplat import write_compressed_ply

        p = work / "supersplat" / "scene.compressed.ply"
        p.parent.mkdir(parents=True)
        write_compressed_ply(p, sample_model(300))
        out["supersplat"] = Target("supersplat", [p], lambda p=p: read_splat(p, "supersplat"), "bytes")
    if "splat" in formats:
        p = work / "splat" / "scene.splat"
        p.parent.mkdir(parents=True)
        write_splat_file(p, sample_model(degree=0))
        out["splat"] = Target("splat", [p], lambda p=p: read_splat(p, "splat"), "bytes")
    if "spz" in formats:
        p = work / "spz" / "scene.spz"
        p.parent.mkdir(parents=True)
        write_spz(p, sample_model())
        out["spz"] = Target("spz", [p], lambda p=p: read_splat(p, "spz"), "gzip")
    for name, text in (("colmap_bin", False), ("colmap_txt", True)):
        if name in formats:
            folder = work / name
            _images(folder / "images", cams)
            model = _colmap(folder, cams, text)
            ext = ".txt" if text else ".bin"
            files = [model / f"{stem}{ext}" for stem in ("cameras", "images", "points3D")]
            out[name] = Target(name, files, lambda folder=folder: read_source(folder, "colmap"),
                               "text" if text else "bytes")
    if "transforms" in formats:
        folder = work / "transforms"
        _images(folder / "images", cams)
        p = _transforms(folder, cams)
        out["transforms"] = Target("transforms", [p], lambda folder=folder: read_source(folder, "nerfstudio"), "json")
    if "llff" in formats:
        folder = work / "llff"
        _images(folder / "images", cams)
        p = _poses_bounds(folder, cams)
        out["llff"] = Target("llff", [p], lambda folder=folder: read_source(folder, "llff"), "npy")
    if "paint" in formats:
        from abcgs.masks.page.requests import Refused, image_index, read_body

        p = work / "paint" / "request.txt"
        p.parent.mkdir(parents=True)
        body = json.dumps({"strokes": [{"label": 1, "radius": 4, "points": [[1, 2], [3, 4]]}], "fill": True})
        p.write_bytes(f"{len(body)}\n7\n{body}".encode())

        def read_request(p=p):
            head, index, body = (p.read_bytes().split(b"\n", 2) + [b"", b""])[:3]
            image_index(index.decode("utf-8", "replace"))
            return read_body(head.decode("utf-8", "replace"), io.BytesIO(body))
        out["paint"] = Target("paint", [p], read_request, "json", Refused)
    _more_targets(work, formats, cams, out)
    for t in out.values():
        t.read()  # the valid input reads
    return out


def _more_targets(work: Path, formats: tuple[str, ...], cams: list[Camera], out: dict[str, Target]) -> None:
    """The targets of :mod:`eval.bench.fuzz_inputs` among ``formats``, added to ``out``."""
    makers = {"image": ("png", lambda w: fuzz_inputs.make_image(w)),
              "gsplat_ckpt": ("ckpt", lambda w: fuzz_inputs.make_gsplat_ckpt(w, sample_model(), cams, sample_points())),
              "inria_cameras": ("json", lambda w: fuzz_inputs.make_inria_cameras(w, cams)),
              "splatfacto": ("json", fuzz_inputs.make_splatfacto_transforms),
              "params": ("yaml", fuzz_inputs.make_params),
              "fitted_rows": ("bytes", fuzz_inputs.make_fitted_rows),
              "scene_record": ("json", lambda w: fuzz_inputs.make_scene_record(w, cams)),
              "special": ("special", lambda w: fuzz_inputs.make_special(w, cams, _transforms, _images))}
    for name, (kind, make) in makers.items():
        if name in formats:
            files, read = make(work / name)
            out[name] = Target(name, files, read, kind, fuzz_inputs.REFUSALS.get(name, InputError))


# ------------------------------------------------------------------------------------------ the run


@dataclass
class Finding:
    """An input whose reader neither read it nor refused it clearly (or took longer than :data:`SLOW_S`)."""

    format: str
    index: int
    mutation: str
    file: str
    error: str
    seconds: float


@dataclass
class FormatRun:
    """One format's run: counts, slowest input (s), findings, peak memory of its process (GiB)."""

    format: str
    inputs: int = 0
    read: int = 0
    refused: int = 0
    seconds: float = 0.0
    slowest_s: float = 0.0
    slowest_mutation: str = ""
    peak_rss_gib: float = 0.0
    mutations: dict[str, int] = field(default_factory=dict)
    findings: list[Finding] = field(default_factory=list)


def fuzz_target(t: Target, inputs: int, seed: int = 0, progress: Path | None = None) -> FormatRun:
    """``inputs`` mutations of ``t``'s input, each read once (module docstring); ``progress`` gets the input about
    to be read (what a crash leaves behind)."""
    rng = np.random.default_rng([seed, FORMATS.index(t.name)])
    run = FormatRun(t.name)
    used: Counter[str] = Counter()
    muts = MUTATIONS[t.kind]
    t0 = time.perf_counter()
    for i in range(inputs):
        f = t.files[0] if len(t.files) == 1 or rng.random() < 0.5 else t.files[int(rng.integers(len(t.files)))]
        if t.kind == "special":  # the file replaced by a FIFO, a link to /dev/zero, a symlink loop …
            name = f"special_{fuzz_inputs.special(f, rng)}"
        else:
            mut = muts[int(rng.integers(len(muts)))]
            name = mut.__name__
            f.write_bytes(mut(t.originals[f], rng))
        used[name] += 1
        if progress is not None:
            progress.write_text(json.dumps({"index": i, "mutation": name, "file": f.name}))
        start = time.perf_counter()
        error = None
        try:
            t.read()
            run.read += 1
        except t.refusal as exc:
            run.refused += 1
            if "\n" in str(exc):
                error = f"a refusal of more than one line: {str(exc)[:300]!r}"
        except BaseException as exc:  # noqa: BLE001 (every other exception is the finding)
            if isinstance(exc, KeyboardInterrupt):
                raise
            tb = traceback.extract_tb(exc.__traceback__)[-1]
            error = f"{type(exc).__name__}: {str(exc)[:300]} ({Path(tb.filename).name}:{tb.lineno})"
        dt = time.perf_counter() - start
        if dt > run.slowest_s:
            run.slowest_s, run.slowest_mutation = dt, name
        if error is None and dt > SLOW_S:
            error = f"took {dt:.1f} s"
        if error is not None:
            run.findings.append(Finding(t.name, i, name, f.name, error, round(dt, 3)))
        t.restore()
        run.inputs += 1
    run.seconds = time.perf_counter() - t0
    run.mutations = dict(used)
    run.peak_rss_gib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    return run


def _child(fmt: str, inputs: int, seed: int, result: Path, progress: Path) -> None:
    import logging

    logging.disable(logging.WARNING)  # the readers' notes would flood the output
    with tempfile.TemporaryDirectory() as work:
        t = make_targets(Path(work), (fmt,))[fmt]
        result.write_text(json.dumps(asdict(fuzz_target(t, inputs, seed, progress))))


def run_format(fmt: str, inputs: int, seed: int = 0) -> FormatRun:
    """:func:`fuzz_target` of one format in a child process; a crash of the child is a finding naming the input."""
    with tempfile.TemporaryDirectory() as tmp:
        result, progress = Path(tmp) / "result.json", Path(tmp) / "progress.json"
        proc = mp.get_context("spawn").Process(target=_child, args=(fmt, inputs, seed, result, progress))
        proc.start()
        proc.join()
        if result.is_file():
            data = json.loads(result.read_text())
            data["findings"] = [Finding(**f) for f in data["findings"]]
            return FormatRun(**data)
        last = json.loads(progress.read_text()) if progress.is_file() else {"index": -1, "mutation": "", "file": ""}
        return FormatRun(fmt, inputs=last["index"] + 1, findings=[Finding(
            fmt, last["index"], last["mutation"], last["file"], f"the process died (exit code {proc.exitcode})", 0.0)])


def main(argv: list[str] | None = None) -> int:
    ap = bench_parser(__doc__)
    ap.prog = "python -m eval run fuzz"
    ap.add_argument("--inputs", type=int, default=1000, help="mutated inputs per format")
    ap.add_argument("--formats", nargs="+", choices=FORMATS, default=list(FORMATS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1, help="formats run at once (each in its own process)")
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    runs = []
    print(f"{'format':<11} {'inputs':>7} {'read':>6} {'refused':>8} {'findings':>8} {'slowest s':>10} {'peak GiB':>9} "
          f"{'total s':>8}")
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max(1, args.jobs)) as pool:  # threads that wait on one child process each
        for r in pool.map(lambda fmt: run_format(fmt, args.inputs, args.seed), args.formats):
            runs.append(r)
            print(f"{r.format:<11} {r.inputs:>7} {r.read:>6} {r.refused:>8} {len(r.findings):>8} {r.slowest_s:>10.3f} "
                  f"{r.peak_rss_gib:>9.2f} {r.seconds:>8.1f}", flush=True)
            for f in r.findings[:5]:
                print(f"    #{f.index} {f.mutation} {f.file}: {f.error}")
    if args.json:
        write_record(args.json, {"seed": args.seed, "inputs_per_format": args.inputs, "slow_s": SLOW_S,
                                 "jobs": args.jobs, "seconds": round(time.perf_counter() - t_start, 1),
                                 "runs": [asdict(r) for r in runs]}, argv)
    return 1 if any(r.findings for r in runs) else 0


if __name__ == "__main__":
    raise SystemExit(main())
