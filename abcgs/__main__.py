"""``python -m abcgs``: add a scene or a painting to ``params.yaml`` (:mod:`abcgs.add`).

    python -m abcgs add-scene NAME PATH [--format F] [--images SUBFOLDER] [--background R G B | transparent] [--splat FILE]
        [--splat-format F] [--splat-nonfinite drop] [--views-kind K --views-count N --views-width W ...]
    python -m abcgs add-style NAME PAINTING [--labels REGION_MAP]
    python -m abcgs add-experiment NAME --scene SCENE (--style P [P ...] [--binding auto | L=R ...] | --styles L=P ...)
        [--method fast [nnfm ...]]

Each prints what it found and the entry it wrote; a problem is one line naming the file and the fix (exit status 2).
"""

from __future__ import annotations

import argparse
import sys
from typing import get_args

import yaml

from abcgs.errors import AbcgsError
from abcgs.sources.registry import formats
from abcgs.splats.params import SplatFormatParam, SplatViewsParams
from abcgs.types import StyleMethod


def _background_word(word: str) -> float | str:
    if word == "transparent":
        return word
    try:
        return float(word)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{word!r} is neither a number in [0, 1] nor 'transparent'") from None


def _background(words: list | None) -> tuple[float, float, float] | str | None:
    """``--background``: three numbers, or ``transparent``."""
    if words is None:
        return None
    if words == ["transparent"]:
        return "transparent"
    if len(words) != 3 or "transparent" in words:
        raise SystemExit("--background takes R G B (three numbers in [0, 1]) or the word transparent")
    return tuple(float(w) for w in words)  # type: ignore[return-value]


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m abcgs", description=__doc__.strip().splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    scene = sub.add_parser("add-scene", help="check a scene folder and add it to data.scenes")
    scene.add_argument("name", help="the scene's name (letters, digits, _ -)")
    scene.add_argument("path", help="its folder (photos in images/, or a dataset with cameras), or a splat file")
    scene.add_argument("--format", default="auto", choices=("auto", *formats()), help="where the cameras come from: "
                       "a registered reader's format (abcgs/sources/formats/, ABCGS_READERS; default: detected from "
                       "the folder's files)")
    scene.add_argument("--images", default=None, help="image subfolder, e.g. images_8 (default: images)")
    scene.add_argument("--background", nargs="+", metavar="R G B | transparent", default=None, type=_background_word,
                       help="an object on nothing: RGB in [0, 1] behind it (RGBA views are composited on it), or "
                       "transparent (RGBA renders); default: white for NeRF-synthetic, black for a bare splat")
    scene.add_argument("--splat", default=None, help="a splat already fitted to this scene (.ply, .splat, .spz)")
    scene.add_argument("--splat-format", default="auto", choices=get_args(SplatFormatParam),
                       help="the splat's format (default: detected; opensplat, gsplat_ply: their trainers' worlds)")
    scene.add_argument("--splat-nonfinite", default="refuse", choices=("refuse", "drop"),
                       help="Gaussians with NaN or infinite values: refuse the splat (default) or drop them")
    views = SplatViewsParams.model_fields
    scene.add_argument("--views-kind", choices=get_args(views["kind"].annotation),
                       help="a bare splat's cameras: " + str(views["kind"].description))
    scene.add_argument("--views-up", choices=get_args(views["up"].annotation),
                       help="a bare splat's cameras: " + str(views["up"].description))
    for key in ("count", "width", "height", "fov_deg", "parallax_deg", "min_opacity"):
        scene.add_argument(f"--views-{key.replace('_', '-')}", type=views[key].annotation,
                           help=f"a bare splat's cameras: {views[key].description} (default {views[key].default})")
    scene.add_argument("--views-elevation-deg", type=float, nargs=2, metavar=("LOW", "HIGH"),
                       help="a bare splat's cameras: " + str(views["elevation_deg"].description))
    style = sub.add_parser("add-style", help="check a painting and add it to data.styles")
    style.add_argument("name", help="the painting's name (letters, digits, _ . -)")
    style.add_argument("path", help="the painting's image file")
    style.add_argument("--labels", default=None, help="its region map (label PNG, for semantic transfer)")
    exp = sub.add_parser("add-experiment", help="add a colour match and its experiments (single, compositional or "
                         "semantic transfer) to colormatches and experiments")
    exp.add_argument("name", help="the experiment's name (letters, digits, _ . -); also its colour match's")
    exp.add_argument("--scene", required=True, help="a scene of data.scenes (python -m abcgs add-scene)")
    exp.add_argument("--style", nargs="+", default=None, metavar="PAINTING",
                     help="single transfer: one experiment per painting of data.styles; semantic: one painting, "
                     "with --binding")
    exp.add_argument("--styles", nargs="+", default=None, metavar="LABEL=PAINTING",
                     help="compositional transfer: a painting per content label, e.g. 1=starry 2=kandinsky")
    exp.add_argument("--binding", nargs="+", default=None, metavar="LABEL=REGION",
                     help="semantic transfer: content label → region of the painting's label map, e.g. 1=3 2=2, or "
                     "auto (the same number)")
    exp.add_argument("--method", nargs="+", default=["fast"], choices=(*get_args(StyleMethod), "none"),
                     help="style losses: one experiment each, sharing the colour match (default: fast; none: the colour "
                     "match alone)")
    exp.add_argument("--content-weight", nargs="+", default=None, metavar="LABEL=WEIGHT",
                     help="a content label's own λ_c (stylize.weights.content elsewhere), e.g. 2=0.005 keeps that "
                     "region closer to the photo (docs/FIDELITY.md 'Detail per label')")
    exp.add_argument("--structure-weight", nargs="+", default=None, metavar="LABEL=WEIGHT",
                     help="a content label's own λ_st, the luminance-gradient term (stylize.weights.structure "
                     "elsewhere), e.g. 2=3000")
    exp.add_argument("--keep", nargs="+", default=None, metavar="LABEL",
                     help="content labels whose detail (a face's eyes and mouth) the painting should keep: each gets "
                     "the measured λ_st 3000 unless --structure-weight gives its own (docs/FIDELITY.md 'Detail per label')")
    for p in (scene, style, exp):
        p.add_argument("--params", default="params.yaml", help="the params file to edit (default: params.yaml)")
        p.add_argument("--force", action="store_true", help="replace an entry of that name")
        p.add_argument("--dry-run", action="store_true", help="check and print the entry, write nothing")
    return ap


def _views(args: argparse.Namespace) -> dict | None:
    """The ``views`` settings given as ``--views-*`` options (``None`` when none is)."""
    given = {key: getattr(args, f"views_{key}") for key in SplatViewsParams.model_fields}
    return {k: v for k, v in given.items() if v is not None} or None


def _add_experiment(args: argparse.Namespace) -> int:
    from abcgs.add_experiment import (
        add_experiment,
        keep_weights,
        parse_binding,
        parse_pairs,
        parse_weights,
        plan_experiments,
    )

    styles = parse_pairs(args.styles, "--styles") if args.styles else None
    plan = plan_experiments(args.name, args.scene, style=args.style, styles=styles, binding=parse_binding(args.binding),
                            methods=args.method, content_weights=parse_weights(args.content_weight, "--content-weight"),
                            structure_weights=keep_weights(args.keep, parse_weights(args.structure_weight,
                                                                                    "--structure-weight")))
    lines = add_experiment(args.params, plan, force=args.force, dry_run=args.dry_run)
    for line in lines:
        print(f"  {line}")
    print(f"{'would write' if args.dry_run else 'wrote'} colormatches and experiments in {args.params}:")
    body = {"colormatches": plan.colormatches, "experiments": plan.experiments}
    print("  " + yaml.safe_dump(body, sort_keys=False, default_flow_style=None).rstrip().replace("\n", "\n  "))
    print(f"run just {'it' if len(plan.experiments) == 1 else 'them'} with:\n  {plan.command()}")
    return 0


def main(argv: list[str] | None = None) -> int:
    from abcgs.add import add_scene, add_style

    args = _parser().parse_args(argv)
    try:
        if args.command == "add-experiment":
            return _add_experiment(args)
        if args.command == "add-scene":
            entry, lines = add_scene(args.params, args.name, args.path, fmt=args.format, images=args.images,
                                     background=_background(args.background), splat=args.splat,
                                     force=args.force, dry_run=args.dry_run, splat_format=args.splat_format,
                                     splat_nonfinite=args.splat_nonfinite, views=_views(args))
            where, body = "data.scenes", {args.name: entry}
        else:
            entry, lines = add_style(args.params, args.name, args.path, labels=args.labels, force=args.force,
                                     dry_run=args.dry_run)
            where, body = "data.styles" + (" and data.style_masks" if args.labels else ""), {
                section: {args.name: value} for section, value in entry.items()}
    except AbcgsError as exc:
        print(f"[{args.command}] error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.name}: {entry['source']['format']}" if args.command == "add-scene" else f"{args.name}:")
    for line in lines:
        print(f"  {line}")
    verb = "would write" if args.dry_run else "wrote"
    print(f"{verb} {where} in {args.params}:")
    print("  " + yaml.safe_dump(body, sort_keys=False, default_flow_style=False).rstrip().replace("\n", "\n  "))
    return 0


if __name__ == "__main__":
    from abcgs.runtime import setup

    setup()  # the process settings (abcgs.runtime.setup): the wait policy only where torch is not loaded yet
    sys.exit(main())
