"""Run time against error for every reconstruction method: which to pick when.

    python -m benchmarks.time_to_quality [--scale quick|default|paper] [--out DIR]
                                         [--seed 0] [--resume] [--no-progress] [--part K/N]

The cube, sphere and pyramid (ρ = 1) are synthesised on the forward grid and reconstructed
on the nested inverse grid, from 100 and from 1000 training viewpoints, by every method of
`rift_jax.fit`: kaczmarz, lsmr, gauss-newton, fista, rift-n and rift-s, each on the whole
grid and on ``support="auto"``; RIFT also trained at the forward granularity on that
support (``train_granularity``, coarse to fine) and Kaczmarz, LSMR and FISTA solving for
the same points (the data's own grid: the comparison on the same points); and RIFT(N) with
the paper's recipe. All runs face one shared set of unseen test viewpoints
(`experiments.runner.draw`).

While each run runs, a `experiments.runner.Trace` samples its best reconstruction so far
at wall times on a geometric ladder: m-SSIM against the truth, p-RMSE at 10 unseen
viewpoints, and the data residual (the sampling's own time is left out of the run's
clock). Each method runs its budget or stops once converged (its default ``tol``; RIFT's
``patience``), so a curve ends where the method has nothing more to give.

Writes (atomically, after every run; ``--resume`` goes on from an interrupted run) to
``docs/results/time_to_quality_<scale>/``: ``results.json`` (rows named by each method's
`fit` name, with the traces), ``results.md`` (time to reach m-SSIM 0.5 / 0.8 / 0.9, and the
m-SSIM a run stopped at 1 / 5 / 15 min gives, per scene and number of views),
``time_to_quality.png`` (m-SSIM and p-RMSE against seconds, one curve per method) and
``reconstructions.npz``. Like every
experiment (`experiments.runner.versions`), it prints and records this machine's complex
matmul rate from the same run, so the times can be read on another machine.

Scales:
- quick: seconds, for the tests (the cube, ±2 m at 0.5 / 1.0 m, a small radar, 10 views,
  Kaczmarz and RIFT(N) only);
- default: ±4.8 m at 0.4 / 0.8 m (13³ inverse points), 16 frequencies over the paper's
  band, 8 × 8 antennas; each run at 1000 views capped at a minute (`fit`'s
  ``time_limit``): 108 runs in 100 min on a 2-core CPU;
- paper: the paper's grids (±5 m at 0.2 / 0.4 m, 26³ inverse points) and radar (100
  frequencies, 16 × 16 antennas): for a GPU, or a CPU and a day.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

import rift_jax as rj
from experiments.runner import (
    Run,
    command,
    environment_line,
    execute,
    figure_lines,
    rift_options,
    save_figure,
    table,
    write_atomic,
)

LEAST_SQUARES = ("kaczmarz", "lsmr", "gauss-newton", "fista")
THRESHOLDS = (0.5, 0.8, 0.9)  # m-SSIM levels: time to reach each
BUDGETS = (60.0, 300.0, 900.0)  # seconds: the m-SSIM a run stopped then gives


@dataclasses.dataclass(frozen=True)
class Config:
    extent: float
    forward: float  # the truth's (synthesis) granularity, m
    inverse: float  # the reconstruction's, m (nested: a multiple of `forward`)
    n_frequencies: int
    n_antennas: int  # TX = RX
    n_train: tuple[int, ...]
    n_test: int
    iterations: dict  # each least-squares method's budget (its `iterations`)
    rift_steps: int  # RIFT's optimizer steps of 10 views (`rift_options`)
    patience: int  # RIFT stops after this many epochs without progress
    scenes: tuple[str, ...] = ("cube", "sphere", "pyramid")
    methods: tuple[str, ...] = (*LEAST_SQUARES, "rift-n", "rift-s")  # `fit` methods compared
    # {n_train: seconds}: every run on that many views ends once its clock passes this
    # (`fit`'s ``time_limit``), after the iteration in which it does
    time_limit: dict = dataclasses.field(default_factory=dict)
    # seconds into a run of its first trace sample (then 1.5× apart, `runner.Trace`)
    first_sample: float = 0.25


SCALES = {
    # one scene, two methods: the mechanics (traces, tables, figure, resume) in seconds
    "quick": Config(
        2.0, 0.5, 1.0, 8, 4, (10,), 4, {"kaczmarz": 3, "fista": 5}, rift_steps=6,
        patience=5, scenes=("cube",), methods=("kaczmarz", "rift-n"),
        # its runs last seconds: the first iteration's end is always sampled, on any machine
        first_sample=1e-3,
    ),
    "default": Config(
        4.8, 0.4, 0.8, 16, 8, (100, 1000), 100,
        {"kaczmarz": 10, "lsmr": 50, "gauss-newton": 3, "fista": 50},
        rift_steps=500, patience=10,
        # a sweep over 1000 views costs 10× one over 100: at 1000, what a minute buys
        time_limit={1000: 60.0},
    ),
    "paper": Config(
        5.0, 0.2, 0.4, 100, 16, (100, 1000), 100,
        {"kaczmarz": 100, "lsmr": 1000, "gauss-newton": 30, "fista": 1000},
        rift_steps=10000, patience=10,
    ),
}  # fmt: skip


def methods(cfg: Config, n_train: int) -> list[tuple[str, str, dict]]:
    """(label, `fit` method, options) of every method compared, for ``n_train`` views."""
    out = []
    limit = {"time_limit": cfg.time_limit[n_train]} if n_train in cfg.time_limit else {}
    fine = AUTO | {"train_granularity": cfg.forward}
    for method in [m for m in LEAST_SQUARES if m in cfg.methods]:
        options = {"iterations": cfg.iterations[method]} | limit
        if method == "gauss-newton":
            options["inner"] = 20  # LSMR steps per outer step
        out += [(method, method, options | GRID), (f"{method} auto", method, options | AUTO)]
    # least squares on the points RIFT's "auto fine" rows train last: the same points
    # (Gauss-Newton left out: LSMR's image at 2-3x its cost, here as on the inverse grid)
    for method in [m for m in LEAST_SQUARES if m in cfg.methods and m != "gauss-newton"]:
        out.append(
            (f"{method} auto fine", method, {"iterations": cfg.iterations[method]} | limit | fine)
        )
    rift = rift_options(n_train, cfg.rift_steps) | {"patience": cfg.patience, "prune": None}
    rift |= limit
    for method in [m for m in ("rift-n", "rift-s") if m in cfg.methods]:
        out += [
            (method, method, rift | GRID),
            (f"{method} auto", method, rift | AUTO),
            (f"{method} auto fine", method, rift | fine),
        ]
    if "rift-n" in cfg.methods:
        paper = rift | GRID | {"recipe": "paper", "loss": "paper"}  # the recipe's own loss
        out.append(("rift-n paper recipe", "rift-n", paper))
    return out


AUTO = {"support": "auto"}
GRID = {"support": None}  # named: `fit`'s default is "auto"


def runs(cfg: Config) -> list[Run]:
    return [
        Run(scene, f"{label}/{n}", method, n, options)
        for n in cfg.n_train
        for scene in cfg.scenes
        for label, method, options in methods(cfg, n)
    ]


def main(
    cfg: Config,
    *,
    out: Path,
    scale: str,
    seed: int,
    resume: bool,
    progress: bool,
    part: tuple[int, int] | None = None,
):
    radar = rj.Radar(n_frequencies=cfg.n_frequencies, n_tx=cfg.n_antennas, n_rx=cfg.n_antennas)
    scenes = {name: getattr(rj.scenes, name)(cfg.forward, extent=cfg.extent) for name in cfg.scenes}

    def report(results, volumes, figures):
        write_atomic(out / "results.md", markdown(results, cfg, scale, figures))
        if figures:
            plot(results, cfg, out / "time_to_quality.png")

    return execute(
        "time_to_quality",
        scale,
        cfg,
        scenes,
        runs(cfg),
        pool=rj.Viewpoints.grid(),
        radar=radar,
        inverse=cfg.inverse,
        n_test=cfg.n_test,
        seed=seed,
        out=out,
        report=report,
        trace={"first": cfg.first_sample},
        resume=resume,
        progress=progress,
        part=part,
    )


# -- reading the traces ---------------------------------------------------------------------


def time_to(trace: list[dict], level: float) -> float | None:
    """The first sampled time at which m-SSIM reached ``level`` (None: never)."""
    return next((r["seconds"] for r in trace if r["m_ssim"] >= level), None)


def quality_at(trace: list[dict], seconds: float) -> float | None:
    """m-SSIM of what stopping at ``seconds`` gives: the last sample by then (None: none
    yet). Not the best m-SSIM seen, which only the truth could pick."""
    values = [r["m_ssim"] for r in trace if r["seconds"] <= seconds]
    return values[-1] if values else None


def _seconds(value: float | None) -> str:
    if value is None:
        return "–"
    return f"{value:.1f} s" if value < 60 else f"{value / 60:.1f} min"


def _number(value: float | None) -> str:
    return "–" if value is None else f"{value:.3f}"


def markdown(results: dict, cfg: Config, scale: str, figures: bool) -> str:
    rows = results["rows"]
    lines = [
        f"# Run time against error ({scale} scale)",
        "",
        f"±{cfg.extent:g} m, forward {cfg.forward:g} m, inverse {cfg.inverse:g} m; radar "
        f"{cfg.n_frequencies} frequencies over 95-105 GHz, {cfg.n_antennas} × "
        f"{cfg.n_antennas} antennas; {cfg.n_test} unseen test viewpoints shared by every "
        "run; traces sampled on a 1.5× time ladder (p-RMSE at 10 of the test views).",
        "",
        environment_line(results),
        "",
        '`auto`: on `support="auto"`; `fine`: on the points of the forward grid (the '
        "grid the data were made on) in the support, `train_granularity`: RIFT trains its "
        "last epochs there (coarse to fine), least squares solves for them from the start. "
        "`fine` rows compare with each other on the same points; every other row runs on "
        "the inverse grid. m-SSIM is scored on the inverse grid's points for every row "
        "(a `fine` row: its values there); the final p-RMSE predicts from what was solved "
        "(a `fine` row: the forward grid's points). Times are the run's own (compilation "
        "included, sampling excluded). – : never reached / no sample yet.",
    ]
    for n in sorted({r["n_train"] for r in rows}):
        for scene in cfg.scenes:
            chosen = [r for r in rows if r["scene"] == scene and r["n_train"] == n]
            if not chosen:
                continue
            columns = [("method", lambda r: r["run"].split("/")[0])]
            columns += [
                (f"to m-SSIM {level:g}", lambda r, v=level: _seconds(time_to(r["trace"], v)))
                for level in THRESHOLDS
            ]
            columns += [
                (f"m-SSIM at {_seconds(t)}", lambda r, t=t: _number(quality_at(r["trace"], t)))
                for t in BUDGETS
            ]
            columns += [
                ("final m-SSIM", lambda r: f"{r['m_ssim']:.3f}"),
                ("p-RMSE (rad)", lambda r: f"{r['p_rmse']:.3f}"),
                ("residual", lambda r: f"{r['residual']:.3f}"),
                ("points", lambda r: str(r["points"])),
                ("s", lambda r: f"{r['fit_seconds']:.1f}"),
                ("stopped", lambda r: rj.solvers.Stop.from_json(r["stopped"]).outcome.value),
            ]
            lines += ["", f"## {scene}, {n} training views", ""]
            if n in cfg.time_limit:
                lines += [
                    f"Every run was capped at {_seconds(cfg.time_limit[n])} of its clock "
                    "(`time_limit`): one that reached it ended after the iteration in which "
                    "it did (a Gauss-Newton step, a sweep or an epoch may overshoot), and "
                    "`stopped` says so.",
                    "",
                ]
            lines += [table(chosen, columns)]
    lines += ["", *figure_lines(("time_to_quality.png",), figures)]
    return "\n".join(lines).rstrip("\n") + "\n"


def plot(results: dict, cfg: Config, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = results["rows"]
    views = sorted({r["n_train"] for r in rows})
    fig, axes = plt.subplots(
        2 * len(views), len(cfg.scenes), figsize=(5 * len(cfg.scenes), 3.6 * 2 * len(views)),
        squeeze=False, sharex=True,
    )  # fmt: skip
    labels = [label for label, *_ in methods(cfg, 10)]
    colours = dict(zip(labels, plt.cm.tab20(np.linspace(0, 1, len(labels))), strict=True))
    for i, n in enumerate(views):
        for j, scene in enumerate(cfg.scenes):
            for k, (key, name) in enumerate((("m_ssim", "m-SSIM"), ("p_rmse", "p-RMSE (rad)"))):
                ax = axes[2 * i + k, j]
                for row in rows:
                    if row["scene"] != scene or row["n_train"] != n:
                        continue
                    label = row["run"].split("/")[0]
                    t = [r["seconds"] for r in row["trace"]]
                    y = [r[key] for r in row["trace"]]
                    style = "--" if "auto" in label else "-"
                    ax.plot(t, y, style, marker=".", color=colours[label], label=label)
                ax.set_xscale("log")
                ax.set_title(f"{scene}, {n} views", fontsize=10)
                ax.set_ylabel(name)
                if key == "p_rmse":
                    ax.axhline(math.pi / math.sqrt(3), color="grey", lw=0.8, ls=":")
                ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("seconds (the run's own clock)")
    handles, names = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, names, loc="upper center", ncol=6, fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.97 - 0.08 / len(views)))  # room for the legend
    save_figure(fig, path)
    plt.close(fig)


def cli(argv=None) -> dict:
    return command(argv, __doc__, SCALES, "time_to_quality", main, root="docs/results")


if __name__ == "__main__":
    cli()
