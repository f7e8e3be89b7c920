"""The ``preflight`` stage's check of scenes that come with cameras: each is read by its reader (files present,
images matching cameras, camera and image sizes a consistent scale, cameras that look at the scene, label maps in
``masks/`` at their views' size or its scale) before any stage runs. Scenes whose cameras structure from motion finds
(photos) are checked by :func:`abcgs.preflight.check_input_files`; those whose cameras a reader makes (bare splats) by
the stage that reads them. A trained splat an entry names (``splat:``) is read by its reader too, its values checked and,
with a dataset's cameras, its frame (:func:`abcgs.splats.registry.check_splat_file`).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from abcgs.errors import InputError
from abcgs.preflight import check_label_map_sizes, produced_by_stage
from abcgs.sources.read import read_entry, resolve_format
from abcgs.sources.registry import reader_of
from abcgs.splats.registry import check_splat_file


def check_scene_sources(params, root: Path, produced: Iterable[str] = ()) -> list[str]:
    """Read every ``data.scenes`` entry that is a dataset with cameras; raise :class:`InputError` prefixed with the
    scene's key on the first problem, return the readers' notes as warnings."""
    produced = list(produced)
    warnings = []
    for name, scene in params.data.scenes.items():
        if produced_by_stage(Path(scene.path), produced, root):
            continue
        folder = root / scene.path
        source = None
        try:
            fmt = resolve_format(folder, scene.format, scene.images)
            if reader_of(fmt).check:  # not cameras found from photos or made around a splat: read them now
                source = read_entry(scene, folder, fmt)
                check_label_map_sizes(name, folder / "masks", {Path(v.name).stem: (
                    v.name, (v.camera.height, v.camera.width)) for v in source.views}, scene.images)
            if scene.splat is not None:  # the trained splat the fit stage imports, by its reader's checks
                check_splat_file(scene.splat_path(folder), scene.splat_format, scene=source,
                                 drop_invalid=scene.splat_nonfinite == "drop")
        except InputError as exc:
            raise InputError(f"data.scenes.{name}: {exc}") from None
        warnings += [f"data.scenes.{name}: {note}" for note in (source.notes if source is not None else ())]
    return warnings
