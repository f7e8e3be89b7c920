"""The masks page's state (:class:`PaintSession`): the views of a scene (or one painting), each view's strokes, its
latest cut and where its label map is saved; with a fit, a :class:`~abcgs.masks.page.field_session.FieldSession`
carries each Segment to every view. :func:`scene_views` names the views the pipeline reads."""


from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from abcgs.errors import InputError
from abcgs.io.guarded import regular_file
from abcgs.io.images import load_image, save_labels, save_stroke_map, stroke_map_path, to_uint8
from abcgs.masks.grabcut import segment
from abcgs.masks.params import FieldParams, LiftParams
from abcgs.masks.strokes import Segmentation, Stroke, rasterize_strokes
from abcgs.viz import LABEL_COLOURS

if TYPE_CHECKING:  # torch and the renderer load only with a fit (attach_fit)
    from abcgs.masks.page.field_session import FieldSession

log = logging.getLogger(__name__)

# ----------------------------------------------------------------------------------------------
# Session: the views (or the painting), their strokes and cuts
# ----------------------------------------------------------------------------------------------


@dataclass
class PaintItem:
    """One image on the page and where its label PNG goes."""

    name: str
    image_path: Path
    out_path: Path
    strokes: list[Stroke] = field(default_factory=list)
    result: Segmentation | None = None
    stale: bool = False  # strokes changed since ``result``
    revision: int = 0  # the page's count of edits to ``strokes``: a list of a lower revision is older and ignored


class PaintSession:
    """The images of one page, their strokes and cuts; thread-safe (the server handles requests in threads).

    ``mode`` is ``"scene"`` (every view the pipeline reads of a scene, :func:`scene_views`; masks to
    ``<scene>/masks/<stem>.png``) or
    ``"painting"`` (one painting, its label map to ``labels_out``).
    """

    def __init__(self, items: list[PaintItem], mode: str, title: str, *, iterations: int = 5, max_side: int = 1024,
                 fill: bool = True):
        if not items:
            raise InputError("nothing to paint on: no images")
        self.items, self.mode, self.title = items, mode, title
        self.field: FieldSession | None = None  # the 3-D labels (attach_fit), when the scene's fit exists
        self.field_note = "one view at a time: no fit given"
        self.iterations, self.max_side, self.fill = iterations, max_side, fill
        self._lock = threading.RLock()
        self._images: dict[int, np.ndarray] = {}
        self._png: dict[int, bytes] = {}

    @classmethod
    def for_scene(cls, scene: str | Path, *, images: str | None = None, fmt: str = "auto",
                  background: tuple[float, float, float] | None = None, views: str | Path | None = None,
                  name: str | None = None, first: list[str] = (), **kw) -> PaintSession:
        """The views the pipeline reads of the scene folder ``scene`` (:func:`scene_views`; ``images``, ``fmt``,
        ``background`` as in ``data.scenes.<name>``, ``views`` the folder of a bare splat's generated views, ``name``
        the scene's key for messages); Save
        writes ``<scene>/masks/<stem>.png``, where the ``reconstruct`` stage reads label maps. The views whose
        stems ``first`` names come first, in that order (the page opens the first)."""
        scene = Path(scene)
        found = scene_views(scene, images=images, fmt=fmt, background=background, views=views, name=name)
        stems: dict[str, str] = {}
        for view, _ in found:
            stem = Path(view).stem
            if stem in stems:
                raise InputError(f"{scene} has two views with the stem {stem!r} ({stems[stem]}, {view}): their masks "
                                 f"would share masks/{stem}.png; rename one")
            stems[stem] = view
        rank = {stem: i for i, stem in enumerate(first)}
        found.sort(key=lambda v: rank.get(Path(v[0]).stem, len(rank)))  # stable: the rest keep their order
        items = [PaintItem(view, path, scene / "masks" / f"{Path(view).stem}.png") for view, path in found]
        return cls(items, "scene", scene.resolve().name, **kw)

    @classmethod
    def for_params(cls, params_path: str | Path, name: str, *, out: str | Path | None = None, fit: bool = True,
                   **kw) -> PaintSession:
        """The views of ``data.scenes.<name>`` in the params file ``params_path`` (its folder, format, ``images``
        and background; a bare splat's views from ``<out>/<name>/colmap/images/``, ``out`` default the
        ``out/`` beside the params file), as :meth:`for_scene`; with ``fit``, the scene's 3-D labels from its fit
        (``<out>/<name>/gs/point_cloud.ply``, :meth:`attach_fit`, with ``masks.field`` and ``masks.lift``)."""
        from abcgs import layout
        from abcgs.sections import read_params_file, validate_sections

        params_path = Path(params_path)
        params = validate_sections(read_params_file(params_path), frozenset({"data", "masks"}), str(params_path))
        if name not in params.data.scenes:
            raise InputError(f"data.scenes has no scene {name!r} in {params_path} (it has "
                             f"{', '.join(params.data.scenes)})")
        entry = params.data.scenes[name]
        root = params_path.resolve().parent
        folder = Path(entry.path) if Path(entry.path).is_absolute() else root / entry.path
        dirs = layout.scene(name, Path(out) if out is not None else root / layout.OUT)
        session = cls.for_scene(folder, images=entry.images, fmt=entry.format, background=entry.background,
                                views=dirs.colmap.images, name=name, **kw)
        if fit:
            masks = params.scene_section(name, "masks")
            session.attach_fit(dirs.fit.ply, dirs.colmap.root, masks.field, masks.lift, make=f"`dvc repro fit@{name}`")
        return session

    @classmethod
    def for_painting(cls, painting: str | Path, labels_out: str | Path | None = None, **kw) -> PaintSession:
        """One painting; Save writes its region label map to ``labels_out`` (default ``<stem>_labels.png`` beside it)."""
        painting = Path(painting)
        regular_file(painting, "painting")  # missing, a FIFO, a socket or a folder: named, never opened
        out = Path(labels_out) if labels_out else painting.with_name(f"{painting.stem}_labels.png")
        if out.suffix.lower() != ".png":
            raise InputError(f"--labels-out {out} must be a .png (label numbers need a lossless file)")
        if out.resolve() == painting.resolve():
            raise InputError("--labels-out must not be the painting itself")
        return cls([PaintItem(painting.name, painting, out)], "painting", painting.name, **kw)

    def attach_fit(self, ply: Path, colmap_root: Path, params: FieldParams | None = None,
                   lift: LiftParams | None = None, *, make: str = "the fit stage") -> bool:
        """Show every view's labels after each Segment (:mod:`abcgs.masks.page.field_session`) from the fit ``ply`` and its
        layout ``colmap_root``; without them (or when the views do not match) the page cuts one view at a time and
        :attr:`field_note` says why (``make``: the command that makes the fit). Returns whether it is on."""
        self.field = None
        if not Path(ply).is_file():
            self.field_note = f"one view at a time: no fit at {ply}; {make} makes it"
            log.info("paint: %s", self.field_note)
            return False
        from abcgs.masks.page.field_session import FieldSession  # torch and the renderer: only with a fit

        try:
            self.field = FieldSession.open([it.image_path for it in self.items], ply, colmap_root, params, lift)
        except InputError as exc:
            self.field_note = f"one view at a time: {exc}"
            log.info("paint: %s", self.field_note)
            return False
        self.field_note = f"3-D labels from {ply}"
        return True

    def _item(self, i: int) -> PaintItem:
        if not 0 <= i < len(self.items):
            raise InputError(f"no image {i}; this page has {len(self.items)}")
        return self.items[i]

    def image(self, i: int) -> np.ndarray:
        """``(H, W, 3) uint8`` RGB of image ``i``, as the pipeline reads it (no EXIF rotation)."""
        with self._lock:
            if i not in self._images:
                if len(self._images) >= 8:  # photo-sized scenes: keep a few views in memory
                    self._images.pop(next(iter(self._images)))
                self._images[i] = to_uint8(load_image(self._item(i).image_path))
            return self._images[i]

    def image_png(self, i: int) -> bytes:
        """Image ``i`` encoded for the page (PNG; the browser must not rotate it by EXIF as it would a JPEG)."""
        with self._lock:
            if i not in self._png:
                if len(self._png) >= 8:
                    self._png.pop(next(iter(self._png)))
                ok, buf = cv2.imencode(".png", cv2.cvtColor(self.image(i), cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1])
                if not ok:
                    raise InputError(f"could not encode {self._item(i).name} for the page")
                self._png[i] = buf.tobytes()
            return self._png[i]

    def size(self, i: int) -> tuple[int, int]:
        """``(H, W)`` of image ``i``."""
        return tuple(self.image(i).shape[:2])

    def set_strokes(self, i: int, strokes: list[Stroke], revision: int | None = None) -> bool:
        """Replace image ``i``'s strokes by ``strokes``, the page's list at ``revision`` (its count of edits to
        this image's strokes). A list of a revision not above the one kept is older than it (a request that arrived
        late) and is ignored: returns False. ``None`` replaces the strokes whatever their revision."""
        with self._lock:
            item = self._item(i)
            if revision is not None:
                if revision <= item.revision:
                    log.debug("%s: strokes of revision %d ignored (have %d)", item.name, revision, item.revision)
                    return False
                item.revision = revision
            item.strokes = list(strokes)
            item.stale = True
            if not strokes:
                item.result = None
                if self.field is not None and i in self.field.camera_of:
                    self.field.forget(i)  # its cut no longer seeds the labels in 3-D
            return True

    def segment(self, i: int, fill: bool | None = None) -> Segmentation:
        """Cut image ``i`` from its strokes and keep the result; ``fill`` sets the session's. With the scene's fit
        (:attr:`field`) the cut is seeded by the labels already in 3-D as well, and the strip of every view is
        updated (:meth:`abcgs.masks.page.field_session.FieldSession.segment`; its seconds count from this call); otherwise
        it is :func:`segment` on the view's colours alone."""
        t0 = time.perf_counter()
        with self._lock:
            item = self._item(i)
            if fill is not None:
                self.fill = bool(fill)
            if not any(s.label > 0 for s in item.strokes):
                raise InputError(f"{item.name} has no label strokes yet: pick a label and draw over a region")
            if self.field is not None and i in self.field.camera_of:
                item.result = self.field.segment(i, self.image(i), rasterize_strokes(item.strokes, self.size(i)), t0)
            else:
                item.result = segment(self.image(i), item.strokes, iterations=self.iterations,
                                      max_side=self.max_side, fill=self.fill)
            item.stale = False
            log.info("%s: cut in %.2f s: %s", item.name, item.result.seconds, item.result.counts())
            return item.result

    def saved_labels(self, i: int) -> np.ndarray | None:
        """The label PNG already at image ``i``'s output path (``None`` if there is none or it does not read)."""
        p = self._item(i).out_path
        if not p.is_file():
            return None
        from abcgs.masks.content import read_label_files

        try:
            return np.maximum(read_label_files([p], [self.size(i)])[0][0], 0)  # undecided shows as unassigned
        except InputError:
            return None

    def strokes_of(self, i: int) -> dict:
        """Image ``i``'s strokes as the page sends them and the revision they are at."""
        with self._lock:
            item = self._item(i)
            return {"strokes": [st.to_json() for st in item.strokes], "revision": item.revision}

    def shown_labels(self, i: int) -> tuple[str, np.ndarray | None]:
        """Image ``i``'s name and the labels the page shows on it: its latest cut, else its saved label PNG, else
        ``None`` (not cut yet)."""
        item = self._item(i)
        return item.name, item.result.labels if item.result is not None else self.saved_labels(i)

    def strip_listing(self) -> dict | None:
        """Every view of the strip, most doubtful first (:meth:`FieldSession.listing`); ``None`` without a fit."""
        return None if self.field is None else self.field.listing([it.name for it in self.items])

    def strip_thumbnail(self, camera: int) -> np.ndarray | None:
        """The strip's thumbnail of view ``camera`` (:meth:`FieldSession.thumbnail`); ``None`` without a fit."""
        return None if self.field is None else self.field.thumbnail(camera)

    def save(self, fill: bool | None = None) -> list[Path]:
        """Write the label PNG of every image with strokes (cutting those whose strokes changed), atomically;
        ``fill`` sets the session's first.

        Returns the files written. Images without strokes are left alone (no file is written or removed).
        """
        with self._lock:
            if fill is not None:
                self.fill = bool(fill)
            todo = [i for i, it in enumerate(self.items) if any(s.label > 0 for s in it.strokes)]
            if not todo:
                raise InputError("nothing to save: no image has label strokes")
            for i in todo:
                if self.items[i].result is None or self.items[i].stale:
                    self.segment(i)
            written = []
            for i in todo:
                item = self.items[i]
                # a view's gaps the cut left undecided are saved as such (UNDECIDED), not as "no label": only the
                # background brush says that; a painting's label map has no such value (its regions are all it has)
                save_labels(item.out_path, item.result.saved_map() if self.mode == "scene" else item.result.labels)
                written.append(item.out_path)
                if self.mode == "scene":  # the masks stage binds the Gaussians under them, as the page does
                    save_stroke_map(stroke_map_path(item.out_path.parent, item.out_path.stem),
                                    rasterize_strokes(item.strokes, self.size(i)))
            log.info("saved %d label map(s): %s", len(written), ", ".join(str(p) for p in written))
            return written

    def state(self) -> dict:
        """What the page shows: the images, their stroke counts and whether they are cut and saved."""
        with self._lock:
            used = [s.label for it in self.items for s in it.strokes]
            used += [int(it.result.labels.max()) for it in self.items if it.result is not None]
            return {
                "mode": self.mode, "title": self.title,
                "palette": [[int(c) for c in rgb] for rgb in LABEL_COLOURS],
                "n_labels": max([2, *used]), "fill": self.fill,
                "field": {"on": self.field is not None, "note": self.field_note},
                "items": [{
                    "index": i, "name": it.name, "strokes": len(it.strokes), "cut": it.result is not None,
                    "stale": it.stale, "saved": it.out_path.is_file(), "out": str(it.out_path),
                    "revision": it.revision,
                    "counts": {str(k): v for k, v in it.result.counts().items()} if it.result is not None else None,
                } for i, it in enumerate(self.items)],
            }


def scene_views(folder: Path, *, images: str | None = None, fmt: str = "auto",
                background: tuple[float, float, float] | None = None, views: str | Path | None = None,
                name: str | None = None) -> list[tuple[str, Path]]:
    """``(view name, image file)`` of every view the pipeline reads of the scene folder ``folder``, in name order:

    - photos: the images in ``<folder>/<images>/`` (default ``images/``);
    - a dataset with cameras (COLMAP, nerfstudio, Blender, LLFF): the views its reader names, from the image folder
      ``images`` where the format has one (:func:`abcgs.sources.read.read_source`);
    - a bare splat: the views the ``reconstruct`` stage made around it, in ``views``
      (``out/<name>/colmap/images/``).

    ``fmt`` is ``data.scenes.<name>.format`` (``auto``: detected). The label maps of all of them go to
    ``<folder>/masks/<stem>.png``, at the size of these images."""
    from abcgs.sources.detect import DEFAULT_IMAGES, image_files
    from abcgs.sources.read import read_source, resolve_format
    from abcgs.sources.registry import reader_of

    folder = Path(folder)
    if not folder.exists():
        raise InputError(f"scene folder {folder} does not exist; give the folder of data.scenes.<name>.path in "
                         "params.yaml (or --scene NAME)")
    if folder.is_file() and (fmt == "auto" or reader_of(fmt).cameras == "made"):
        raise InputError(f"{folder} is a splat file: its label maps go to masks/ in the scene's folder, so give the "
                         "splat a folder of its own (data.scenes.<name>.path: that folder) and paint on that")
    resolved = resolve_format(folder, fmt, images)
    cameras = reader_of(resolved).cameras
    if cameras == "sfm":
        files = image_files(folder / (images or DEFAULT_IMAGES))
        return [(p.name, p) for p in files]
    if cameras == "made":
        run = f"dvc repro reconstruct@{name}" if name else "the reconstruct stage (dvc repro reconstruct@<name>)"
        if views is None:
            raise InputError(f"{folder} is a bare splat: its views are the ones {run} makes around it; give --scene "
                             "NAME (params.yaml) or --views out/<name>/colmap/images")
        files = image_files(views)
        if not files:
            raise InputError(f"{views} holds no views yet: run {run} first, which renders the splat's views there")
        return [(p.name, p) for p in files]
    source = read_source(folder, resolved, images=images, background=background)
    return [(v.name, v.image_path) for v in source.views]


def worst_views(masks_json: Path) -> list[str]:
    """The stems of the views a ``masks.json`` warns about (``warned_views``), most unlabelled first."""
    try:
        views = json.loads(Path(masks_json).read_text())["warned_views"]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise InputError(f"--worst-first {masks_json}: not a masks stage record with warned_views ({exc}); give "
                         "out/<scene>/masks/masks.json") from exc
    return [str(v) for v in views]
