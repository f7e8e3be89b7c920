"""The masks page's command line: ``python -m abcgs.masks.page`` (its uses: :mod:`abcgs.masks.page`)."""

from __future__ import annotations

import argparse
import logging
import sys
import webbrowser
from pathlib import Path

import abcgs.masks.page as page
from abcgs.errors import AbcgsError, InputError
from abcgs.masks.page.server import make_server, page_url
from abcgs.masks.page.session import PaintSession, worst_views


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m abcgs.masks.page", description=page.__doc__.strip().splitlines()[0],
                                 epilog="Views: the ones the pipeline reads (photos in <scene>/<images>/, a dataset's "
                                        "views, a bare splat's out/<name>/colmap/images/); masks: "
                                        "<scene>/masks/<stem>.png (0 = no label, 1, 2, …, 255 = undecided). "
                                        "Then `dvc repro` re-runs the masks stage and what follows.")
    ap.add_argument("scene", nargs="?", type=Path, help="scene folder (photos or a dataset); not needed with --scene "
                                                        "or --painting")
    ap.add_argument("--scene", dest="scene_name", metavar="NAME",
                    help="the scene data.scenes.NAME of --params: its folder, format and images (a bare splat: the "
                         "views the reconstruct stage made, out/NAME/colmap/images/)")
    ap.add_argument("--params", type=Path, default=Path("params.yaml"), help="the params file of --scene")
    ap.add_argument("--images", help="the scene's image subfolder, as data.scenes.<name>.images (e.g. images_4)")
    ap.add_argument("--format", default="auto", help="the scene's format, as data.scenes.<name>.format")
    ap.add_argument("--views", type=Path, help="a bare splat scene: the folder of its views (out/<name>/colmap/images)")
    ap.add_argument("--painting", type=Path, help="segment this painting into regions instead of a scene's views")
    ap.add_argument("--labels-out", type=Path, help="the painting's label PNG (default: <painting>_labels.png beside it)")
    ap.add_argument("--port", type=int, default=0, help="port on 127.0.0.1 (0: any free port)")
    ap.add_argument("--no-open", action="store_true", help="print the address; do not open a browser")
    ap.add_argument("--iterations", type=int, default=5, help="GrabCut iterations per label")
    ap.add_argument("--max-side", type=int, default=1024, help="cut larger images at this size (longest side)")
    ap.add_argument("--no-fill", action="store_true", help="leave gaps between the cuts unassigned (the page can switch)")
    ap.add_argument("--fit", type=Path, help="a scene folder: the fit (point_cloud.ply) whose labels every view "
                                             "shows after each Segment (with --colmap); --scene NAME finds its own")
    ap.add_argument("--colmap", type=Path, help="the fit's layout (out/<name>/colmap): its cameras")
    ap.add_argument("--one-view", action="store_true", help="cut one view at a time even where a fit exists")
    ap.add_argument("--worst-first", type=Path, metavar="MASKS_JSON",
                    help="the masks stage's masks.json (out/<scene>/masks/masks.json): open the views it warns about "
                         "first, most unlabelled first")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        kw = {"iterations": args.iterations, "max_side": args.max_side, "fill": not args.no_fill}
        if args.painting is not None:
            if args.scene is not None:
                print(f"--painting given: showing {args.painting}; the scene folder {args.scene} is not used")
            session = PaintSession.for_painting(args.painting, args.labels_out, **kw)
        elif args.scene is not None or args.scene_name is not None:
            if args.labels_out is not None:
                raise InputError("--labels-out is for --painting; a scene's masks go to <scene>/masks/")
            kw["first"] = worst_views(args.worst_first) if args.worst_first else ()
            if args.scene_name is not None:
                if args.scene is not None or args.images or args.views or args.format != "auto":
                    raise InputError("--scene NAME takes the folder, format, images and views from the params file; "
                                     "give either it or a scene folder (with --images/--format/--views)")
                if args.fit is not None or args.colmap is not None:
                    raise InputError("--scene NAME finds its own fit (out/NAME/gs/point_cloud.ply); --fit and --colmap "
                                     "are for a scene folder")
                session = PaintSession.for_params(args.params, args.scene_name, fit=not args.one_view, **kw)
            else:
                if (args.fit is None) != (args.colmap is None):
                    raise InputError("--fit and --colmap go together: the fit's PLY and its layout's folder")
                session = PaintSession.for_scene(args.scene, images=args.images, fmt=args.format, views=args.views,
                                                 **kw)
                if args.fit is not None and not args.one_view:
                    session.attach_fit(args.fit, args.colmap)
        else:
            raise InputError("give a scene folder, --scene NAME (a scene of params.yaml) or --painting PATH")
        server = make_server(session, args.port)
    except (AbcgsError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    url = page_url(server)
    what = (f"{len(session.items)} views; masks go to {session.items[0].out_path.parent}" if session.mode == "scene"
            else f"the painting; its labels go to {session.items[0].out_path}")
    print(f"paint: {url}  ({what}; {session.field_note}); Ctrl+C to stop")
    if not args.no_open:
        webbrowser.open(url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0
