"""Checks that run before any stage does work: what the schema cannot see.

The schema (:mod:`abcgs.params`) checks types, names and cross-references inside ``params.yaml``. This module
checks the params against the two other things a run depends on:

- ``dvc.yaml``: every params key a stage tracks must be present in the params file itself (a default filled in by
  the schema does not count: DVC reads the YAML, and aborts with "Parameters ... are missing" after the earlier
  stages have run). :func:`check_dvc_tracked_keys`; :func:`check_scene_entries`: scenes are mappings when
  ``dvc.yaml`` reads ``${item.path}``. :func:`check_report_inputs` (run by the ``report`` stage before it reads
  anything): the report stage depends on every output it reads for these experiments (``python -m abcgs.dag
  --update``, which ``make run`` runs first, writes them).
- the inputs (:func:`check_input_files`): every scene folder exists and its format is known (given or detected:
  :mod:`abcgs.sources.detect`); a folder of photos holds decodable views of similar sizes (:func:`check_scene_images`;
  an alpha channel or a grey view among colour ones is a warning), its ``masks/`` name views and label something
  (:func:`check_scene_masks`; numbered labels that skip values are a warning) at their views' size or its scale
  (:func:`check_label_map_sizes`); a dataset with cameras is read and
  checked by the ``preflight`` stage (:mod:`abcgs.source_check`: the model is present, images match cameras, sizes
  are a consistent scale); paintings and label maps exist, decode, are large enough and do not live in a folder stages write (a label map of another
  size than its painting is a warning), and ``vgg.path`` exists. A scene or painting a ``dvc.yaml`` stage produces
  (the embedded tiny scene, made by ``make_tiny``) is checked by that stage instead; a path into it must name a
  file the stage writes there (:data:`PRODUCED_FILES`). The labels the colour matches bind exist in the label
  maps where those are given files (:func:`check_bindings`).
- the names and numbers (:mod:`abcgs.entry_checks`; no file read): an entry's name is a
  file name of at most :data:`MAX_NAME_LENGTH` characters that none of the pipeline's own outputs or stages takes,
  no two entries' outputs are one path (DVC stops every ``dvc repro`` on overlapping outputs, before the
  ``preflight`` stage), and every label a colour match binds is one a label map holds (1 … 254).

:func:`abcgs.pipeline.run_stage` runs the params checks for every stage; the ``preflight`` stage
(``stages/preflight.py``), which every other stage depends on, runs the input checks too, so ``dvc repro`` stops
there before any stage's outputs are deleted. ``python -m abcgs.preflight params.yaml`` runs them all by hand
(``make run`` does, before ``dvc repro``: it also explains params that DVC cannot even parse).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Collection, Iterable, Mapping
from pathlib import Path

import cv2
import numpy as np
import yaml

from abcgs import layout
from abcgs.dotted import has_key
from abcgs.dvc_file import dvc_stages, stage_body, stage_outs
from abcgs.entry_checks import check_label_numbers, check_names, pipeline_names
from abcgs.errors import InputError, ParamsError
from abcgs.io.images import check_label_size, check_label_values, decode_image, image_header, stroke_map_path
from abcgs.masks.params import UNDECIDED
from abcgs.scene.params import TINY_STYLE_FILES
from abcgs.sources.detect import DEFAULT_IMAGES, IMAGE_SUFFIXES, detect_format
from abcgs.sources.registry import reader_of

log = logging.getLogger(__name__)


def dvc_tracked_keys(dvc_yaml: Path) -> dict[str, list[str]]:
    """Dotted params keys of ``params.yaml`` tracked by ``dvc.yaml`` stages → the stages tracking them.

    Templated entries (``experiments.${key}``) are left out: their names come from the params themselves.
    Entries that name another params file (``{other.yaml: [...]}``) are left out too.
    """
    out: dict[str, list[str]] = {}
    for name, stage in dvc_stages(dvc_yaml).items():
        for entry in stage_body(stage).get("params", []) or []:
            if isinstance(entry, str) and "${" not in entry:
                out.setdefault(entry, []).append(name)
    return out


def check_dvc_tracked_keys(raw: dict, dvc_yaml: Path, source: str = "params.yaml") -> None:
    """Raise :class:`ParamsError` listing every key ``dvc.yaml`` tracks that the params file lacks."""
    missing = {k: v for k, v in dvc_tracked_keys(dvc_yaml).items() if not has_key(raw, k)}
    if missing:
        lines = [f"{source} lacks key(s) that {dvc_yaml.name} tracks (DVC would stop at those stages after running the "
                 "earlier ones):"]
        for key, stages in sorted(missing.items()):
            parent, _, leaf = key.rpartition(".")
            hint = f"add `{leaf}: {{}}` under `{parent}:`" if parent else f"add a `{leaf}:` section"
            lines.append(f"  {key}: tracked by stage(s) {', '.join(sorted(set(stages)))}; {hint} (empty is fine)")
        raise ParamsError("\n".join(lines))


def check_scene_entries(raw: dict, dvc_yaml: Path, source: str = "params.yaml") -> None:
    """Every ``data.scenes`` entry is a mapping when a ``dvc.yaml`` stage reads ``${item.path}`` from it (DVC
    would stop with "Could not find 'item.path'" before any stage runs)."""
    reads_path = any(
        isinstance(stage, dict) and stage.get("foreach") == "${data.scenes}" and "${item.path}" in yaml.safe_dump(stage)
        for stage in dvc_stages(dvc_yaml).values()
    )
    scenes = ((raw.get("data") or {}).get("scenes") or {}) if isinstance(raw, dict) else {}
    plain = [name for name, v in scenes.items() if isinstance(v, str)] if isinstance(scenes, dict) else []
    if reads_path and plain:
        name = plain[0]
        raise ParamsError(
            f"{source}: data.scenes.{', data.scenes.'.join(plain)}: a plain path; {dvc_yaml.name} reads "
            f"${{item.path}}, so write e.g. `{name}: {{path: {scenes[name]}}}` (a scene is a mapping so that it can "
            "carry per-scene overrides: fit, reconstruct, masks)")


def dvc_outputs(dvc_yaml: Path) -> list[str]:
    """Paths a ``dvc.yaml`` stage writes (``outs``; templated ones left out)."""
    return [p for stage in dvc_stages(dvc_yaml).values() for p in stage_outs(stage) if "${" not in p]


PRODUCED_FILES: dict[str, tuple[str, ...]] = {"make_tiny": TINY_STYLE_FILES}
"""Per ``dvc.yaml`` stage: the files in its output folder that params may name, relative to it (checked before the
stage has run)."""


def dvc_output_files(dvc_yaml: Path) -> dict[str, tuple[str, ...]]:
    """Output folder of each stage of :data:`PRODUCED_FILES` → the files in it that params may name."""
    out: dict[str, tuple[str, ...]] = {}
    for name, stage in dvc_stages(dvc_yaml).items():
        if name not in PRODUCED_FILES:
            continue
        for p in stage_outs(stage):
            if "${" not in p:
                out[p] = PRODUCED_FILES[name]
    return out


def _producer(path: Path, outputs: Iterable[str], root: Path) -> str | None:
    """The stage output (a path of ``outputs``) that ``path`` is or lies in, if any."""
    target = (root / path).resolve()
    for out in outputs:
        o = (root / out).resolve()
        if target == o or o in target.parents:
            return out
    return None


def produced_by_stage(path: Path, outputs: Iterable[str], root: Path) -> bool:
    return _producer(path, outputs, root) is not None


def check_image(path: Path, what: str) -> None:
    """The image ``path`` exists, is a regular file, its header is within :data:`abcgs.io.images.MAX_IMAGE_PIXELS`
    and it decodes (:func:`abcgs.io.images.decode_image`); :class:`InputError` prefixed with ``what``."""
    if not path.exists() and not path.is_symlink():
        raise InputError(f"{what}: {path} does not exist; fix the path in params.yaml (paths are relative to the "
                         "repository root)")
    try:
        decode_image(path)
    except InputError as exc:
        raise InputError(f"{what}: {exc}") from None


MIN_PAINTING_SIDE = 32
"""Paintings smaller than this on a side carry no strokes for VGG's relu3 features (a 4× downsampling)."""
STAGE_OUTPUT_ROOTS = ("out", "reports")
"""Folders the pipeline's stages write and delete: inputs must not live there."""


def check_painting(path: Path, what: str) -> None:
    check_image(path, what)
    w, h = _size(path)
    if min(w, h) < MIN_PAINTING_SIDE:
        raise InputError(f"{what}: {path} is {w}×{h} pixels; a painting needs at least {MIN_PAINTING_SIDE} pixels on "
                         "each side for its strokes to reach the style features; use a larger image")


def _in_stage_output(rel: str, root: Path) -> str | None:
    """The stage-output folder (``out/``, ``reports/``) that ``rel`` lies in, if any."""
    try:
        parts = (root / rel).resolve().relative_to(root.resolve()).parts
    except ValueError:
        return None
    return parts[0] if parts and parts[0] in STAGE_OUTPUT_ROOTS else None


def check_scene_images(name: str, images: Path, max_ratio: float) -> list[str]:
    """Headers of a scene's photos (no decoding): an error for a view far larger than the capture's median view,
    warnings for an alpha channel (ignored) and grey views among colour ones (used as grey RGB). Returns warnings."""
    sizes, modes = {}, {}
    for p in sorted(q for q in images.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES):
        w, h, modes[p.name] = image_header(p, f"data.scenes.{name}: view")
        sizes[p.name] = (w, h)
    pixels = {n: w * h for n, (w, h) in sizes.items()}
    median = float(np.median(list(pixels.values())))
    big = {n: px / median for n, px in pixels.items() if max_ratio and px > max_ratio * median}
    if big:
        worst = max(big, key=big.get)
        w, h = sizes[worst]
        mw, mh = sorted(sizes.values(), key=lambda s: s[0] * s[1])[len(sizes) // 2]
        raise InputError(
            f"data.scenes.{name}: {images / worst} is {w}×{h}, {big[worst]:.0f}× the pixels of the capture's median "
            f"view ({mw}×{mh}){f' (and {len(big) - 1} more)' if len(big) > 1 else ''}. One capture's views should have "
            f"similar sizes: resize it to about {mw}×{mh}, or remove it; reconstruct.max_view_size_ratio "
            f"(now {max_ratio:g}, 0 = off) sets the limit")
    warnings = []
    alpha = [n for n, m in modes.items() if m in ("RGBA", "LA", "PA") or m.endswith("A")]
    if alpha:
        warnings.append(f"data.scenes.{name}: {len(alpha)} view(s) have an alpha channel, which is ignored (pixels are "
                        f"used as if opaque): {', '.join(alpha[:5])}{' …' if len(alpha) > 5 else ''}")
    grey = [n for n, m in modes.items() if m in ("L", "LA", "I;16", "I", "1")]
    if grey and len(grey) < len(modes):
        warnings.append(f"data.scenes.{name}: {len(grey)} grey view(s) among colour views are used as grey RGB, which "
                        f"the fit cannot reconcile with the colour views: {', '.join(grey[:5])}")
    return warnings


def mask_labels(path: Path) -> np.ndarray | None:
    """A numbered label PNG (single-channel or grey) as ``(H, W)`` integers; ``None`` when it holds colours (those
    are numbered together across the files by :func:`abcgs.masks.content.read_label_files`). A value above 255 or
    a file that does not decode raises :class:`InputError` naming it."""
    img = decode_image(path, "label map")
    if img.ndim == 3:
        img = img[..., :3]
        if not (np.all(img[..., 0] == img[..., 1]) and np.all(img[..., 1] == img[..., 2])):
            return None
        img = img[..., 0]
    check_label_values(path, img)
    return img


def paint_command(folder: Path, images: str | None = None) -> str:
    """The command that opens the strokes page on a scene's views (what a label map of the right size comes from)."""
    return f"python -m abcgs.masks.page {folder}" + (f" --images {images}" if images and images != DEFAULT_IMAGES else "")


def check_label_map_sizes(name: str, masks: Path, views: Mapping[str, tuple[str, tuple[int, int]]],
                          images: str | None = None) -> int:
    """Every label PNG in ``masks`` is its view at some scale (:func:`abcgs.io.images.check_label_size`, from the
    files' headers). ``views``: view stem → ``(file name, (H, W))``; maps of no view are left to
    the caller. Raises :class:`InputError` naming the file, both sizes and the fix (or a label above 255:
    :func:`mask_labels`); returns how many maps are of
    another size (the ``reconstruct`` stage scales them to their views, nearest label)."""
    scaled = 0
    for p in sorted(masks.glob("*.png")) if masks.is_dir() else []:
        if p.stem not in views:
            continue
        view, hw = views[p.stem]
        strokes = stroke_map_path(masks, p.stem)  # the page's strokes of the view, scaled with it (strokes_for_view)
        for f in (p, strokes) if strokes.exists() else (p,):
            w, h = _size(f)
            mask_labels(f)  # its values: a label above 255 is refused before any work
            if (h, w) != tuple(hw):
                check_label_size(f, (h, w), hw, view, f"or paint it on the views: {paint_command(masks.parent, images)}")
                scaled += 1
    if scaled:
        log.info("data.scenes.%s: %d label map(s) in %s are scaled to their views (nearest label)", name, scaled, masks)
    return scaled


def view_sizes(images: Path, stems: Collection[str]) -> dict[str, tuple[str, tuple[int, int]]]:
    """View stem → ``(file name, (H, W))`` of the images in the folder ``images`` whose stems are in ``stems`` (from
    the files' headers), for :func:`check_label_map_sizes`."""
    return {p.stem: (p.name, _size(p)[::-1]) for p in sorted(images.iterdir())
            if p.suffix.lower() in IMAGE_SUFFIXES and p.stem in stems}


def check_scene_masks(name: str, folder: Path, images: str = DEFAULT_IMAGES) -> list[str]:
    """The user's label PNGs in ``<scene>/masks/`` name views of ``images/`` and label something. Returns warnings:
    numbered labels that skip values (``7`` beside ``1, 2, 3``: each value is a label of its own; ``255``,
    :data:`~abcgs.masks.params.UNDECIDED`, is no label but a gap left undecided)."""
    masks = folder / "masks"
    files = sorted(masks.glob("*.png")) if masks.is_dir() else []
    if not files:
        return []
    stems = {p.stem for p in (folder / images).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES}
    orphans = [p.name for p in files if p.stem not in stems]
    if orphans:
        raise InputError(
            f"data.scenes.{name}: {len(orphans)} of {len(files)} mask file(s) in {masks} match no view in images/ "
            f"({', '.join(orphans[:5])}{' …' if len(orphans) > 5 else ''}). A mask is named like its view "
            f"(masks/IMG_0001.png labels images/IMG_0001.jpg); rename or remove them")
    try:
        check_label_map_sizes(name, masks, view_sizes(folder / images, {p.stem for p in files}), images)
    except InputError as exc:
        raise InputError(f"data.scenes.{name}: {exc}") from None
    if all(_labels_nothing(p) for p in files):
        raise InputError(f"data.scenes.{name}: every mask in {masks} is all 0 (no label) or 255 (undecided), so it labels nothing; "
                         "paint the labels (1, 2, … or colours on black) or remove the folder for automatic masks")
    values = scene_mask_labels(folder)
    if values and max(values) > len(values):
        return [f"data.scenes.{name}: the masks in {masks} use the label value(s) {sorted(values)}: each value is a "
                f"label of its own, so labels beyond {len(values)} ({sorted(v for v in values if v > len(values))}) "
                "are regions too (0 is no label, 255 a gap left undecided)"]
    return []


def _labels_nothing(path: Path) -> bool:
    """A mask PNG with no label: a numbered one (single channel) holding only 0 (no label) and
    :data:`~abcgs.masks.params.UNDECIDED`, or a colour one that is all black."""
    img = decode_image(path, "label map")
    if img.ndim == 2:
        return not np.any((img > 0) & (img != UNDECIDED))
    return not np.any(img[..., :3])


def scene_mask_labels(folder: Path) -> set[int] | None:
    """The non-zero label values of the numbered masks in ``<scene>/masks/``; ``None`` when there are none or they
    hold colours (then the numbers are given when they are read)."""
    files = sorted((folder / "masks").glob("*.png")) if (folder / "masks").is_dir() else []
    maps = [mask_labels(p) for p in files]
    if not maps or any(m is None for m in maps):
        return None
    return {int(v) for m in maps for v in np.unique(m)} - {0, UNDECIDED}


def _check_produced_file(rel: str, out: str, contents: Mapping[str, Collection[str]], root: Path, what: str) -> None:
    """``rel`` lies in the output folder ``out`` of a stage that has not necessarily run: it must be a file that
    stage writes there (``contents``), when that is known."""
    if out not in contents:
        return
    inner = (root / rel).resolve().relative_to((root / out).resolve()).as_posix()
    if inner not in contents[out]:
        raise InputError(f"{what}: {rel} is none of the files the pipeline writes there for params to name "
                         f"({', '.join(f'{out}/{f}' for f in contents[out])}); fix the path")


def _size(path: Path) -> tuple[int, int]:
    """``(width, height)`` from the image's header (:func:`abcgs.io.images.image_header`)."""
    return image_header(path)[:2]


def check_bindings(params, root: Path, produced: Iterable[str]) -> None:
    """The labels each colour match binds exist in the label files the user gives: a compositional or an explicit
    semantic binding's content labels in the scene's numbered masks, where the ``masks`` stage lifts them
    (``masks.source`` auto or given), an explicit semantic binding's regions in the painting's label map
    (:meth:`abcgs.features.params.TransferSpec.check_labels`). Files a stage makes are checked by the
    ``colormatch`` stage instead, before its work."""
    produced = list(produced)
    known: dict[str, set[int] | None] = {}  # scene → the labels of its numbered masks (None: not known here)
    for name, spec in params.colormatches.items():
        scene = params.data.scenes[spec.scene].path
        content = None
        if (spec.reads_content_labels and params.scene_section(spec.scene, "masks").source in ("auto", "given")
                and not produced_by_stage(Path(scene), produced, root)):  # the masks stage lifts the given masks
            if spec.scene not in known:
                known[spec.scene] = scene_mask_labels(root / scene)
            content = known[spec.scene]
        regions, map_path = None, ""
        if spec.transfer == "semantic" and spec.binding != "auto":
            map_path = params.data.style_masks.get(spec.style, "")
            if map_path and not produced_by_stage(Path(map_path), produced, root):
                labels = mask_labels(root / map_path)
                regions = None if labels is None else {int(v) for v in np.unique(labels)} - {0, UNDECIDED}
        spec.check_labels(name, content, f"the masks in {Path(scene) / 'masks'}", regions, map_path)


def check_input_files(params, root: Path, produced: Iterable[str] = (),
                      contents: Mapping[str, Collection[str]] | None = None) -> list[str]:
    """Scene folders, style files and weights named in the params exist, decode and make sense (module docstring).
    A path inside a stage's output folder must be among the files the stage writes there (``contents``:
    :func:`dvc_output_files`). Raises :class:`InputError` on the first problem; returns warnings."""
    produced, contents = list(produced), dict(contents or {})
    warnings: list[str] = []
    for section, entries in (("styles", params.data.styles), ("style_masks", params.data.style_masks)):
        for name, rel in entries.items():
            inside = _in_stage_output(rel, root)
            if inside:
                raise InputError(f"data.{section}.{name}: {rel} lies in {inside}/, which pipeline stages write and "
                                 "delete when they re-run; copy the file to a folder of its own")
            out = _producer(Path(rel), produced, root)
            if out is not None:  # e.g. the tiny scene's paintings, made by make_tiny
                _check_produced_file(rel, out, contents, root, f"data.{section}.{name}")
            else:
                (check_painting if section == "styles" else check_image)(root / rel, f"data.{section}.{name}")
    for name, rel in params.data.style_masks.items():
        painting = params.data.styles.get(name)
        if painting is None or produced_by_stage(Path(rel), produced, root) or produced_by_stage(Path(painting), produced, root):
            continue
        (mw, mh), (pw, ph) = _size(root / rel), _size(root / painting)
        if (mw, mh) != (pw, ph):
            stretch = " (another aspect ratio: its regions are stretched)" if abs(mw * ph - mh * pw) > max(pw, ph) else ""
            warnings.append(f"data.style_masks.{name}: {rel} is {mw}×{mh} but its painting {painting} is {pw}×{ph}; "
                            f"the label map is resized to the painting (nearest label){stretch}")
    if params.vgg.path and not (root / params.vgg.path).is_file():
        raise InputError(f"vgg.path: {params.vgg.path} does not exist; give a torchvision VGG-16 state dict (.pth) or "
                         "null to use the weights found on this machine (docs/WEIGHTS.md)")
    for name, scene in params.data.scenes.items():
        rel = scene.path
        folder = root / rel
        if _in_stage_output(rel, root):
            raise InputError(f"data.scenes.{name}: {rel} lies in a folder pipeline stages write and delete; move the "
                             "scene elsewhere")
        if produced_by_stage(Path(rel), produced, root):
            continue
        sub = scene.images or DEFAULT_IMAGES
        images = folder / sub
        if not folder.exists():
            raise InputError(f"data.scenes.{name}: {images} does not exist; a scene folder holds {sub}/ (and "
                             "optionally masks/), or a dataset with its cameras (README \"Your own scene\")")
        try:
            fmt = detect_format(folder, scene.images) if scene.format == "auto" else scene.format
        except InputError as exc:
            raise InputError(f"data.scenes.{name}: {exc}") from None
        if reader_of(fmt).cameras != "sfm":
            continue  # a dataset with cameras: its reader checks it in the preflight stage (abcgs/source_check.py)
        if not images.is_dir():
            raise InputError(f"data.scenes.{name}: {images} does not exist; a scene folder holds {sub}/ (and "
                             "optionally masks/)")
        files = sorted(p for p in images.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise InputError(f"data.scenes.{name}: {images} holds no images ({', '.join(IMAGE_SUFFIXES)})")
        bad = _undecodable(files)
        if bad:
            raise InputError(f"data.scenes.{name}: {len(bad)} image(s) in {images} do not decode: "
                             f"{', '.join(list(bad)[:5])}{' …' if len(bad) > 5 else ''}; remove or replace them (the "
                             f"first: {next(iter(bad.values()))})")
        warnings += check_scene_images(name, images, params.scene_section(name, "reconstruct").max_view_size_ratio)
        warnings += check_scene_masks(name, folder, sub)
    check_label_numbers(params)  # after the label files themselves: a map of label 60000 is named as the cause
    check_bindings(params, root, produced)
    return warnings


def _undecodable(files: list[Path]) -> dict[str, str]:
    """File name → why it does not decode (:func:`abcgs.io.images.decode_image`, at an eighth of its size), for the
    files of ``files`` that do not."""
    bad = {}
    for p in files:
        try:
            decode_image(p, flags=cv2.IMREAD_REDUCED_GRAYSCALE_8)
        except InputError as exc:
            bad[p.name] = str(exc)
    return bad


def check_report_inputs(params, dvc_yaml: Path) -> None:
    """``dvc.yaml``'s ``report`` stage lists every output the report reads for ``params``
    (:func:`abcgs.layout.report_inputs`): its deps are generated from ``params.yaml``'s experiments, so an
    experiment added since leaves the report without a dependency on it, and DVC could build the page before that
    experiment's stages or leave it stale after them."""
    if not dvc_yaml.is_file():  # the stage run outside a pipeline checkout
        return
    stage = dvc_stages(dvc_yaml).get("report")
    if not isinstance(stage, dict):
        return
    listed = {str(d) for d in stage.get("deps") or []}
    missing = [p for p in layout.report_inputs(params) if p not in listed]
    if missing:
        raise ParamsError(
            f"{dvc_yaml}: the report stage does not depend on {len(missing)} output(s) it reads for these params "
            f"({', '.join(missing[:4])}{' …' if len(missing) > 4 else ''}); dvc.yaml is generated from params.yaml's "
            "experiments: run `python -m abcgs.dag --write` (make run does it), then run again")


def preflight(params, raw: dict, params_path: str | os.PathLike, *, files: bool = True) -> list[str]:
    """The checks for ``params`` validated from ``raw``, the parsed ``params_path``; ``dvc.yaml`` and the
    repository root are taken from the params file's folder. Without a ``dvc.yaml`` there (a params file used
    outside the pipeline) only the files are checked; ``files=False`` skips them (stages after the ``preflight``
    stage, which ran them). Returns the warnings (each also logged)."""
    params_path = Path(params_path)
    root = params_path.resolve().parent
    dvc_yaml = root / "dvc.yaml"
    produced: list[str] = []
    contents: dict[str, tuple[str, ...]] = {}
    if dvc_yaml.is_file():
        check_dvc_tracked_keys(raw, dvc_yaml, str(params_path))
        check_scene_entries(raw, dvc_yaml, str(params_path))
        produced, contents = dvc_outputs(dvc_yaml), dvc_output_files(dvc_yaml)
    check_names(params, *pipeline_names(dvc_yaml))
    warnings = check_input_files(params, root, produced, contents) if files else []
    for w in warnings:
        log.warning("preflight: %s", w)
    return warnings


def main(argv: list[str] | None = None) -> int:
    """``python -m abcgs.preflight [params.yaml]``: validate the params and run the checks, before ``dvc repro``
    (DVC reads ``dvc.yaml`` templates before any stage, so some mistakes are best caught here)."""
    import sys

    from abcgs.errors import AbcgsError
    from abcgs.params import validate_params
    from abcgs.sections import read_params_file

    path = (argv if argv is not None else sys.argv[1:]) or ["params.yaml"]
    try:
        raw = read_params_file(path[0])
        preflight(validate_params(raw, path[0]), raw, path[0])
    except AbcgsError as exc:
        print(f"[preflight] error: {exc}", file=sys.stderr)
        return 2
    print(f"[preflight] {path[0]}: ok")
    return 0


if __name__ == "__main__":
    from abcgs.runtime import setup

    setup()  # the process settings (abcgs.runtime.setup): the wait policy only where torch is not loaded yet
    raise SystemExit(main())
