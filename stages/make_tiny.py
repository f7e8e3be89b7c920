"""Stage ``make_tiny``: write the embedded synthetic default scene.

Usage: ``python stages/make_tiny.py --out data/tiny [--seed 0] [--params params.yaml]``
(``--params`` takes the ``tiny:`` section, :class:`abcgs.scene.synthetic.TinySceneParams`, after
validating the whole file; ``--seed`` overrides its seed). The folder is written atomically.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make the repository importable without installing it
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abcgs.errors import AbcgsError
from abcgs.scene.synthetic import TinySceneParams, make_tiny_scene

log = logging.getLogger("make_tiny")


def load_tiny_params(path: Path | None, seed: int | None) -> TinySceneParams:
    """``TinySceneParams`` from ``path``'s ``tiny:`` section (defaults without a file), ``seed`` overriding."""
    params = TinySceneParams()
    if path is not None:
        from abcgs.params import load_params  # imports every stage's schema; only needed with --params

        params = load_params(path).tiny
    return params if seed is None else params.model_copy(update={"seed": seed})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("data/tiny"), help="output scene folder")
    ap.add_argument("--seed", type=int, default=None, help="random seed (default: params, else 0)")
    ap.add_argument("--params", type=Path, default=None, help="params.yaml with a tiny: section")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    try:
        params = load_tiny_params(args.params, args.seed)
    except AbcgsError as e:
        log.error("%s", e)
        return 1
    t0 = time.perf_counter()
    make_tiny_scene(args.out, params)
    log.info("wrote %d views + styles to %s in %.1f s", params.n_views, args.out, time.perf_counter() - t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
