"""Stage ``fit``: baseline 3DGS (Kerbl et al. 2023) from a COLMAP reconstruction, or the import of the trained splat
the scene names (``data.scenes.<scene>.splat``, or a bare splat: checked against the photos, docs/SPLATS.md), as
the ``reconstruct`` stage recorded it in the scene (:func:`abcgs.sfm.model.read_scene`).

    dvc repro fit@tiny     # its command, with every input and output path: dvc.yaml or --help

Writes ``point_cloud.ply``, ``metrics.json`` (the full record: per-view scores, evaluation history),
``history.csv``, ``heldout_grid.png`` and ``splat_source.json`` (what the export stage gives the scene back as) into
``--out``, and the scene's headline numbers (the DVC metric) to ``--headline``. Options: the ``fit`` section with
``data.scenes.<scene>.fit`` merged in.
"""

from __future__ import annotations

import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.fit.outputs import fit_and_save
from abcgs.io.metrics import fit_headline, write_headline
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser
from abcgs.runtime import resolve_device
from abcgs.sfm.model import read_scene
from abcgs.splats.importing import import_and_save, write_fitted_source

_S = layout.scene("{key}")
SPEC = StageSpec("fit", foreach="data.scenes", params=("fit", "data.scenes.{key}", "runtime"), deps=(
    Dep("colmap", _S.colmap.root, "the scene's COLMAP layout (reconstruct)"),
    Dep("source", "{item.path}", "the scene's folder (a splat it names is imported instead of a fit)"),
), outs=(
    Out(_S.fit.root, "out", kind="folder", help="the folder of the files below"),
    Out(_S.fit.ply), Out(_S.fit.heldout_grid), Out(_S.fit.record), Out(_S.fit.splat_source),
    Out(_S.fit_headline, "headline", kind="metric", help="the scene's headline metrics (the DVC metric)"),
    Out(_S.fit.history, kind="plot", plot_axes=("step", "psnr")),
))


def main(args, params) -> None:
    scene = read_scene(args.colmap)
    fit = params.scene_section(args.scene, "fit")
    background = scene.background
    if background.object:  # an object on nothing: fitted, checked and evaluated on its own background
        fit = fit.model_copy(update={"background": background.color})
    spec = params.data.scenes[args.scene]
    device = resolve_device(params.runtime.device)
    if scene.splat is not None:  # the splat the scene names (a bare splat: its renders are the photos)
        splat = spec.recorded_splat(scene.splat, args.source)
        record = import_and_save(scene, splat, spec.splat_format, fit, args.out, device=device,
                                 drop_invalid=spec.splat_nonfinite == "drop")
    else:
        record = fit_and_save(scene, fit, args.out, device=device).metrics()
        write_fitted_source(args.out)
    write_headline(args.headline, fit_headline(record))


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
