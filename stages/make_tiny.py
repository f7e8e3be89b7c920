"""Stage ``make_tiny``: generate the embedded default scene (views, label maps, cameras, paintings).

    python stages/make_tiny.py --out data/tiny

Deterministic for a seed; options: the ``tiny`` section of params.yaml
(:class:`abcgs.scene.synthetic.TinySceneParams`).
"""

from __future__ import annotations

import sys
from pathlib import Path

from abcgs.pipeline import StageSpec, run_stage, stage_parser
from abcgs.scene.synthetic import make_tiny_scene

SPEC = StageSpec("make_tiny", params=("tiny",))


def main(args, params) -> None:
    make_tiny_scene(args.out, params.tiny)


if __name__ == "__main__":
    ap = stage_parser(SPEC, __doc__.strip().splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("data/tiny"), help="output scene folder")
    sys.exit(run_stage(SPEC, ap, main))
