"""The command line: ``rift-jax`` (or ``python -m rift_jax``).

    rift-jax fit DATA --extent E --granularity G [--method M] [--support auto|none]
                 [--option NAME=VALUE ...] [--out RESULT]
    rift-jax info FILE
    rift-jax experiment NAME [ITS ARGUMENTS ...]

``fit`` reconstructs measured signals saved by `rift_jax.save` (a `RadarData`, NPZ or HDF5)
or in the RIFT authors' NPZ layout (``--public``), and saves the `FitResult` beside them;
``info`` says what a rift_jax file holds; ``experiment`` runs one of the paper's studies
(``experiments/``, in a clone of the repository) with its own arguments.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
from pathlib import Path

from ._io.native import _SUFFIXES

_EXPERIMENTS = ("weak_target", "simple_scenes", "complex_scenes", "stability", "mismatch")
_EXPERIMENTS += ("rift_ideas",)


def main(argv: list[str] | None = None) -> int:
    """Run the command line with ``argv`` (default ``sys.argv[1:]``); returns the exit code."""
    parser = _parser()
    args = parser.parse_args(argv)
    return args.run(args)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rift-jax", description="Reconstruct radar scenes through the GRT (rift_jax)."
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    fit = commands.add_parser(
        "fit",
        help="reconstruct measured signals from a file",
        description="Reconstruct the signals in DATA on the grid ±EXTENT at GRANULARITY and "
        "save the FitResult (rift_jax.load reads it back).",
    )
    fit.add_argument("data", type=Path, help="a RadarData saved by rift_jax.save (.npz, .h5)")
    fit.add_argument("--extent", type=float, required=True, help="grid half-width (m)")
    fit.add_argument("--granularity", type=float, required=True, help="grid spacing (m)")
    fit.add_argument(
        "--method",
        default=None,
        help="fista (default: its λ chosen on held-out views), auto (fista or rift-n, chosen "
        "on held-out views), rift-n, ...",
    )
    fit.add_argument(
        "--support",
        choices=("auto", "none"),
        default="auto",
        help="auto: estimate where the scene is (default); none: every grid point",
    )
    fit.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a method option, e.g. --option iterations=200 (VALUE read as JSON, else text); "
        "method auto takes none but candidates={...}",
    )
    fit.add_argument("--public", action="store_true", help="DATA is in the authors' NPZ layout")
    fit.add_argument("--seed", type=int, default=0)
    fit.add_argument("--out", type=Path, help="where to save (default DATA_fit.h5 beside it)")
    fit.add_argument("--no-progress", action="store_true", help="no progress bar")
    fit.set_defaults(run=_fit)

    info = commands.add_parser("info", help="say what a rift_jax file holds")
    info.add_argument("path", type=Path)
    info.set_defaults(run=_info)

    experiment = commands.add_parser(
        "experiment",
        help="run one of the paper's studies (from a clone)",
        description="Run experiments.NAME with the arguments that follow it (see "
        "`rift-jax experiment NAME --help`). The studies live in the repository, not in "
        "the installed package: run this from a clone's root.",
    )
    experiment.add_argument("name", choices=_EXPERIMENTS)
    experiment.add_argument("args", nargs=argparse.REMAINDER, help="the study's own arguments")
    experiment.set_defaults(run=_experiment)
    return parser


# fit's arguments that the command sets itself: not method options
_RESERVED = ("extent", "granularity", "support", "seed", "progress", "radar", "monitor", "method")


def _options(pairs: list[str]) -> dict:
    options = {}
    for pair in pairs:
        name, sep, text = pair.partition("=")
        if not sep or not name.isidentifier():
            raise SystemExit(f"rift-jax fit: `--option` must be NAME=VALUE, got {pair!r}.")
        if name in _RESERVED:
            raise SystemExit(
                f"rift-jax fit: `{name}` is not a method option: the command sets it (from its "
                "own options, such as --extent, or from the file)."
            )
        try:
            options[name] = json.loads(text)
        except json.JSONDecodeError:
            options[name] = text  # a word such as fista or rift-n
    return options


def _fit(args) -> int:
    import rift_jax as rj

    options = _options(args.option)
    if args.method is not None:
        options["method"] = args.method
    out = args.out or args.data.with_name(f"{args.data.stem}_fit.h5")
    if out.suffix.lower() not in _SUFFIXES or not out.parent.is_dir():
        raise SystemExit(  # now, not after the fit
            f"rift-jax fit: `--out` must be a .npz, .h5 or .hdf5 file in an existing folder, "
            f"got {str(out)!r}."
        )
    try:
        data = rj.load_rift_public(args.data) if args.public else rj.load(args.data)
    except (ValueError, OSError) as error:
        raise SystemExit(f"rift-jax fit: {error}") from error
    if not isinstance(data, rj.RadarData):
        raise SystemExit(
            f"rift-jax fit: {str(args.data)!r} holds a {type(data).__name__}, not measured "
            "signals (a RadarData): reconstruct a Scene with rift_jax.fit in Python."
        )
    try:
        result = rj.fit(
            data,
            data.viewpoints,
            extent=args.extent,
            granularity=args.granularity,
            support=None if args.support == "none" else "auto",
            seed=args.seed,
            progress=not args.no_progress,
            **options,
        )
    except rj.solvers.Diverged as error:  # the run so far is kept: save it, and say so
        rj.save(out, error.result)
        raise SystemExit(f"rift-jax fit: {error} Saved the best before it to {out}.") from error
    except ValueError as error:  # bad input: the message names the argument
        raise SystemExit(f"rift-jax fit: {error}") from error
    rj.save(out, result)
    residual = result.stats.get("data_residual")
    print(
        f"{result.method}: {result.stopped} in {result.seconds:.1f} s, "
        f"{result.scene.shape[0]}³ grid"
        + ("" if residual is None else f", data residual {residual:.3g}")
        + f"; saved to {out}"
    )
    return 0


def _info(args) -> int:
    import rift_jax as rj

    try:
        obj = rj.load(args.path)
    except (ValueError, OSError) as error:
        raise SystemExit(f"rift-jax info: {error}") from error
    print(f"{args.path}: {type(obj).__name__}")
    if isinstance(obj, rj.RadarData):
        print(f"  signal {tuple(obj.signal.shape)} (views, frequencies, TX, RX), {obj.radar}")
    elif isinstance(obj, rj.Scene):
        print(f"  {obj.shape[0]}³ points at {obj.granularity} m over ±{obj.extent} m")
    elif isinstance(obj, rj.PointScatterers):
        print(f"  {len(obj.points)} scatterers within ±{obj.extent} m")
    else:
        scene = obj.scene
        print(
            f"  {obj.method}, {obj.stopped}, {obj.seconds:.1f} s; {scene.shape[0]}³ points at "
            f"{scene.granularity} m over ±{scene.extent} m, {len(obj.viewpoints)} views"
        )
    return 0


def _experiment(args) -> int:
    added = os.getcwd() not in sys.path  # a console script's path starts at its own folder
    if added:
        sys.path.insert(0, os.getcwd())
    try:
        module = importlib.import_module(f"experiments.{args.name}")
    except ModuleNotFoundError as error:
        if error.name not in ("experiments", f"experiments.{args.name}"):
            raise
        raise SystemExit(
            "rift-jax experiment: the studies live in the repository's experiments/ folder, "
            "not in the installed package; run this from the root of a clone."
        ) from error
    finally:
        if added:
            sys.path.remove(os.getcwd())
    module.cli(args.args)
    return 0
