"""Which reader a scene folder needs, from the files it holds (no file is decoded): the first reader of
:mod:`abcgs.sources.registry`, in priority order, whose ``detect`` takes the folder. The built-in formats
(:mod:`abcgs.sources.formats`):

=================================================  ==============
the folder holds                                   format
=================================================  ==============
``transforms_train.json``                          ``blender``
``transforms.json``                                ``nerfstudio``
``sparse/0/cameras.{bin,txt}`` or ``sparse/…``     ``colmap``
``poses_bounds.npy`` (and no COLMAP model)         ``llff``
an image folder (``images/``)                      ``photos``
only a splat file (and ``masks/``)                 ``splat``
=================================================  ==============

An LLFF release that ships its COLMAP model beside ``poses_bounds.npy`` is read as ``colmap`` (the model carries
the sparse points and the exact intrinsics that the poses were made from); ``format: llff`` in the scene's
params entry reads the poses instead. A path to a splat file itself is a ``splat`` scene. A splat file is
``.ply .splat .spz .pt``; ``masks/`` beside it holds label maps of its generated views.

This module and the registry import only light modules: :mod:`abcgs.preflight` (imported by every stage) uses it.
"""

from __future__ import annotations

import os
from pathlib import Path

from abcgs.errors import InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
SPLAT_SUFFIXES = (".ply", ".splat", ".spz", ".pt")
DEFAULT_IMAGES = "images"


def colmap_model_dir(folder: str | os.PathLike) -> Path | None:
    """The COLMAP model folder of a scene: ``sparse/0`` when it holds a model, else ``sparse`` (``None`` if neither
    has ``cameras.bin`` or ``cameras.txt``)."""
    folder = Path(folder)
    for cand in (folder / "sparse" / "0", folder / "sparse"):
        if present(cand / "cameras.bin") or present(cand / "cameras.txt"):
            return cand
    return None


def present(path: Path) -> bool:
    """Whether a scene's marker file is there at all, even as something its reader refuses (a FIFO, a link to
    ``/dev/zero``, a symlink loop): the reader then says what is wrong with it, instead of the scene being taken for
    another format."""
    return os.path.lexists(path)


def image_files(folder: str | os.PathLike) -> list[Path]:
    """Sorted image files directly inside ``folder`` (none when it is not a folder)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))


def _splat_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in SPLAT_SUFFIXES)


def _subfolders(folder: Path) -> list[Path]:
    """The folders in ``folder`` other than ``masks/`` (a bare splat's label maps): a folder with a splat and no other
    folder is a bare splat scene."""
    return [p for p in folder.iterdir() if p.is_dir() and p.name != "masks"]


def is_bare_splat(folder: Path) -> bool:
    """Whether ``folder`` is a bare splat scene: a splat file, or a folder holding one and no folder but ``masks/``."""
    if folder.is_file():
        return folder.suffix.lower() in SPLAT_SUFFIXES
    return folder.is_dir() and bool(_splat_files(folder)) and not _subfolders(folder)


def splat_file(folder: str | os.PathLike) -> Path:
    """The splat of a bare-splat scene: ``folder`` itself when it is a splat file, else the one splat file it holds."""
    folder = Path(folder)
    if folder.is_file():
        return folder
    files = _splat_files(folder) if folder.is_dir() else []
    if len(files) != 1:
        raise InputError(f"{folder} holds {len(files)} splat files ({', '.join(SPLAT_SUFFIXES)}); a bare-splat scene is "
                         "one splat file, or a folder with exactly one")
    return files[0]


def detect_format(folder: str | os.PathLike, images: str | None = None) -> str:
    """The format of the scene at ``folder`` (module docstring); ``images`` is the image subfolder the scene's
    params name (default ``images/``). Raises :class:`InputError` naming the folder and what it looked for when no
    format fits (a missing or empty folder, a model without images, …)."""
    from abcgs.sources.registry import registered

    folder = Path(folder)
    if not folder.is_file() and not folder.is_dir():
        raise InputError(f"{folder} does not exist; give the scene's folder (absolute paths: DVC experiments run in a "
                         "copy of the repository)")
    for name, reader in registered().items():
        if reader.detects(folder, images):
            return name
    if folder.is_file():
        raise InputError(f"{folder} is a file, not a scene folder; give the folder that holds images/ (or a "
                         f"splat file: {', '.join(SPLAT_SUFFIXES)})")
    sub = images or DEFAULT_IMAGES
    entries = sorted(p.name + ("/" if p.is_dir() else "") for p in folder.iterdir() if not p.name.startswith("."))
    held = f"it holds {', '.join(entries[:8])}{' …' if len(entries) > 8 else ''}" if entries else "it is empty"
    if (folder / "sparse").is_dir():
        hint = (f"{folder / 'sparse'} has no cameras.bin/cameras.txt (nor sparse/0/): copy the COLMAP model there")
    elif (folder / sub).is_dir():
        hint = f"{folder / sub} holds no images ({', '.join(IMAGE_SUFFIXES)}): put the photos there"
    else:
        hint = (f"put the photos in {folder / sub}/, or give a dataset with its cameras (sparse/0/ COLMAP model, "
                "transforms.json, transforms_train.json, poses_bounds.npy), or a splat file")
    raise InputError(f"{folder}: no scene found ({held}); {hint}")
