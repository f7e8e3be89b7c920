"""Stage ``report``: one self-contained HTML page and a PNG summary across all experiments.

    python stages/report.py --out out/report.html
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abcgs.io.atomic import write_text  # noqa: E402
from abcgs.pipeline import run_stage, stage_parser  # noqa: E402
from abcgs.view import viewer_fragment  # noqa: E402
from abcgs.view.outputs import load_experiment  # noqa: E402
from eval.report import load_runs, render_html, summary_png  # noqa: E402


def main(args, params) -> None:
    runs = load_runs(args.root, params.experiment_specs())
    viewer = None
    if params.viewer.enabled:
        exps = [load_experiment(args.root / name, scene=exp.scene, root=args.root,
                                max_gaussians=params.viewer.max_gaussians, path_kind=params.viewer.camera_path,
                                path_frames=params.viewer.path_frames)
                for name, exp in params.experiments.items()]
        viewer = viewer_fragment(exps, max_width=params.viewer.max_width)
    write_text(args.out, render_html(runs, viewer=viewer))
    summary_png(runs, args.out.with_suffix(".png"))


if __name__ == "__main__":
    ap = stage_parser(__doc__.strip().splitlines()[0])
    ap.add_argument("--root", type=Path, default=Path("out"))
    ap.add_argument("--out", type=Path, required=True)
    sys.exit(run_stage("report", ap, main))
