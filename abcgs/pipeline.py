"""Shared plumbing of the DVC stage scripts in ``stages/``: argument parsing, params, logging, errors.

A stage script is a short ``main(args, params)`` that calls the library; :func:`run_stage` validates the
whole ``params.yaml`` first (so a typo fails before any work), then runs :func:`abcgs.preflight.preflight`
(every key ``dvc.yaml`` tracks is in the file; style files and scene folders exist and decode), sets up
logging, and turns an
:class:`abcgs.errors.AbcgsError` into a one-paragraph message and exit status 2 instead of a traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections.abc import Callable
from pathlib import Path

from abcgs.errors import AbcgsError
from abcgs.params import Params, read_params_file, validate_params
from abcgs.preflight import preflight

log = logging.getLogger("abcgs")


def stage_parser(description: str) -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--params", type=Path, default=Path("params.yaml"), help="the pipeline's params file")
    return ap


def run_stage(
    name: str, parser: argparse.ArgumentParser, main: Callable[[argparse.Namespace, Params], None], argv=None
) -> int:
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", datefmt="%H:%M:%S")
    t0 = time.perf_counter()
    try:
        raw = read_params_file(args.params)
        params = validate_params(raw, str(args.params))
        preflight(params, raw, args.params)
        main(args, params)
    except AbcgsError as exc:
        print(f"\n[{name}] error: {exc}", file=sys.stderr)
        return 2
    log.info("[%s] done in %.1f s", name, time.perf_counter() - t0)
    return 0
