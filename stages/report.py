"""Stage ``report``: one self-contained HTML page, a PNG summary, the results table (markdown) and a comparison
figure across all experiments.

    dvc repro report     # its command, with every input and output path: dvc.yaml or --help
"""

from __future__ import annotations

import sys
from pathlib import Path

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

from abcgs import layout
from abcgs.pipeline import Out, StageSpec, run_stage, stage_parser
from abcgs.preflight import check_report_inputs
from abcgs.report import collect_warnings, load_runs, report_siblings, write_report
from abcgs.view.outputs import load_experiment
from abcgs.view.page import viewer_fragment

_HTML = Path("reports/report.html")
SPEC = StageSpec("report", params=("experiments", "colormatches", "data.styles", "viewer"), outs=(
    Out(_HTML, "out", help="the self-contained page"),
    *(Out(p) for p in report_siblings(_HTML)),
))


def reads(params) -> list[str]:
    """The outputs this stage reads for ``params`` (:func:`abcgs.layout.report_inputs`; :mod:`abcgs.dag` lists them
    as its ``dvc.yaml`` deps)."""
    return layout.report_inputs(params)


def main(args, params) -> None:
    # an experiment added to params.yaml since dvc.yaml was generated: this stage would not depend on its outputs
    check_report_inputs(params, Path("dvc.yaml"))
    runs = load_runs(args.root, params.experiment_specs())
    viewer = None
    if params.viewer.enabled:
        exps = [load_experiment(layout.experiment(name, args.root).root, scene=exp.scene, root=args.root,
                                max_gaussians=params.viewer.max_gaussians, path_kind=params.viewer.camera_path,
                                path_frames=params.viewer.path_frames)
                for name, exp in params.experiments.items()]
        viewer = viewer_fragment(exps, max_width=params.viewer.max_width)
    scenes = sorted({exp.scene for exp in params.experiments.values()})
    paintings = layout.styles(args.root).paintings(params.data.styles)
    write_report(args.out, runs, args.root, paintings, viewer, collect_warnings(args.root, scenes))


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--root", type=Path, default=layout.OUT, help="the folder the stages write (out)")
    sys.exit(run_stage(SPEC, ap, main))
