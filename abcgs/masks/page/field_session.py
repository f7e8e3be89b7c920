"""The masks page's 3-D labels: with the scene's fit, every Segment cuts the view from its strokes and the labels
already in 3-D (:func:`abcgs.masks.field.cut_painted_view`), lifts the painted views' cuts and strokes onto the
Gaussians, decides the rest in 3-D (:class:`abcgs.masks.field.LabelField`) and shows every view's labels in a strip
(:class:`abcgs.masks.page.strip.Strip`), most doubtful first; a view whose strokes are cleared leaves the field.

The page's views are matched to the fit's cameras by image stem, and each must have its camera's size (the views the
fit was made from: a scene whose photos were undistorted to another size is painted one view at a time).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from abcgs.errors import InputError
from abcgs.io.images import image_header, load_image, to_uint8
from abcgs.masks.field import FieldResult, LabelField, cut_painted_view, render_field
from abcgs.masks.page.strip import Strip
from abcgs.masks.params import UNDECIDED, FieldParams, LiftParams
from abcgs.masks.regions import view_evidence
from abcgs.masks.strokes import Segmentation
from abcgs.viz import colorize_labels

log = logging.getLogger(__name__)

THUMB_PHOTO = 0.4
"""Share of the photo in a labelled pixel of a strip thumbnail (the rest: the label's colour)."""


class _Photos:
    """The views' photos ``(H, W, 3) uint8``, each read when asked for: the strip keeps only its small copies."""

    def __init__(self, paths: list[Path]) -> None:
        self.paths = paths

    def __getitem__(self, i: int) -> np.ndarray:
        return to_uint8(load_image(self.paths[i]))


@dataclass
class StripState:
    """The strip after the last Segment: each view's small label map, its doubt, the seconds from the request to the
    strip and the painted view's labels ready, and their split (``phases``: ``cut``, ``solve``, ``strip``, ``view``:
    the painted view's labels at full size; seconds)."""

    maps: list[np.ndarray]
    doubt: list[float]
    seconds: float
    phases: dict[str, float]


class FieldSession:
    """The fit behind the page: its Gaussians and cameras, the page item of each camera, the field and the strip.

    ``camera_of``: page item index → camera index (items without a camera are cut one view at a time). The field's
    neighbour graph is built here, with the strip, so that the first Segment does not wait for it."""

    def __init__(self, field: LabelField, strip: Strip, camera_of: dict[int, int]) -> None:
        self.field, self.strip, self.camera_of = field, strip, camera_of
        t0 = time.perf_counter()
        _ = field.graph  # built with the strip, not at the first Segment
        self.graph_seconds = time.perf_counter() - t0
        self.result: FieldResult | None = None
        self.state: StripState | None = None
        self._lock = threading.RLock()

    @classmethod
    def open(cls, item_paths: list[Path], ply: Path, colmap_root: Path, params: FieldParams | None = None,
             lift: LiftParams | None = None) -> FieldSession:
        """The fit ``ply`` with the cameras of the layout ``colmap_root`` (``abcgs.sfm.model.read_scene``), matched to
        the page's images ``item_paths`` by stem; the strip is recorded here (about 3 s for 97 views).

        Raises:
            InputError: no fit, no camera matches a page image, or a matched image is not its camera's size.
        """
        from abcgs.gaussians.ply import read_ply
        from abcgs.sfm.model import read_scene

        if not Path(ply).is_file():
            raise InputError(f"no fit at {ply}")
        scene = read_scene(colmap_root)
        by_stem = {Path(c.name).stem: i for i, c in enumerate(scene.cameras)}
        camera_of = {i: by_stem[Path(p).stem] for i, p in enumerate(item_paths) if Path(p).stem in by_stem}
        if not camera_of:
            raise InputError(f"no view of the page is a camera of {colmap_root}")
        for i, c in camera_of.items():
            w, h, _ = image_header(item_paths[i], "view")
            cam = scene.cameras[c]
            if (h, w) != (cam.height, cam.width):
                raise InputError(f"{Path(item_paths[i]).name} is {w}x{h} but the fit's view of it is {cam.width}x"
                                 f"{cam.height} (undistorted): paint the views one at a time")
        model = read_ply(ply)
        field = LabelField(model, scene.cameras, params or FieldParams(), lift or LiftParams())
        strip = Strip.record(model, scene.cameras, _Photos(scene.image_paths))
        session = cls(field, strip, camera_of)
        log.info("3-D labels: %d Gaussians, %d views (strip recorded in %.1f s, neighbour graph built in %.1f s)",
                 model.num_gaussians, len(scene.cameras), strip.seconds, session.graph_seconds)
        return session

    def segment(self, item: int, photo: np.ndarray, strokes: np.ndarray, started: float | None = None) -> Segmentation:
        """Segment page item ``item`` (``photo`` ``(H, W, 3) uint8``, its stroke seed map ``(H, W) int64``): while no
        label exists in 3-D, or with ``correction: cut``, cut the view seeded by its strokes and the labels in 3-D
        (:func:`cut_painted_view`); otherwise the view keeps the cut it has, if any. Over the cut lie the strokes'
        corrections (:func:`~abcgs.masks.regions.correction_regions`: with ``correction: region`` their regions in the
        photo, with ``strokes`` the strokes alone), so that a correction on a view once cut overrules the cut where it
        lies and keeps the rest. Then lift every painted view, solve and update the strip. Returns the view's labels as
        the page shows them (its evidence where it decided, the labels in 3-D refined against ``photo`` elsewhere:
        ``labels``; ``claimed``: the pixels of its evidence) and what the page saves for the ``masks`` stage to set
        the same view from (:meth:`Segmentation.saved_map`: :meth:`LabelField.saved_of`). The seconds count from
        ``started`` (``time.perf_counter()`` when the request came; default now)."""
        started = time.perf_counter() if started is None else started
        with self._lock:
            cam = self.camera_of[item]
            t0 = time.perf_counter()
            p = self.field.params
            if self.result is None or p.correction == "cut":
                cut = cut_painted_view(self.field, self.result, cam, photo, strokes, reach=p.correction_reach,
                                       min_margin=p.cut_margin)
            else:
                cut = self.field.cut_of(cam)
            cut, regions = view_evidence(cut, strokes, photo, p, self.field.depth_of(cam))
            self.field.set_view(cam, cut, strokes, regions=regions)
            self._solve(started, cut_seconds=time.perf_counter() - t0)
            t1 = time.perf_counter()
            shown = render_field(self.field, self.result, cam, photo=photo)
            self.state.phases["view"] = time.perf_counter() - t1
            self.state.seconds = time.perf_counter() - started
            saved = self.field.saved_of(cam)
            return Segmentation(shown, self.field.evidence_map(cam) >= 0, seconds=self.state.seconds,
                                saved=np.where(saved >= 0, saved, UNDECIDED))

    def forget(self, item: int) -> None:
        """Page item ``item`` has no strokes any more: its cut and strokes leave the field, and the labels and the
        strip are solved again from the other painted views (none left: back to the unlabelled strip)."""
        with self._lock:
            started = time.perf_counter()
            cam = self.camera_of[item]
            if cam not in self.field.painted:
                return
            self.field.set_view(cam, None, None)
            if self.field.painted:
                self._solve(started)
            else:
                self.result, self.state = None, None

    def set_evidence(self, item: int, cut: np.ndarray, strokes: np.ndarray | None) -> None:
        """Page item ``item``'s evidence is ``cut`` ``(H, W) int64`` (0..L, :data:`NO_VOTE` undecided), a label map made
        elsewhere (a benchmark's ideal part mask, say), with its ``strokes``; the labels and the strip are solved
        again."""
        with self._lock:
            started = time.perf_counter()
            self.field.set_view(self.camera_of[item], cut, strokes)
            self._solve(started)

    def _solve(self, started: float, cut_seconds: float = 0.0) -> None:
        t0 = time.perf_counter()
        before = self.result
        self.result = self.field.solve()
        t1 = time.perf_counter()
        kept = {}
        if before is not None and self.state is not None and before.n_labels == self.result.n_labels:
            changed = (before.labels != self.result.labels) | (before.decided != self.result.decided)
            kept = {"previous": self.state.maps, "changed": changed}
        maps = self.strip.labels(self.result.labels, self.result.decided, self.result.n_labels, **kept)
        doubt = self.strip.doubt(maps)
        t2 = time.perf_counter()
        self.state = StripState(maps, doubt, t2 - started, {"cut": cut_seconds, "solve": t1 - t0, "strip": t2 - t1})

    def listing(self, names: list[str]) -> dict:
        """The strip for the page (``names``: the page items' names): its views, most doubtful first, each with
        ``index`` (the page item; None: a view of the fit the page does not show), ``camera`` (its index in the
        strip: ``/api/strip/<camera>.png``), ``name``, ``doubt`` and whether it is ``painted``; ``seconds``, from
        the last Segment's request to the strip ready, and ``counts``, how many Gaussians each step decided (None
        before the first Segment)."""
        with self._lock:
            item_of = {c: i for i, c in self.camera_of.items()}
            cams = self.field.cameras
            doubt = self.state.doubt if self.state else [0.0] * len(cams)
            painted = set(self.field.painted)
            views = [{"index": item_of.get(c), "camera": c,
                      "name": names[item_of[c]] if c in item_of else cams[c].name,
                      "doubt": round(float(doubt[c]), 4), "painted": c in painted}
                     for c in range(len(cams))]
            views.sort(key=lambda v: -v["doubt"])
            return {"views": views, "labelled": self.state is not None,
                    "seconds": None if self.state is None else round(self.state.seconds, 3),
                    "counts": None if self.result is None else self.result.counts()}

    def thumbnail(self, camera: int) -> np.ndarray:
        """Camera ``camera``'s strip picture ``(h, w, 3) uint8``: its photo, where a label is shown
        ``THUMB_PHOTO`` of it and the rest the label's colour (:func:`abcgs.viz.colorize_labels`, the page's palette),
        white where undecided (the photo alone before the first Segment)."""
        with self._lock:
            if not 0 <= camera < len(self.strip.views):
                raise InputError(f"no view {camera} in the strip; it has {len(self.strip.views)}")
            photo = self.strip.photos[camera].astype(np.float32)
            if self.state is None:
                return photo.astype(np.uint8)
            lab = self.state.maps[camera]
            undecided = lab == UNDECIDED
            colour = colorize_labels(np.where(undecided, 0, lab)).astype(np.float32)
            out = np.where(((lab > 0) & ~undecided)[..., None], THUMB_PHOTO * photo + (1 - THUMB_PHOTO) * colour, photo)
            out[undecided] = 255.0
            return np.rint(out).astype(np.uint8)
