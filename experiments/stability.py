"""The stress grid: every method at its defaults, over scenes, views, noise and seeds.

    python -m experiments.stability [--scale quick|default|paper] [--out DIR] [--seed 0]
                                    [--resume] [--no-progress] [--part K/N]

Each run is `rift_jax.fit` with the method's defaults (`DEFAULTS`: every method on
``support="auto"``, RIFT on an active set and stopped once converged) on one of the paper's
six scenes (the weak target at 4:1) or a seeded random-primitive scene
(`rift_jax.scenes.random_primitives`), from 10, 30 or 100 training views, noise-free or at
20, 10, 0 and -10 dB SNR. A **cell** is one scene × views × noise; every method runs in
every cell on the same data (one seeded draw of views, nested 10 ⊂ 30 ⊂ 100; the run's
seed draws the noise and RIFT's start). Where every seed in every cell would not fit the
time (`Config.seeds_per_cell`), each cell runs that many seeds, rotated over the cells so
that every seed runs at every level of every factor.

A run **fails** if a metric is non-finite, its m-SSIM is below half its cell's median
(over every run in the cell), or it is below 0.5 where the cell's best run is ≥ 0.9.
Kaczmarz (the paper's baseline) is reported but its failures are not counted. The target
is 0 failures. results.md reports each cell, every method's win rate against every other
on the same runs (by views and by noise), and every failure.

Scales:
- quick (a minute; the tests): one random scene at ±2.4 m, 0.4 / 0.8 m, a tiny radar, RIFT(N)
  and FISTA with small budgets, 6 and 10 views, noise-free and 0 dB;
- default: ±4.8 m, forward 0.4 m, inverse 0.8 m (13³ grid points; the grids nest, and the
  paper's scenes keep their parts), 20 test views, a radar of 16 frequencies and 8 × 8
  antennas, every method at its defaults; one seed per cell (seeds 0-2, rotated);
- paper: ±5 m at 0.2 / 0.4 m, the paper's radar, 100 test views.

Writes results.json (with a top-level integer ``failures``), results.md, stability.png
(m-SSIM per scene and method, one panel per views × noise) and reconstructions.npz into
``--out``.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections import defaultdict
from pathlib import Path

import numpy as np

import rift_jax as rj

from .runner import (
    METRIC_COLUMNS,
    PAPER_SCENES,
    Run,
    build_scene,
    command,
    environment_line,
    execute,
    figure_lines,
    noise_name,
    save_figure,
    table,
    write_atomic,
    write_json,
)

LABELS = {
    "rift-n": "RIFT(N)",
    "rift-s": "RIFT(S)",
    "fista": "FISTA",
    "lsmr": "LSMR",
    "kaczmarz": "Kaczmarz",
    "auto": "Auto",  # not on the grid: replays of its cells (experiments.replay)
}
BASELINE = "kaczmarz"  # the paper's: reported, its failures not counted
DEFAULTS = {"support": "auto"}
RIFT_DEFAULTS = {"loss": "mse", "prune": 0.05, "patience": 10, "epoch_views": 100}
"""`fit`'s and `Recipe`'s defaults, named in each run's options so that a results file says
what it ran even after a default changes (tests/test_experiments.py checks they are still
the library's)."""


@dataclasses.dataclass(frozen=True)
class Config:
    scenes: tuple[str, ...]  # `rift_jax.scenes` builders, or "random-K" (seed K)
    seeds: tuple[int, ...]
    methods: tuple[str, ...]  # `fit` methods
    snrs: tuple[float | None, ...]  # SNR in dB; None: noise-free
    views: tuple[int, ...]  # training view counts
    extent: float  # half-width of the scene (m)
    forward: float  # synthesis granularity (m)
    inverse: float  # reconstruction granularity (m)
    n_test: int
    n_frequencies: int
    n_antennas: int  # transmitters, and receivers
    seeds_per_cell: int | None = None  # None: every seed in every cell
    budgets: tuple[tuple[str, tuple[tuple[str, int], ...]], ...] = ()  # options beyond the
    # defaults, per method (the quick scale's small budgets); () at the default scale

    def radar(self) -> rj.Radar:
        """The scale's radar: its frequencies, and as many transmitters as receivers."""
        return rj.Radar(n_frequencies=self.n_frequencies, n_tx=self.n_antennas,
                        n_rx=self.n_antennas)  # fmt: skip


RANDOM_SCENES = tuple(f"random-{k}" for k in range(4))
SNRS = (None, 20.0, 10.0, 0.0, -10.0)
SCALES = {
    "quick": Config(
        ("random-0",), (0, 1), ("rift-n", "fista"), (None, 0.0), (6, 10), 2.4, 0.4, 0.8,
        n_test=3, n_frequencies=8, n_antennas=4, seeds_per_cell=1,
        budgets=(("rift-n", (("epochs", 3), ("retries", 0))), ("fista", (("iterations", 10),))),
    ),
    "default": Config(
        PAPER_SCENES + RANDOM_SCENES, (0, 1, 2), ("rift-n", "rift-s", "fista", "lsmr",
        "kaczmarz"), SNRS, (10, 30, 100), 4.8, 0.4, 0.8, n_test=20, n_frequencies=16,
        n_antennas=8, seeds_per_cell=1,
    ),
    "paper": Config(
        PAPER_SCENES + RANDOM_SCENES, (0, 1, 2), ("rift-n", "rift-s", "fista", "lsmr",
        "kaczmarz"), SNRS, (10, 30, 100), 5.0, 0.2, 0.4, n_test=100, n_frequencies=100,
        n_antennas=16, seeds_per_cell=1,
    ),
}  # fmt: skip


def label(method: str, n_train: int, snr: float | None, seed: int) -> str:
    return f"{LABELS[method]} {n_train} views {noise_name(snr)} seed {seed}"


def options(method: str, cfg: Config) -> dict:
    """`fit` options of ``method``: its defaults, named, and the scale's budget if any."""
    out = DEFAULTS | (RIFT_DEFAULTS if method.startswith("rift") else {})
    return out | dict(dict(cfg.budgets).get(method, ()))


def cell_seeds(cfg: Config, index: int) -> tuple[int, ...]:
    """The seeds of the ``index``-th cell: all of them, or `seeds_per_cell` rotated."""
    k = cfg.seeds_per_cell
    if k is None or k >= len(cfg.seeds):
        return cfg.seeds
    return tuple(cfg.seeds[(index + j) % len(cfg.seeds)] for j in range(k))


def runs(cfg: Config) -> list[Run]:
    """Every run, cell by cell, in the order that makes a run cut short most useful (and
    `--resume` goes on from there): noise level by noise level (noise-free first, then the
    harshest, see `_noise_order`), each over every view count and every scene. Seeds rotate
    over the cells in scene, views, noise order."""
    out = []
    cells = list(itertools.product(cfg.scenes, cfg.views, cfg.snrs))
    seeds = {cell: cell_seeds(cfg, index) for index, cell in enumerate(cells)}
    order = sorted(cells, key=lambda c: (_noise_order(c[2]), cfg.views.index(c[1]),
                                         cfg.scenes.index(c[0])))  # fmt: skip
    for scene, n_train, snr in order:
        for seed in seeds[scene, n_train, snr]:
            for method in cfg.methods:
                fit_options = options(method, cfg)
                if snr is not None:
                    fit_options |= {"snr_db": snr}
                name = label(method, n_train, snr, seed)
                out.append(Run(scene, name, method, n_train, fit_options, seed))
    return out


def _noise_order(snr: float | None) -> tuple:
    """Noise-free first, then the lowest SNR measured above -10 dB (0 dB: where a prior
    should matter), then the rest from clean to harsh."""
    if snr is None:
        return (0, 0.0)
    return (1, 0.0) if snr == 0 else (2, -snr)


def judge(rows: list[dict]) -> list[dict]:
    """Each row with ``noise``, ``cell_median`` and ``cell_best`` (the median and the best
    m-SSIM of every run in its cell: scene × views × noise) and ``failed`` (None, or why;
    always None for the baseline, which is reported but not counted)."""
    cells = defaultdict(list)
    for row in rows:
        row["noise"] = noise_name(row["options"].get("snr_db"))
        cells[_cell(row)].append(row["m_ssim"])
    for row in rows:
        values = np.asarray(cells[_cell(row)], float)
        values = values[np.isfinite(values)]
        median = float(np.median(values)) if values.size else float("nan")
        best = float(values.max()) if values.size else float("nan")
        row["cell_median"], row["cell_best"] = median, best
        metrics = [row[k] for k in ("m_ssim", "m_cos", "t_iou", "p_rmse", "residual")]
        row["failed"] = None
        if row["method"] == BASELINE:
            continue
        if not np.all(np.isfinite(metrics)):
            row["failed"] = "non-finite metric"
        elif row["m_ssim"] < 0.5 * median:
            row["failed"] = f"m-SSIM {row['m_ssim']:.3f} < half the cell's median {median:.3f}"
        elif best >= 0.9 and row["m_ssim"] < 0.5:
            row["failed"] = f"m-SSIM {row['m_ssim']:.3f} < 0.5 where the cell's best is {best:.3f}"
    return rows


def _cell(row: dict) -> tuple:
    return row["scene"], row["n_train"], row["noise"]


def win_rates(rows: list[dict], methods, by: str | None = None) -> dict:
    """{(level, a, b): (wins, comparisons)}: how often ``a``'s m-SSIM beats ``b``'s on the
    same data (scene, views, noise and seed), per level of ``by`` ("n_train", "noise", or
    None: all)."""
    ssim = {(*_cell(r), r["seed"], r["method"]): r["m_ssim"] for r in rows}
    out = defaultdict(lambda: [0, 0])
    for (scene, n, noise, seed, a), value in ssim.items():
        level = {"n_train": n, "noise": noise, None: "all"}[by]
        for b in methods:
            if b != a and (other := ssim.get((scene, n, noise, seed, b))) is not None:
                out[level, a, b][1] += 1
                out[level, a, b][0] += bool(value > other)
    return {key: tuple(value) for key, value in out.items()}


def _win_tables(rows: list[dict], methods, by: str, levels) -> list[str]:
    rates = win_rates(rows, methods, by)
    lines = []
    for level in levels:
        name = f"{level} views" if by == "n_train" else level
        lines += [
            "",
            f"**{name}** (row beats column, % of shared runs):",
            "",
            "| | " + " | ".join(LABELS[m] for m in methods) + " |",
            "|---|" + "---|" * len(methods),
        ]
        for a in methods:
            cells = []
            for b in methods:
                wins, total = rates.get((level, a, b), (0, 0))
                cells.append("–" if a == b or not total else f"{100 * wins / total:.0f}")
            lines.append(f"| {LABELS[a]} | " + " | ".join(cells) + " |")
    return lines


def medians(rows: list[dict]) -> dict:
    """{(cell, method): median m-SSIM over its seeds}."""
    groups = defaultdict(list)
    for row in rows:
        groups[_cell(row), row["method"]].append(row["m_ssim"])
    return {key: float(np.median(values)) for key, values in groups.items()}


def rift_target(rows: list[dict], model: str = "rift-n", rival: str = "fista") -> dict:
    """The share of cells where ``model``'s median m-SSIM is at least ``rival``'s, among
    the 10- and 30-view cells and among the ≤ 0 dB cells (the issue's target: half)."""
    med = medians(rows)
    out = {}
    for name, keep in (
        ("10 and 30 views", lambda cell: cell[1] in (10, 30)),
        ("≤ 0 dB", lambda cell: cell[2].endswith("dB") and float(cell[2][:-3]) <= 0),
    ):
        cells = {cell for cell, m in med if keep(cell)}
        pairs = [(med.get((c, model)), med.get((c, rival))) for c in cells]
        pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
        out[name] = (sum(a >= b for a, b in pairs), len(pairs))
    return out


def report(results: dict, volumes: dict, figures: bool, cfg: Config, out: Path) -> None:
    rows = judge(results["rows"])
    failures = [r for r in rows if r["failed"]]
    counted = [m for m in cfg.methods if m != BASELINE]
    asked = runs(cfg)
    lines = [
        f"# The stress grid, scale `{results['scale']}`",
        "",
        f"Forward {cfg.forward} m / inverse {cfg.inverse} m over ±{cfg.extent} m; radar of "
        f"{cfg.n_frequencies} frequencies and {cfg.n_antennas} × {cfg.n_antennas} antennas "
        f"at 10 m; {', '.join(map(str, cfg.views))} training views and {cfg.n_test} test "
        "views from the paper's 51 × 51 grid (one seeded draw, nested). Every method at "
        f"`fit`'s defaults ({_defaults_text(cfg)}). A cell is scene × views × noise; "
        + (
            f"each cell runs {cfg.seeds_per_cell} of the seeds {_seeds(cfg)}, rotated over "
            "the cells. "
            if cfg.seeds_per_cell
            else f"seeds {_seeds(cfg)} in every cell. "
        )
        + "A run fails if a metric is non-finite, its m-SSIM is below half its cell's "
        "median, or it is below 0.5 where the cell's best is ≥ 0.9; Kaczmarz (the "
        "paper's baseline) is not counted.",
        "",
        f"**Failures: {len(failures)} of {sum(r['method'] in counted for r in rows)} counted "
        f"runs** ({len(rows)} of the {len(asked)} runs asked for are done).",
        "",
    ]
    if len(rows) < len(asked):
        done = {(r["scene"], r["run"]) for r in rows}
        missing = defaultdict(list)  # (noise, views): the scenes whose cell is not complete
        for run in asked:
            key = (noise_name(run.options.get("snr_db")), run.n_train)
            if (run.scene, run.label) not in done and run.scene not in missing[key]:
                missing[key].append(run.scene)
        lines += ["Not run yet (`--resume` runs them), by noise and views:", ""]
        lines += [
            f"- {noise}, {n} views: "
            + ("every scene" if len(scenes) == len(cfg.scenes) else ", ".join(scenes))
            for (noise, n), scenes in missing.items()
        ]
        lines.append("")
    lines += ["By method, against the targets:", ""]  # a list of its own, not the one above
    for method, counts in _failures_by_method(rows, counted).items():
        lines.append(f"- {LABELS[method]}: {counts[0]} of {counts[1]} runs failed.")
    if "rift-n" in cfg.methods and "fista" in cfg.methods:
        for name, (wins, total) in rift_target(rows).items():
            if total:
                lines.append(
                    f"- RIFT(N)'s median m-SSIM is at least FISTA's in {wins} of {total} "
                    f"cells at {name} (target: half)."
                )
    retried = [r for r in rows if r.get("remedies")]
    collapsed = [r for r in rows if r.get("collapse")]
    lines.append(
        f"- RIFT's collapse check (docs/rift.md) retried {len(retried)} run(s); "
        f"{len(collapsed)} still collapsed after their retries."
    )
    lines += ["", "## Win rates", "", "Over every scene, views, noise and seed both ran:"]
    lines += _win_tables(rows, cfg.methods, None, ["all"])
    lines += ["", "### By views"]
    lines += _win_tables(rows, cfg.methods, "n_train", cfg.views)
    lines += ["", "### By noise"]
    lines += _win_tables(rows, cfg.methods, "noise", [noise_name(s) for s in cfg.snrs])
    lines += [
        "",
        "## Cells",
        "",
        "m-SSIM per cell: the median over its seeds, and failures.",
        "",
        "| scene | views | noise | " + " | ".join(LABELS[m] for m in cfg.methods) + " |",
        "|---|---|---|" + "---|" * len(cfg.methods),
    ]
    by_cell = defaultdict(list)
    for row in rows:
        by_cell[(*_cell(row), row["method"])].append(row)
    for scene, n, snr in itertools.product(cfg.scenes, cfg.views, cfg.snrs):
        cells = []
        for method in cfg.methods:
            group = by_cell.get((scene, n, noise_name(snr), method), [])
            if not group:
                cells.append("–")
                continue
            value = float(np.median([r["m_ssim"] for r in group]))
            failed = sum(bool(r["failed"]) for r in group)
            cells.append(f"{value:.3f}" + (f" **{failed} failed**" if failed else ""))
        if any(cell != "–" for cell in cells):
            lines.append(f"| {scene} | {n} | {noise_name(snr)} | " + " | ".join(cells) + " |")
    if failures:
        lines += ["", "## Failures", ""]
        lines += [f"- {r['scene']}, {r['run']}: {r['failed']}." for r in failures]
    columns = [("scene", lambda r: r["scene"]), ("run", lambda r: r["run"]), *METRIC_COLUMNS]
    lines += ["", "## Every run", "", table(rows, columns), ""]
    lines += [*figure_lines(("stability.png",), figures), environment_line(results), ""]
    write_atomic(out / "results.md", "\n".join(lines))
    if figures:
        _figure(rows, cfg, out / "stability.png")


def _seeds(cfg: Config) -> str:
    return ", ".join(map(str, cfg.seeds))


def _defaults_text(cfg: Config) -> str:
    text = 'every method on `support="auto"`; RIFT `prune=0.05`, `patience=10`'
    for method, budget in cfg.budgets:
        text += f"; {LABELS[method]} " + ", ".join(f"{k}={v}" for k, v in budget)
    return text


def _failures_by_method(rows: list[dict], methods) -> dict:
    out = {}
    for method in methods:
        group = [r for r in rows if r["method"] == method]
        if group:
            out[method] = (sum(bool(r["failed"]) for r in group), len(group))
    return out


def _figure(rows: list[dict], cfg: Config, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        len(cfg.views), len(cfg.snrs), figsize=(3.2 * len(cfg.snrs), 2.6 * len(cfg.views)),
        squeeze=False, sharey=True,
    )  # fmt: skip
    for (i, n), (j, snr) in itertools.product(enumerate(cfg.views), enumerate(cfg.snrs)):
        ax = axes[i, j]
        for k, method in enumerate(cfg.methods):
            offset = (k - (len(cfg.methods) - 1) / 2) * 0.15
            for x, scene in enumerate(cfg.scenes):
                group = [r for r in rows if _cell(r) == (scene, n, noise_name(snr))
                         and r["method"] == method]  # fmt: skip
                ys = [r["m_ssim"] for r in group]
                colours = ["red" if r["failed"] else f"C{k}" for r in group]
                ax.scatter([x + offset] * len(ys), ys, s=10, c=colours,
                           label=LABELS[method] if x == 0 else None)  # fmt: skip
        ax.set_xticks(range(len(cfg.scenes)), cfg.scenes, rotation=70, fontsize=6)
        ax.set_title(f"{n} views, {noise_name(snr)}", fontsize=8)
        ax.set_ylim(-0.1, 1.05)
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("m-SSIM (red: failed)")
    axes[0, 0].legend(fontsize=6)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def on_the_grid(
    name: str,
    cfg: Config,
    asked: list[Run],
    report,
    *,
    out: Path,
    scale: str,
    seed: int,
    resume: bool,
    progress: bool,
    part: tuple[int, int] | None = None,
) -> dict:
    """`execute` the runs ``asked`` on the stress grid's scenes, radar, grids and views of
    ``cfg`` (the stress grid's, or a study of its cells), with ``report(results, volumes,
    figures, cfg, out)``."""
    scenes = {scene: build_scene(scene, cfg.forward, cfg.extent) for scene in cfg.scenes}
    radar = cfg.radar()
    return execute(
        name,
        scale,
        cfg,
        scenes,
        asked,
        pool=rj.Viewpoints.grid(),
        radar=radar,
        inverse=cfg.inverse,
        n_test=cfg.n_test,
        seed=seed,
        out=Path(out),
        report=lambda *args: report(*args, cfg, Path(out)),
        resume=resume,
        progress=progress,
        part=part,
    )


def main(
    cfg: Config,
    *,
    out: Path,
    scale: str = "custom",
    seed: int = 0,
    resume: bool = False,
    progress: bool = True,
    part: tuple[int, int] | None = None,
) -> dict:
    """Every run of ``cfg``; the results dict as written to ``out/results.json``, with
    ``failures`` (an integer: the target is 0)."""
    results = on_the_grid(
        "stability", cfg, runs(cfg), report, out=out, scale=scale, seed=seed, resume=resume,
        progress=progress, part=part,
    )  # fmt: skip
    # the last report judged every row; results.json, written just before it, gets the verdicts
    results["failures"] = sum(bool(r["failed"]) for r in results["rows"])
    write_json(Path(out) / "results.json", results)
    print(f"{results['failures']} failures in {len(results['rows'])} runs; wrote results.md, "
          f"results.json, stability.png and reconstructions.npz to {out}/")  # fmt: skip
    return results


def cli(argv=None) -> dict:
    return command(argv, __doc__, SCALES, "stability", main)


if __name__ == "__main__":
    cli()
