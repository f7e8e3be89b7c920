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
from abcgs.report import collect_warnings, load_runs, report_siblings, write_report
from abcgs.view.outputs import load_experiment
from abcgs.view.page import viewer_fragment

_HTML = Path("reports/report.html")
SPEC = StageSpec("report", params=("experiments", "colormatches", "data.styles", "viewer"), outs=(
    Out(_HTML, "out", help="the self-contained page"),
    *(Out(p) for p in report_siblings(_HTML)),
))


def reads(params) -> list[str]:
    """The outputs this stage reads for the experiments and paintings of ``params`` (validated ``params.yaml``),
    named one by one: its ``dvc.yaml`` deps besides the preflight stamp (:mod:`abcgs.dag` lists them)."""
    paths: list[Path] = [layout.PREFLIGHT_REPORT]
    paths += [Path(p) for p in layout.styles().paintings(params.data.styles).values()]
    scenes = []
    for name, exp in params.experiments.items():
        d = layout.experiment(name)
        paths += [d.stylize_record, d.eval_record, d.eval_consistency, d.stylize.root]
        if exp.scene not in scenes:
            scenes.append(exp.scene)
    for scene in scenes:  # the photos and cameras, the viewer's original splat and labels, the run's warnings
        s = layout.scene(scene)
        paths += [s.colmap.root, s.reconstruct_record, s.fit.ply, s.masks.root]
    return [p.as_posix() for p in paths]


def main(args, params) -> None:
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
