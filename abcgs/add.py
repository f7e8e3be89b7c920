"""Adding a scene or a painting to ``params.yaml``: detect and check the input, say what was found, write the entry.

    python -m abcgs add-scene garden /data/garden                 # photos, a COLMAP model, transforms.json, …
    python -m abcgs add-scene lego /data/nerf_synthetic/lego --background 1 1 1
    python -m abcgs add-style starry /data/paintings/starry.jpg --labels /data/paintings/starry_labels.png

The scene's format is detected from its files (:mod:`abcgs.sources.detect`) unless ``--format`` names it, then its
reader checks it (camera count, image sizes, the cameras' conventions) before anything is written. The entry holds
absolute paths (DVC runs experiments in a copy of the repository). ``params.yaml`` is edited as data, never as
text: loaded (with ruamel.yaml's round trip, which keeps the comments, where it is installed), changed, validated
against the schema as a whole and written atomically.
"""

from __future__ import annotations

import io
import os
import re
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from abcgs.entry_checks import check_names, name_problem, pipeline_names
from abcgs.errors import InputError, ParamsError
from abcgs.fit.params import FitParams
from abcgs.io.atomic import write_text
from abcgs.io.guarded import checked_path, regular_file
from abcgs.io.images import load_labels
from abcgs.params import load_params, validate_params
from abcgs.preflight import check_image, check_label_map_sizes, check_painting, check_scene_images, view_sizes
from abcgs.sections import NAME_PATTERN, NAME_RE, read_params_file
from abcgs.sfm.params import ReconstructParams
from abcgs.sources.detect import DEFAULT_IMAGES, image_files
from abcgs.sources.lens import consistent_scale, image_size
from abcgs.sources.params import SceneParams, scene_name_problem
from abcgs.sources.read import marker, read_entry, resolve_format
from abcgs.sources.registry import reader_of
from abcgs.types import SourceScene

MIN_PHOTOS = 3
"""Structure from motion needs at least this many overlapping photos (as :mod:`abcgs.sfm.colmap`)."""


def _sizes(sizes: list[tuple[int, int]]) -> str:
    counts = Counter(sizes)
    return ", ".join(f"{w}x{h}" + (f" ({n})" if len(counts) > 1 else "") for (w, h), n in counts.most_common(4))


def describe_source(scene: SourceScene, folder: Path) -> list[str]:
    """Lines saying what a reader found: views, sizes, lenses, points, what it did."""
    lens = Counter(v.distortion.model if v.distortion else "pinhole" for v in scene.views)
    folders = Counter(str(v.image_path.parent.relative_to(folder)) if v.image_path.is_relative_to(folder)
                      else str(v.image_path.parent) for v in scene.views)
    lines = [f"{len(scene.views)} views with cameras from {marker(scene.format)}, "
             f"{_sizes([(v.camera.width, v.camera.height) for v in scene.views])} pixels, in "
             f"{', '.join(f + '/' for f in folders)}; lens: {', '.join(f'{m} ({n})' for m, n in lens.items())}"]
    if scene.points is not None:
        lines.append(f"{len(scene.points)} points in the dataset (the fit starts from them)")
    else:
        lines.append("no points in the dataset: the reconstruct stage triangulates them from the given cameras")
    if scene.depth_range is not None:
        lines.append(f"depth range {scene.depth_range[0]:.3g} .. {scene.depth_range[1]:.3g}")
    if scene.background is not None:
        lines.append(f"RGBA views are composited on background {list(scene.background.color)}")
    if masks := sum(v.mask_path is not None for v in scene.views):
        lines.append(f"{masks} view(s) with a mask (passed to the masks stage as labels 1 = kept, 2 = masked out)")
    return lines + list(scene.notes)


def describe_photos(name: str, folder: Path, images: str | None, max_ratio: float) -> list[str]:
    """Check a folder of photos (count, decodable headers, sizes within ``max_ratio`` of the median view's pixels:
    ``reconstruct.max_view_size_ratio``) and say what it holds."""
    sub = images or DEFAULT_IMAGES
    files = image_files(folder / sub)
    if len(files) < MIN_PHOTOS:
        raise InputError(f"{folder / sub} holds {len(files)} image(s); structure from motion needs at least "
                         f"{MIN_PHOTOS} overlapping photos of the scene (LLFF-style captures have 20-60)")
    warnings = check_scene_images(name, folder / sub, max_ratio)
    lines = [f"{len(files)} photos, {_sizes([image_size(p) for p in files])} pixels, in {sub}/; cameras: structure "
             "from motion in the reconstruct stage"]
    stems = {p.stem for p in files}
    lines += label_map_lines(name, folder, view_sizes(folder / sub, stems), images)
    return lines + warnings


def label_map_lines(name: str, folder: Path, views: dict[str, tuple[str, tuple[int, int]]],
                    images: str | None) -> list[str]:
    """Check the label maps in ``<folder>/masks/`` against their views' sizes (``views``: stem → ``(file name,
    (H, W))``; :func:`abcgs.preflight.check_label_map_sizes`) and say what there is."""
    masks = folder / "masks"
    if not masks.is_dir():
        return []
    scaled = check_label_map_sizes(name, masks, views, images)
    n = len(list(masks.glob("*.png")))
    return [f"{n} label map(s) in masks/" + (f", {scaled} of another size than their views: scaled to them (nearest "
                                             "label)" if scaled else "")]


def edit_params(path: str | os.PathLike, edit: Callable[[Any], None], *, write: bool = True) -> str:
    """Apply ``edit`` to the parsed params file and write it back atomically once the result validates (``write``
    False: validate only, as ``--dry-run`` does, so that it refuses what the real run refuses); returns the new
    text. Comments survive where ruamel.yaml is installed (a DVC dependency)."""
    path = Path(path)
    if not path.is_file():
        raise ParamsError(f"{path} not found; run from the repository root or pass --params")
    read_params_file(path)  # the guarded reader first: one line for a file it refuses (a key given twice, a bomb)
    text = path.read_text(encoding="utf-8")
    try:
        from ruamel.yaml import YAML
    except ImportError:
        doc = yaml.safe_load(text)
        edit(doc)
        new = yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)
    else:
        rt = YAML()
        rt.preserve_quotes = True
        rt.width = 120
        rt.indent(mapping=2, sequence=4, offset=2)
        rt.representer.add_representer(  # null stays `null` (ruamel writes an empty value)
            type(None), lambda r, _: r.represent_scalar("tag:yaml.org,2002:null", "null"))
        doc = rt.load(text)
        edit(doc)
        buf = io.StringIO()
        rt.dump(doc, buf)
        new = buf.getvalue()
    validate_params(yaml.safe_load(new), str(path))
    if write:
        write_text(path, new)
    return new


def check_new_name(name: str, section: str, existing: Any, force: bool,
                   params_path: str | os.PathLike | None = None) -> None:
    """Raise :class:`InputError` when ``name`` is not an identifier, is not a valid scene name (``data.scenes``),
    is one the pipeline cannot take (:func:`abcgs.entry_checks.name_problem`: too long, or its outputs or stages the
    pipeline's own, from the ``dvc.yaml`` beside ``params_path``), or is a key of ``existing`` (``section``'s
    entries) and ``force`` is off."""
    if not NAME_RE.fullmatch(name):
        raise InputError(f"{name!r}: a name must match {NAME_PATTERN} (it becomes a folder and a DVC stage name)")
    if section == "data.scenes" and (problem := scene_name_problem(name)) is not None:
        raise InputError(problem)
    dvc_yaml = None if params_path is None else Path(params_path).resolve().parent / "dvc.yaml"
    if (problem := name_problem(name, section, *pipeline_names(dvc_yaml))) is not None:
        raise InputError(problem)
    if name in (existing or {}) and not force:
        raise InputError(f"{section}.{name} exists already in the params file; choose another name or pass --force to "
                         "replace it")


def edit_checked(params_path: str | os.PathLike, edit: Callable[[Any], None], *, dry_run: bool = False) -> str:
    """:func:`edit_params`, then the names of the edited file checked as the preflight checks them
    (:func:`abcgs.entry_checks.check_names`: no two entries' outputs one path), before it is written (``dry_run``:
    checked only); returns the new text."""
    text = edit_params(params_path, edit, write=False)
    check_names(validate_params(yaml.safe_load(text), str(params_path)),
                *pipeline_names(Path(params_path).resolve().parent / "dvc.yaml"))
    if not dry_run:
        write_text(params_path, text)
    return text


def scene_entry(name: str, path: str | os.PathLike, *, fmt: str = "auto", images: str | None = None,
                background: tuple[float, float, float] | str | None = None, splat: str | os.PathLike | None = None,
                max_view_size_ratio: float = ReconstructParams().max_view_size_ratio,
                min_psnr: float = FitParams().import_min_psnr, splat_format: str = "auto",
                splat_nonfinite: str = "refuse", views: dict | None = None) -> tuple[dict, list[str]]:
    """The ``data.scenes.<name>`` entry for the scene at ``path`` (absolute paths, the detected format) and the lines
    describing it. Raises :class:`InputError` for anything its reader refuses. ``splat_format``,
    ``splat_nonfinite`` and ``views`` (a :class:`~abcgs.splats.params.SplatViewsParams` mapping) are the entry's
    settings of the same names, written when they are not the defaults and used by the checks here."""
    folder = checked_path(path, "scene folder")
    if folder.exists() and not folder.is_dir():
        try:
            regular_file(folder, "scene")  # a FIFO, a socket or a device is named as such, not "does not exist"
        except InputError as exc:
            raise InputError(f"{str(exc).split('; ')[0]}; give the scene's folder, or its splat file") from None
    resolved = resolve_format(folder, fmt, images)
    options: dict[str, Any] = {"format": resolved}
    if images:
        options["images"] = images
    if views:
        options["views"] = dict(views)
    entry: dict[str, Any] = {"path": str(folder), "source": options}
    if background is not None:
        entry["background"] = background if background == "transparent" else [float(c) for c in background]
    if splat_format != "auto":
        entry["splat_format"] = splat_format
    if splat_nonfinite != "refuse":
        entry["splat_nonfinite"] = splat_nonfinite
    SceneParams.model_validate(entry)  # the settings, before any file is read
    drop = splat_nonfinite == "drop"
    source = None
    cameras = reader_of(resolved).cameras
    if cameras == "sfm":  # photos: structure from motion finds their cameras in the reconstruct stage
        lines = describe_photos(name, folder, images, max_view_size_ratio)
    elif cameras == "made":  # a bare splat: its cameras are made around it in the reconstruct stage
        from abcgs.sources.detect import splat_file
        from abcgs.splats.registry import read_splat

        model = read_splat(splat_file(folder), splat_format, drop_invalid=drop).model
        lines = [f"a bare splat scene: {folder}, {model.num_gaussians} Gaussians of SH degree {model.sh_degree} "
                 "(cameras are made around it; its renders are the photos)"]
    else:
        source = read_entry(SceneParams.model_validate(entry), folder, resolved)
        lines = describe_source(source, folder)
        lines += label_map_lines(name, folder, {Path(v.name).stem: (v.name, (v.camera.height, v.camera.width))
                                                for v in source.views}, images)
    bg = SceneParams.model_validate(entry).resolved_background(resolved)
    if bg.object:
        lines.append("an object on nothing: colour match and stylization act on the object, empty space stays "
                     + ("transparent (RGBA renders)" if bg.transparent else f"{list(bg.color)}"))
    if splat is not None:
        splat_path = checked_path(splat, "--splat")
        if not splat_path.exists():
            raise InputError(f"--splat {splat_path} does not exist; give the fitted splat: its file (.ply, .splat, "
                             ".spz, gsplat's .pt) or its trainer's output folder (INRIA's, splatfacto's exports)")
        splat_path = _splat_file(splat_path, splat_format)
        entry["splat"] = str(splat_path)
        lines.append(_splat_check(splat_path, source, min_psnr, splat_format, drop))
    SceneParams.model_validate(entry)
    return entry, lines


def _splat_file(path: Path, fmt: str) -> Path:
    """What the entry names for ``--splat path``: the PLY in splatfacto's exports folder (so that the export stage
    gives the stylized scene back as a PLY of that name, beside the run's transforms), else ``path`` itself."""
    from abcgs.splats.formats.splatfacto import splatfacto_ply
    from abcgs.splats.registry import detect_splat_format

    if path.is_dir() and (fmt == "splatfacto" or fmt == "auto" and detect_splat_format(path) == "splatfacto"):
        return splatfacto_ply(path)
    return path


def _splat_check(splat: Path, source: SourceScene | None, min_psnr: float, fmt: str = "auto", drop: bool = False) -> str:
    """The fit stage's render-versus-photo check of a trained splat (:func:`abcgs.splats.validate.check_splat`), run
    now on the dataset's undistorted views; the file's frame comes from every camera and the dataset's points, as in
    the fit stage (gsplat's and OpenSplat's worlds are computed from them). Without such views the format is only
    detected (a folder that holds no splat is refused now). Raises :class:`InputError` naming the likely cause."""
    from abcgs.splats.registry import detect_splat_format, read_splat
    from abcgs.splats.validate import check_splat

    try:
        found = detect_splat_format(splat) if fmt == "auto" else fmt
        plain = np.flatnonzero(~source.cameras.distorted) if source is not None else []
        if source is None or not len(plain):
            return (f"splat {splat} ({found}): checked against the photos in the fit stage, once the reconstruct "
                    "stage has the scene's undistorted cameras")
        model = read_splat(splat, found, scene=source, drop_invalid=drop).model
        check = check_splat(model, source.subset(plain), min_psnr=min_psnr, source=str(splat))
    except InputError as exc:  # the fixes the readers name as settings, as this command's options
        text = re.sub(r"set splat_format: (\w+)", r"set splat_format: \1 (add-scene --splat-format \1)", str(exc))
        text = text.replace("splat_nonfinite: drop", "splat_nonfinite: drop (add-scene --splat-nonfinite drop)")
        raise InputError(text) from None
    return (f"splat {splat} ({found}): its renders match the photos at {check.psnr:.1f} dB over "
            f"{len(check.per_view)} views (threshold {min_psnr:g})")


def add_scene(params_path: str | os.PathLike, name: str, path: str | os.PathLike, *, fmt: str = "auto",
              images: str | None = None, background: tuple[float, float, float] | str | None = None,
              splat: str | os.PathLike | None = None, force: bool = False, dry_run: bool = False,
              splat_format: str = "auto", splat_nonfinite: str = "refuse", views: dict | None = None
              ) -> tuple[dict, list[str]]:
    """Check the scene and write ``data.scenes.<name>`` into the params file (``dry_run``: check the edited file
    as the real run does, write nothing). ``splat_format``, ``splat_nonfinite``, ``views``: :func:`scene_entry`."""
    params = load_params(params_path)
    check_new_name(name, "data.scenes", params.data.scenes, force, params_path)
    entry, lines = scene_entry(name, path, fmt=fmt, images=images, background=background, splat=splat,
                               max_view_size_ratio=params.reconstruct.max_view_size_ratio,
                               min_psnr=params.fit.import_min_psnr, splat_format=splat_format,
                               splat_nonfinite=splat_nonfinite, views=views)

    def edit(doc: Any) -> None:
        doc["data"]["scenes"][name] = entry

    edit_checked(params_path, edit, dry_run=dry_run)
    return entry, lines


def describe_labels(labels_path: Path, painting: Path) -> list[str]:
    """Check a painting's region map (decodes, labels something, the painting's shape) and say what it holds."""
    check_image(labels_path, "--labels")
    labels = load_labels(labels_path)
    if not np.any(labels):
        raise InputError(f"{labels_path} is all 0 (unassigned): it labels no region; paint regions 1, 2, … "
                         "(python -m abcgs.masks.page --painting PAINTING)")
    h, w = labels.shape
    pw, ph = image_size(painting)
    if not consistent_scale((pw, ph), (w, h)):
        raise InputError(f"{labels_path} is {w}x{h} but the painting {painting} is {pw}x{ph}: a region map has the "
                         "painting's shape (any scale); paint it on this painting")
    values, counts = np.unique(labels[labels > 0], return_counts=True)
    shares = ", ".join(f"{int(v)}: {c / labels.size:.0%}" for v, c in zip(values, counts))
    return [f"region map {w}x{h}, labels {shares} of the pixels"]


def add_style(params_path: str | os.PathLike, name: str, path: str | os.PathLike, *,
              labels: str | os.PathLike | None = None, force: bool = False, dry_run: bool = False
              ) -> tuple[dict, list[str]]:
    """Check the painting (and its region map) and write ``data.styles.<name>`` (and ``data.style_masks.<name>``)."""
    check_new_name(name, "data.styles", load_params(params_path).data.styles, force, params_path)
    painting = checked_path(path, "painting")
    check_painting(painting, "painting")
    w, h = image_size(painting)
    entry = {"styles": str(painting)}
    lines = [f"painting {w}x{h}"]
    if labels is not None:
        labels_path = checked_path(labels, "--labels")
        lines += describe_labels(labels_path, painting)
        entry["style_masks"] = str(labels_path)

    def edit(doc: Any) -> None:
        for section, value in entry.items():
            if doc["data"].get(section) is None:
                doc["data"][section] = {}
            doc["data"][section][name] = value

    edit_checked(params_path, edit, dry_run=dry_run)
    return entry, lines
