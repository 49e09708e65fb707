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
judged with the grid's other methods in its cell. For example, docs/rift.md's comparison of
losses, which ran when the robust loss was the default (its replays then named
``{"loss": "mse"}``). The committed grid's RIFT rows ran the robust loss, so ``'{}'`` now
sets today's default, complex MSE, beside them:

    python -m experiments.replay --method rift-n --options '{}' \\
        --cells cube:30:none cube:30:0 parking_lot:100:none ...

``--method auto`` runs `fit`'s choice between FISTA and RIFT(N) (its default until FISTA
chose its λ on held-out views), which the grid does not run, in the cells with
`fit`'s defaults (``--options`` added to them; at the quick scale each candidate with the
scale's budget), judged with the grid's five methods there: how docs/experiments.md
measured it.

Writes results.json, results.md and reconstructions.npz into ``--out`` (default
``results/replay_SCALE``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from . import stability
from .runner import (
    Run,
    check_writable,
    environment_line,
    rift_loss,
    table,
    write_atomic,
    write_json,
)

GRIDS = Path("docs/results")  # the committed grids: stability_SCALE
AUTO = "auto"  # `fit`'s choice between methods (rift_jax/_selection.py)
# options a replay may not change: they would move a run to another cell's data
FIXED = ("snr_db", "seed")


@dataclasses.dataclass(frozen=True)
class Config(stability.Config):
    """The stress grid's config, and what is replayed (so that ``--resume`` checks it).
    ``scenes`` holds only the replayed cells' scenes (the ones built); the runs themselves
    come from the whole grid's config, whose rotation gives each cell its seed."""

    replay_method: str = "rift-n"
    replay_options: dict = dataclasses.field(default_factory=dict)


def parse_cell(text: str) -> tuple[str, int, float | None]:
    """``"cube:30:none"`` → ("cube", 30, None); ``"cube:30:-10"`` → ("cube", 30, -10.0)."""
    try:
        scene, views, noise = text.split(":")
        return scene, int(views), None if noise == "none" else float(noise)
    except ValueError:
        raise ValueError(
            f"`--cells` entries are SCENE:VIEWS:NOISE (NOISE an SNR in dB or 'none'), got {text!r}."
        ) from None


def runs(cfg: stability.Config, method: str, cells, extra: dict) -> list[Run]:
    """The grid's runs of ``method`` in ``cells`` (every seed the grid gives a cell), each
    with ``extra`` options added. ``method`` ``"auto"``, which the grid does not run, runs
    where FISTA did with `fit`'s defaults (`stability.DEFAULTS`): a new method on the
    cells' own data."""
    if method not in (*cfg.methods, AUTO):
        raise ValueError(f"`--method` must be one of {[*cfg.methods, AUTO]}, got {method!r}.")
    if fixed := sorted(set(extra) & set(FIXED)):
        raise ValueError(f"`--options` may not set {fixed}: they choose the cell's data.")
    template = "fista" if method == AUTO else method
    asked, found, out = set(cells), set(), []
    for run in stability.runs(cfg):
        cell = (run.scene, run.n_train, run.options.get("snr_db"))
        if run.method == template and cell in asked:
            if method == AUTO:
                options = stability.DEFAULTS | _noise(run) | _auto_budgets(cfg) | extra
                label = stability.label(AUTO, run.n_train, cell[2], run.seed)
                run = dataclasses.replace(run, method=AUTO, label=label, options=options)
            else:
                run = dataclasses.replace(run, options=dict(run.options) | extra)
            out.append(run)
            found.add(cell)
    if missing := asked - found:
        names = ", ".join(f"{s}:{v}:{'none' if n is None else f'{n:g}'}" for s, v, n in missing)
        raise ValueError(
            f"`--cells`: the {cfg.scenes} × views {cfg.views} × SNR {cfg.snrs} grid has no "
            f"cell {names}."
        )
    return out


def _auto_budgets(cfg: stability.Config) -> dict:
    """``candidates``, `fit`'s default ones in its order, with the scale's budgets (the
    quick scale's), or nothing (the defaults)."""
    budgets = dict(cfg.budgets)
    if not budgets:
        return {}
    return {"candidates": {m: dict(budgets.get(m, ())) for m in ("fista", "rift-n")}}


def _noise(run: Run) -> dict:
    return {"snr_db": run.options["snr_db"]} if "snr_db" in run.options else {}


def load_grid(grid: Path, cfg: stability.Config) -> list[dict]:
    """The rows of the stress grid in ``grid`` (each with its seed and ``noise``), after
    checking that it ran ``cfg`` with seed 0: the cells' data the replay draws."""
    path = grid / "results.json"
    try:
        saved = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as error:
        raise ValueError(f"`--grid`: cannot read {path}: {error}") from None
    config = json.loads(json.dumps(dataclasses.asdict(cfg)))
    if saved.get("experiment") != "stability" or saved.get("seed") != 0:
        raise ValueError(f"`--grid`: {path} is not a stress grid run with seed 0.")
    if changed := sorted(k for k in config if saved.get("config", {}).get(k) != config[k]):
        raise ValueError(
            f"`--grid`: {path} ran another config than this scale's ({', '.join(changed)} "
            "differ): its cells hold other data."
        )
    rows = [{"seed": saved["seed"]} | row for row in saved["rows"]]
    for row in rows:
        row["noise"] = stability.noise_name(row["options"].get("snr_db"))
    return rows


def compare(rows: list[dict], grid_rows: list[dict], method: str) -> list[dict]:
    """Each replayed row with ``grid`` (the grid's own m-SSIM of the run, or None),
    ``fista`` (FISTA's in the cell, or None), ``best`` and ``best_method`` (the best of the
    grid's other counted methods there, or None) and ``failed`` (the grid's rule; None where
    the grid has none of the cell). A cell's replays are judged together with the grid's other
    methods there: the replays stand in for the grid's own runs of the method."""
    judged = {}
    for key in {stability._cell(row) for row in rows}:
        others = [dict(r) for r in grid_rows if stability._cell(r) == key and r["method"] != method]
        mine = [dict(r) for r in rows if stability._cell(r) == key]
        if others:
            for row in stability.judge(others + mine)[len(others) :]:
                judged[key, row["seed"]] = row["failed"] or ""
    out = []
    for row in rows:
        same = [r for r in grid_rows if stability._cell(r) == stability._cell(row)
                and r["seed"] == row["seed"]]  # fmt: skip
        own = [r["m_ssim"] for r in same if r["method"] == method]
        fista = [r["m_ssim"] for r in same if r["method"] == "fista"]
        counted = [r for r in same if r["method"] not in (method, stability.BASELINE)]
        best = max(counted, key=lambda r: r["m_ssim"], default=None)
        out.append(
            row
            | {
                "grid": own[0] if own else None,
                "fista": fista[0] if fista else None,
                "best": None if best is None else best["m_ssim"],
                "best_method": None if best is None else best["method"],
                "failed": judged.get((stability._cell(row), row["seed"])),
            }
        )
    return out


def _losses(rows: list[dict], grid_rows: list[dict], method: str) -> str:
    """For RIFT, which loss the replays and the grid's runs trained with (a grid's rows from
    before complex MSE name none: `rift_loss`)."""
    if not method.startswith("rift"):
        return ""

    def losses(rows):
        return ", ".join(sorted({rift_loss(r["options"]) for r in rows})) or "–"

    ran = [r for r in grid_rows if r.get("method") == method]
    return f" Loss: the replays' {losses(rows)}, the grid's runs' {losses(ran)}."


def _chose(row: dict) -> str:
    """``"auto"``'s choice, and any candidate whose final fit failed and gave way."""
    selection = row["selection"]
    rejected = "".join(f", not {stability.LABELS[m]}" for m in selection["rejected"])
    return stability.LABELS[selection["chosen"]] + rejected


def _held_out(row: dict) -> str:
    """Each candidate's held-out residual, in the candidates' order, and for the later ones
    how many standard errors they beat the first by (`paired_t`; > 1 takes the lead)."""
    scores = row["selection"]["scores"]
    if not scores:
        return "– (unscored)"
    parts = []
    for method, score in scores.items():
        t = score.get("paired_t")
        part = f"{stability.LABELS[method]} {score['holdout_residual']:.5f}"
        parts.append(part + ("" if t is None else f" (t {t:+.1f})"))
    return " / ".join(parts)


def report(results, cfg, out: Path, grid: Path | None, grid_rows: list[dict]) -> None:
    """results.md: each replay beside the grid's own run and FISTA's; the verdicts go into
    the rows of ``results`` too (results.json is written before each report)."""
    rows = [dict(r) | {"noise": stability.noise_name(r["options"].get("snr_db"))}
            for r in results["rows"]]  # fmt: skip
    rows = compare(rows, grid_rows, cfg.replay_method)
    for saved, row in zip(results["rows"], rows, strict=True):
        saved.update({key: row[key] for key in ("grid", "fista", "best", "best_method", "failed")})

    def number(value):
        return "–" if value is None else f"{value:.3f}"

    def best(row):
        if row["best"] is None:
            return "–"
        return f"{row['best']:.3f} ({stability.LABELS[row['best_method']]})"

    def verdict(row):
        return "–" if row["failed"] is None else (row["failed"] or "no")

    columns = [
        ("scene", lambda r: r["scene"]),
        ("views", lambda r: str(r["n_train"])),
        ("noise", lambda r: r["noise"]),
        ("seed", lambda r: str(r["seed"])),
        ("m-SSIM", lambda r: number(r["m_ssim"])),
        ("residual", lambda r: number(r["residual"])),
        ("the grid's run", lambda r: number(r["grid"])),
        ("FISTA", lambda r: number(r["fista"])),
        ("the cell's best other", lambda r: best(r)),
        ("fails", verdict),
        ("s", lambda r: f"{r['wall_seconds']:.0f}"),
    ]
    if cfg.replay_method == AUTO:  # what it chose, and on what evidence
        columns[5:5] = [("chose", _chose), ("held-out residuals, t", _held_out)]
    lines = [
        f"# Stress-grid cells replayed, scale `{results['scale']}`",
        "",
        f"{stability.LABELS[cfg.replay_method]} on each cell's own data with "
        f"`{json.dumps(cfg.replay_options)}` added to "
        + ("`fit`'s defaults" if cfg.replay_method == AUTO else "the grid's options")
        + "; beside it the grid's "
        f"own run and FISTA's from {grid if grid is not None else '(no grid given)'}. A "
        "replay fails by the grid's rule, judged with the grid's other methods in its cell."
        + _losses(rows, grid_rows, cfg.replay_method),
        "",
        table(rows, columns),
        "",
        environment_line(results),
        "",
    ]
    write_atomic(out / "results.md", "\n".join(lines))


def main(
    cfg: Config,
    cells,
    *,
    out: Path,
    grid: Path | None = None,
    scale: str = "custom",
    resume: bool = False,
    progress: bool = True,
) -> dict:
    """Replay ``cfg.replay_method``'s runs of ``cells`` with ``cfg.replay_options`` added;
    the results dict as written to ``out/results.json``."""
    base = grid_config(cfg)
    asked = runs(base, cfg.replay_method, cells, cfg.replay_options)
    grid_rows = load_grid(grid, base) if grid is not None else []
    # the scenes built, in the grid's order: the order `--cells` names them in would make a
    # resumed replay's config differ from its first
    order = {scene: k for k, scene in enumerate(base.scenes)}
    scenes = tuple(sorted({run.scene for run in asked}, key=order.get))
    results = stability.on_the_grid(
        "replay", dataclasses.replace(cfg, scenes=scenes), asked,
        lambda res, vol, fig, cfg_, out_: report(res, cfg_, out_, grid, grid_rows),
        out=out, scale=scale, seed=0, resume=resume, progress=progress,
    )  # fmt: skip
    write_json(Path(out) / "results.json", results)  # with the last report's verdicts
    print(f"wrote results.md, results.json and reconstructions.npz to {out}/")
    return results


def grid_config(cfg: Config) -> stability.Config:
    """The stress grid's own config within ``cfg``."""
    return stability.Config(
        **{f.name: getattr(cfg, f.name) for f in dataclasses.fields(stability.Config)}
    )


def cli(argv=None) -> dict:
    parser = argparse.ArgumentParser(
        prog="python -m experiments.replay",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--cells", nargs="+", required=True, help="SCENE:VIEWS:NOISE ...")
    parser.add_argument("--method", default="rift-n", help="a grid method, or auto")
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
    base = stability.SCALES[args.scale]
    grid = args.grid
    if grid is None and (GRIDS / f"stability_{args.scale}" / "results.json").exists():
        grid = GRIDS / f"stability_{args.scale}"
    try:  # every argument checked before any run
        cells = [parse_cell(text) for text in args.cells]
        runs(base, args.method, cells, extra)
        if grid is not None:
            load_grid(grid, base)
    except ValueError as error:
        parser.error(str(error))
    out = args.out or Path("results") / f"replay_{args.scale}"
    try:
        check_writable(out)
    except OSError as error:
        parser.error(f"argument --out: cannot write results to {out}: {error}")
    cfg = Config(**dataclasses.asdict(base), replay_method=args.method, replay_options=extra)
    return main(
        cfg, cells, out=out, grid=grid, scale=args.scale, resume=args.resume,
        progress=not args.no_progress,
    )  # fmt: skip


if __name__ == "__main__":
    cli()
