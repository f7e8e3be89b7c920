"""Stage ``fit``: baseline 3DGS (Kerbl et al. 2023) from a COLMAP reconstruction, or the import of the trained splat
the scene names (``data.scenes.<scene>.splat``: checked against the photos, docs/SPLATS.md).

    python stages/fit.py --scene tiny --colmap out/tiny/colmap --out out/tiny/gs --headline out/tiny/fit_metrics.json

Writes ``point_cloud.ply``, ``metrics.json`` (the full record: per-view scores, evaluation history),
``history.csv``, ``heldout_grid.png`` and ``splat_source.json`` (what the export stage gives the scene back as) into
``--out``, and the scene's headline numbers (the DVC metric) to ``--headline``. Options: the ``fit`` section with
``data.scenes.<scene>.fit`` merged in.
"""

from __future__ import annotations

import sys
from pathlib import Path

from abcgs.fit.outputs import fit_and_save
from abcgs.io.metrics import fit_headline, write_headline
from abcgs.pipeline import StageSpec, run_stage, stage_parser
from abcgs.runtime import resolve_device
from abcgs.sfm.model import read_colmap_scene
from abcgs.sources.detect import bare_splat
from abcgs.splats.importing import import_and_save, write_fitted_source

SPEC = StageSpec("fit", foreach="data.scenes", params=("fit", "data.scenes.{key}", "runtime"))


def main(args, params) -> None:
    scene = read_colmap_scene(args.colmap / "sparse", args.colmap / "images")
    fit = params.scene_section(args.scene, "fit")
    spec = params.data.scenes[args.scene]
    device = resolve_device(params.runtime.device)
    splat = spec.splat_path() or bare_splat(spec.path, spec.format)  # a bare splat: its renders are the photos
    if splat is not None:
        record = import_and_save(scene, splat, spec.splat_format, fit, args.out, device=device)
    else:
        record = fit_and_save(scene, fit, args.out, device=device).metrics()
        write_fitted_source(args.out)
    write_headline(args.headline, fit_headline(record))


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--colmap", type=Path, required=True, help="reconstruct stage output (sparse/ + images/)")
    ap.add_argument("--out", type=Path, required=True, help="output folder for point_cloud.ply, metrics, plots")
    ap.add_argument("--headline", type=Path, required=True, help="headline metrics JSON (the DVC metric)")
    sys.exit(run_stage(SPEC, ap, main))
