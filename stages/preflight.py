"""Stage ``preflight``: every check that needs no stage's output, before any stage runs or loses its outputs.

    dvc repro preflight     # its command, with every input and output path: dvc.yaml or --help

It validates the whole params file (schema, names, references between sections; every other stage validates only
the sections it reads) and checks it against ``dvc.yaml`` (every tracked key present); then it checks the inputs
(:func:`abcgs.preflight.check_input_files`: scene folders, views, masks, paintings, weights, and the labels
the colour matches bind where the label maps are given files; :func:`abcgs.source_check.check_scene_sources`:
datasets with cameras read by their readers). Every other stage
depends on its stamp, so ``dvc repro`` stops here, with the key named, before DVC deletes any stage's outputs. The
stamp's content does not depend on the params, so a passing preflight re-runs nothing downstream; the warnings are
printed (``dvc repro`` shows them) and go to ``--record``, which the report shows. For each scene it also writes
whether a colour match reads its content labels (``--label-use``, :func:`abcgs.layout.label_use`): the scene's
``masks`` stage depends on that file, which changes only when the answer does.
"""

from __future__ import annotations

import sys

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.features.params import content_label_readers
from abcgs.io.atomic import atomic_path, write_json
from abcgs.params import validate_params
from abcgs.pipeline import Dep, Out, StageSpec, run_stage, stage_parser
from abcgs.preflight import check_input_files, dvc_output_files, dvc_outputs, preflight
from abcgs.sections import read_params_file
from abcgs.source_check import check_scene_sources

SPEC = StageSpec("preflight", deps=(Dep("params", "params.yaml", "the pipeline's params file"),), outs=(
    Out(layout.PREFLIGHT_STAMP, "out", help="the stamp every other stage depends on"),
    Out(layout.PREFLIGHT_REPORT, "record", help="the warnings (JSON)"),
    Out(layout.LABEL_USE, "label-use", help="per scene, whether a colour match reads its content labels (JSON)"),
))


def main(args, _sections) -> None:
    raw = read_params_file(args.params)
    params = validate_params(raw, str(args.params))  # the whole file, which this stage depends on
    preflight(params, raw, args.params, files=False)
    root = args.params.resolve().parent
    dvc_yaml = root / "dvc.yaml"
    known = dvc_yaml.is_file()
    produced = dvc_outputs(dvc_yaml) if known else []
    warnings = (check_input_files(params, root, produced, dvc_output_files(dvc_yaml) if known else {})
                + check_scene_sources(params, root, produced))
    for w in warnings:  # on the terminal of `dvc repro`, and in the record the report shows
        print(f"[preflight] warning: {w}", file=sys.stderr, flush=True)
    write_json(args.record, {"warnings": warnings})
    write_label_use(args.label_use, params)
    write_json(args.out, {"checks": "passed"})


def write_label_use(folder, params) -> None:
    """The folder ``--label-use`` (atomically): per scene, whether a colour match reads its content labels."""
    with atomic_path(folder, is_dir=True) as tmp:
        for scene in params.data.scenes:
            write_json(tmp / layout.label_use(scene).name,
                       {"content_labels_read": bool(content_label_readers(params.colormatches, scene))})


if __name__ == "__main__":
    sys.exit(run_stage(SPEC, stage_parser(SPEC, __doc__.strip().splitlines()[0]), main))
