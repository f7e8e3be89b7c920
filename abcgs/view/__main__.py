"""Look at one experiment in 3-D without the report:

    python -m abcgs.view out/tiny_single            # writes reports/viewers/tiny_single.html and opens it
    python -m abcgs.view out/tiny_single --no-open --max-gaussians 20000

The page is self-contained (viewer bundle and splats inline) and works from file:// with no network. It is written
outside ``out/`` (which the report stage depends on), so looking at a scene never makes the pipeline out of date.
"""

from __future__ import annotations

import argparse
import os
import sys
import webbrowser
from pathlib import Path

from abcgs.errors import AbcgsError, InputError
from abcgs.io.atomic import write_text
from abcgs.sections import read_params_file
from abcgs.view.outputs import experiment_scene, load_experiment
from abcgs.view.page import viewer_page


def positive_int(text: str) -> int:
    """An ``argparse`` type: an integer of at least 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} is not at least 1")
    return value


def check_page_path(out: Path, option: str) -> None:
    """``out`` can become the page: not a folder, and its folder is (or can be made) writable."""
    if out.is_dir():
        raise InputError(f"{option} {out} is a folder; give the page's file name, e.g. {out / 'viewer.html'}")
    parent = next((p for p in (out.parent, *out.parent.parents) if p.exists()), Path("."))
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{option} {out}: {parent} is not a folder you can write; give a path you can write")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m abcgs.view", description=__doc__.strip().splitlines()[0])
    ap.add_argument("run_dir", type=Path, help="an experiment's output folder, e.g. out/tiny_single")
    ap.add_argument("--scene", help="scene key (default: from --params, else the only fitted scene beside it)")
    ap.add_argument("--params", type=Path, default=None,
                    help="the params file naming the experiment's scene (default: params.yaml, when there is one)")
    ap.add_argument("--max-gaussians", type=positive_int, default=150_000,
                    help="Gaussians per layer on the page, at least 1 (larger scenes keep their most visible ones)")
    ap.add_argument("--out", type=Path, help="page to write (default: reports/viewers/<experiment>.html)")
    ap.add_argument("--no-open", action="store_true", help="only write the page")
    args = ap.parse_args(argv)
    out = args.out or Path("reports") / "viewers" / f"{args.run_dir.resolve().name}.html"
    try:
        check_page_path(out, "--out" if args.out else "the page")
        scene = args.scene
        if args.params is not None and not args.params.is_file():
            raise InputError(f"--params {args.params} does not exist; give the params file the experiment ran with, "
                             "or leave --params out (params.yaml where there is one)")
        params = args.params or Path("params.yaml")
        if scene is None:
            experiments = read_params_file(params).get("experiments") if params.is_file() else None
            scene = experiment_scene(args.run_dir, experiments)
        exp = load_experiment(args.run_dir, scene=scene, max_gaussians=args.max_gaussians)
        write_text(out, viewer_page([exp], title=f"abcgs: {exp.name}"))
    except AbcgsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"error: cannot write {out}: {exc.strerror or exc}; give --out a file in a folder you can write",
              file=sys.stderr)
        return 2
    size = out.stat().st_size / 1e6
    print(f"wrote {out} ({size:.1f} MB; {exp.layers['stylized'].num_gaussians} of {exp.n_gaussians_full} Gaussians "
          f"per layer; layers: {', '.join(exp.layers)})")
    for note in exp.notes:
        print(f"note: {note}")
    if not args.no_open:
        webbrowser.open(out.resolve().as_uri())
    return 0


if __name__ == "__main__":
    from abcgs.runtime import setup

    setup()  # the process settings (abcgs.runtime.setup): the wait policy only where torch is not loaded yet
    sys.exit(main())
