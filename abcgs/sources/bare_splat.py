"""A scene that is only a trained splat — no photos, no cameras: cameras made around it, its renders as the photos.

    source = read_splat_source(Path("data/chair/chair.splat"), Path("out/chair/colmap/images"), SplatViewsParams())

Everything downstream then runs unchanged: the reconstruct stage writes these cameras as its COLMAP model, the fit
stage imports the same splat (which renders its own views at any PSNR threshold) and stylization sees the renders as
the content images. The points handed on are the centres of the splat's Gaussians with opacity ≥ 0.5 (at most
:data:`MAX_POINTS`, an evenly strided subset), coloured by their DC colour.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from abcgs.gaussians import render
from abcgs.io.images import save_image
from abcgs.render import sh0_to_rgb
from abcgs.sources.base import ReadOptions
from abcgs.sources.detect import splat_file
from abcgs.splats.cameras import cameras_around
from abcgs.splats.params import SplatViewsParams
from abcgs.splats.registry import read_splat
from abcgs.types import Backend, SourceScene, View

MAX_POINTS = 100_000


@torch.no_grad()
def read_splat_source(path: Path, out_images_dir: Path, params: SplatViewsParams | None = None, *,
                      fmt: str = "auto", backend: Backend = "auto",
                      background: tuple[float, float, float] | None = None, drop_invalid: bool = False) -> SourceScene:
    """Read the splat at ``path`` (``drop_invalid``: dropping its non-finite Gaussians), make ``params``' cameras around
    it, write its render from each on ``background`` (RGB in ``[0, 1]``, default black) into ``out_images_dir`` (PNG,
    named like the cameras) and return the :class:`SourceScene` (``format`` ``"splat"``, naming ``path`` as its splat). A
    ``background`` makes the splat an object on nothing (the stages give a bare splat one): every view, orbit or
    forward, frames all of it (:func:`~abcgs.splats.cameras.cameras_around`'s ``object_scene``); without one, forward
    views frame its quantiles."""
    params = params or SplatViewsParams()
    model = read_splat(path, fmt, drop_invalid=drop_invalid).model
    cams, kind = cameras_around(model, params, object_scene=background is not None)
    out_images_dir = Path(out_images_dir)
    out_images_dir.mkdir(parents=True, exist_ok=True)
    views = []
    bg = torch.tensor(background if background is not None else (0.0, 0.0, 0.0), dtype=torch.float32)
    for cam in cams:
        img, _, _ = render(model, cam, backend=backend, background=bg)
        save_image(out_images_dir / cam.name, img.clamp(0, 1).numpy())
        views.append(View(cam.name, out_images_dir / cam.name, cam))
    keep = torch.nonzero(model.opacities >= 0.5)[:, 0]
    if len(keep) > MAX_POINTS:
        keep = keep[:: -(-len(keep) // MAX_POINTS)]
    points = model.means[keep].numpy().astype(np.float32)
    colors = sh0_to_rgb(model.sh0[keep, 0, :]).clamp(0, 1).numpy().astype(np.float32)
    return SourceScene.from_views(views, points=points, colors=colors, format="splat", background=background,
                            metadata={"views_kind": kind}, splat=path)


def read(folder: Path, options: ReadOptions) -> SourceScene:
    """The ``splat`` format's reading (:mod:`abcgs.sources.formats.splat`): the splat file ``folder`` (or the one in
    it), its views rendered into ``options.work``."""
    if options.work is None:
        raise ValueError("a bare splat's views are rendered into `work`; give a folder")
    return read_splat_source(splat_file(folder), options.work, options.views, background=options.background,
                             drop_invalid=options.drop_invalid)
