"""One way in for a scene: a ``data.scenes`` entry turned into the layout every later stage reads.

    report = reconstruct_scene(params.data.scenes["fern"], "out/fern/colmap", params.scene_section("fern", "reconstruct"))
    report.metrics()      # the reconstruct stage's record

The entry's format (named, or detected) picks the route. A format whose cameras are found from its photos (``photos``:
the reader's ``reconstruct``, structure from motion) writes the layout itself; every other format is read by its
reader with the entry's options (:func:`abcgs.sources.read.read_entry`, the half the checks before any stage use) and
written by :func:`abcgs.sources.model.write_source_model`. Either way ``out`` holds the undistorted model
(``sparse/``), the images, the label maps and ``scene.json`` (format, frame, background, the splat the entry names).
The ``reconstruct`` stage, ``add-scene`` and the benchmarks that need a scene's layout call this function.
"""

from __future__ import annotations

import logging
import os
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Protocol

from abcgs.sfm.params import ReconstructParams
from abcgs.sources.params import SceneParams
from abcgs.sources.read import loaded, read_entry, resolve_format
from abcgs.sources.registry import reader_of

log = logging.getLogger(__name__)


class SceneReport(Protocol):
    """What writing a scene's layout did: :class:`abcgs.sfm.colmap.ReconstructionReport` (structure from motion) or
    :class:`abcgs.sources.model.SourceReport` (a dataset's own cameras)."""

    def metrics(self, *, seconds: bool = True) -> dict: ...

    def summary(self) -> str: ...


def reconstruct_scene(entry: SceneParams | str | os.PathLike, out: str | os.PathLike,
                      options: ReconstructParams | None = None, *, folder: str | os.PathLike | None = None
                      ) -> SceneReport:
    """Write the layout of the scene ``entry`` (a ``data.scenes`` entry, or a folder: its format detected) to
    ``out`` with the ``reconstruct`` section ``options`` (default: the defaults); ``folder``: the entry's folder as
    this process sees it (default ``entry.path``). Raises :class:`~abcgs.errors.InputError` for what the format's
    reader refuses."""
    entry = entry if isinstance(entry, SceneParams) else SceneParams(path=str(entry))
    options = options if options is not None else ReconstructParams()
    folder = Path(entry.path if folder is None else folder)
    fmt = resolve_format(folder, entry.format, entry.images)
    reader, background, splat = reader_of(fmt), entry.resolved_background(fmt), entry.splat_path(folder)
    if reader.reconstruct is not None:  # cameras found from the photos (structure from motion), not read
        report = loaded(reader.reconstruct)(folder, out, options, images=entry.images, background=background,
                                            splat=splat)
    else:
        from abcgs.sources.model import write_source_model  # pycolmap: only where a layout is written

        with tempfile.TemporaryDirectory() as work:  # a bare splat's renders, until the model's images/ holds them
            source = read_entry(entry, folder, fmt, work=work)
            for note in source.notes:
                log.info("%s: %s", fmt, note)
            source = replace(source, splat=splat or source.splat)
            report = write_source_model(source, out, options, masks_dir=folder / "masks", background=background)
    log.info("%s: %s", fmt, report.summary())
    return report
