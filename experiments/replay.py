"""Replay cells of the stress grid with other options: measure a change to one method on
the grid's own data without re-running the grid.

    python -m experiments.replay --cells SCENE:VIEWS:NOISE [...] [--method rift-n]
                                 [--options JSON] [--scale quick|default|paper]
                                 [--grid DIR] [--out DIR] [--resume] [--no-progress]

Each cell (``NOISE``: an SNR in dB, or ``none`` for noise-free) is one of
`experiments.stability`'s; ``--method``'s run there is repeated on that cell's data (the same
scene, draw of views, noise and seed) with ``--options`` (a JSON object) added to the grid's
options. With ``--grid`` (a stress grid's results folder of the same scale; default
``docs/results/stability_SCALE`` where it exists), results.md sets each replay beside that
grid's own run of the method, FISTA's, and says whether the replay fails by the grid's rule,
judged with the grid's other methods in its cell. For example, docs/rift.md's comparison of losses:

    python -m experiments.replay --method rift-n --options '{"loss": "mse"}' \\
        --cells cube:30:none cube:30:0 parking_lot:100:none ...

Writes results.json, results.md and reconstructions.npz into ``--out`` (default
``results/replay_SCALE``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from . import stability
from .runner import Run, check_writable, environment_line, table, write_atomic

GRIDS = Path("docs/results")  # the committed grids: stability_SCALE


def parse_cell(text: str) -> tuple[str, int, float | None]:
    """``"cube:30:none"`` → ("cube", 30, None); ``"cube:30:-10"`` → ("cube", 30, -10.0)."""
    parts = text.split(":")
    try:
        scene, views, noise = parts
        return scene, int(views), None if noise == "none" else float(noise)
    except ValueError:
        raise ValueError(
            f"replay: `--cells` entries are SCENE:VIEWS:NOISE (NOISE an SNR in dB or 'none'), "
            f"got {text!r}."
        ) from None


def runs(cfg: stability.Config, method: str, cells, extra: dict) -> list[Run]:
    """The grid's runs of ``method`` in ``cells``, each with ``extra`` options added."""
    if method not in cfg.methods:
        raise ValueError(f"replay: `--method` must be one of {list(cfg.methods)}, got {method!r}.")
    asked = set(cells)
    out = []
    for run in stability.runs(cfg):
        cell = (run.scene, run.n_train, run.options.get("snr_db"))
        if run.method == method and cell in asked:
            out.append(dataclasses.replace(run, options=dict(run.options) | extra))
            asked.discard(cell)
    if asked:
        missing = ", ".join(f"{s}:{v}:{'none' if n is None else f'{n:g}'}" for s, v, n in asked)
        raise ValueError(
            f"replay: the {cfg.scenes} × views {cfg.views} × SNR {cfg.snrs} grid has no cell "
            f"{missing} (`--cells`)."
        )
    return out


def compare(rows: list[dict], grid_rows: list[dict], method: str) -> list[dict]:
    """Each replayed row with ``grid`` (the grid's own m-SSIM of the run, or None),
    ``fista`` (FISTA's in the cell, or None) and ``failed`` (the grid's rule, judged with
    the grid's other methods in the cell; None where the grid has none)."""
    out = []
    for row in rows:
        cell = [r for r in grid_rows if stability._cell(r) == stability._cell(row)]
        own = [r for r in cell if r["method"] == method and r["seed"] == row["seed"]]
        fista = [r for r in cell if r["method"] == "fista" and r["seed"] == row["seed"]]
        others = [dict(r) for r in cell if r["method"] != method]
        failed = None
        if others:
            judged = stability.judge(others + [dict(row)])
            failed = judged[-1]["failed"] or ""
        out.append(
            row
            | {
                "grid": own[0]["m_ssim"] if own else None,
                "fista": fista[0]["m_ssim"] if fista else None,
                "failed": failed,
            }
        )
    return out


def report(results, volumes, figures, cfg, out: Path, grid: Path | None, method: str) -> None:
    del volumes, figures  # no figures
    rows = [dict(r) | {"noise": stability.noise_name(r["options"].get("snr_db"))}
            for r in results["rows"]]  # fmt: skip
    grid_rows = []
    if grid is not None:
        grid_rows = json.loads((grid / "results.json").read_text())["rows"]
        for r in grid_rows:
            r["noise"] = stability.noise_name(r["options"].get("snr_db"))
    rows = compare(rows, grid_rows, method)

    def number(value):
        return "–" if value is None else f"{value:.3f}"

    def verdict(row):
        return "–" if row["failed"] is None else (row["failed"] or "no")

    columns = [
        ("scene", lambda r: r["scene"]),
        ("views", lambda r: str(r["n_train"])),
        ("noise", lambda r: r["noise"]),
        ("m-SSIM", lambda r: number(r["m_ssim"])),
        ("residual", lambda r: number(r["residual"])),
        ("the grid's run", lambda r: number(r["grid"])),
        ("FISTA", lambda r: number(r["fista"])),
        ("fails", verdict),
        ("s", lambda r: f"{r['wall_seconds']:.0f}"),
    ]
    extra = results["config"].get("replay_options", {})
    lines = [
        f"# Stress-grid cells replayed, scale `{results['scale']}`",
        "",
        f"{stability.LABELS[method]} on each cell's own data with `{json.dumps(extra)}` added to "
        f"the grid's options; beside it the grid's own run and FISTA's from "
        f"{grid if grid is not None else '(no grid given)'}.",
        "",
        table(rows, columns),
        "",
        environment_line(results),
        "",
    ]
    write_atomic(out / "results.md", "\n".join(lines))


@dataclasses.dataclass(frozen=True)
class Config(stability.Config):
    """The stress grid's config, with what is replayed (so that ``--resume`` checks it)."""

    replay_method: str = "rift-n"
    replay_options: dict = dataclasses.field(default_factory=dict)


def cli(argv=None) -> dict:
    parser = argparse.ArgumentParser(
        prog="python -m experiments.replay",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--cells", nargs="+", required=True, help="SCENE:VIEWS:NOISE ...")
    parser.add_argument("--method", default="rift-n")
    parser.add_argument("--options", default="{}", help="a JSON object of `fit` options")
    parser.add_argument("--scale", choices=list(stability.SCALES), default="default")
    parser.add_argument(
        "--grid", type=Path, default=None, help=f"default: {GRIDS}/stability_SCALE if present"
    )
    parser.add_argument("--out", type=Path, default=None, help="default: results/replay_SCALE")
    parser.add_argument("--resume", action="store_true", help="keep the runs already in --out")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    args = parser.parse_args(argv)
    try:
        extra = json.loads(args.options)
    except json.JSONDecodeError as error:
        parser.error(f"argument --options: not JSON: {error}")
    if not isinstance(extra, dict):
        parser.error(f"argument --options: must be a JSON object, got {args.options!r}")
    try:
        cells = [parse_cell(text) for text in args.cells]
        asked = runs(stability.SCALES[args.scale], args.method, cells, extra)
    except ValueError as error:
        parser.error(str(error))
    grid = args.grid
    if grid is None and (GRIDS / f"stability_{args.scale}" / "results.json").exists():
        grid = GRIDS / f"stability_{args.scale}"
    if grid is not None:
        if not (grid / "results.json").exists():
            parser.error(f"argument --grid: {grid / 'results.json'} does not exist")
        scale = json.loads((grid / "results.json").read_text()).get("scale")
        if scale != args.scale:
            parser.error(f"argument --grid: {grid} holds the {scale!r} scale, not {args.scale!r}")
    out = args.out or Path("results") / f"replay_{args.scale}"
    try:
        check_writable(out)
    except OSError as error:
        parser.error(f"argument --out: cannot write results to {out}: {error}")
    base = stability.SCALES[args.scale]
    cfg = Config(
        **{f.name: getattr(base, f.name) for f in dataclasses.fields(base)},
        replay_method=args.method,
        replay_options=extra,
    )
    cfg = dataclasses.replace(cfg, scenes=tuple(dict.fromkeys(run.scene for run in asked)))
    results = stability.on_the_grid(
        "replay", cfg, asked,
        lambda res, vol, fig, cfg_, out_: report(res, vol, fig, cfg_, out_, grid, args.method),
        out=out, scale=args.scale, seed=0, resume=args.resume, progress=not args.no_progress,
    )  # fmt: skip
    print(f"wrote results.md, results.json and reconstructions.npz to {out}/")
    return results


if __name__ == "__main__":
    cli()
