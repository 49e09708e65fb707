"""Numerical stability: every method over seeds, noise, and scenes the paper never used.

    python -m experiments.stability [--scale quick|default|paper] [--out DIR] [--seed 0]
                                    [--resume] [--no-progress]

A grid of runs: the paper's six scenes (the weak target at 4:1) and a seeded family of
random-primitive scenes (`rift_jax.scenes.random_primitives`: boxes, balls, thin poles and
plates, some complex-valued), each reconstructed by RIFT(N), RIFT(S) and the strongest
least-squares solver (FISTA with its sparse prior: level with RIFT(N) at the paper's scale
on an H100), from noise-free data and at 20 and 0 dB SNR, with seeds 0-4 (the seed draws
the INR's start and the noise). The training and test viewpoints are one seeded draw
shared by every run.

A run **fails** if any metric is non-finite, or its m-SSIM is below half the median of all
runs (every method and seed) on its scene at its noise level. The target is 0 failures.
results.md reports each cell (scene × noise × method), RIFT's win rate against FISTA
(the share of scene × noise × seed where its m-SSIM is higher) and every failure.

Scales:
- quick (seconds; the tests): one random scene at ±2.4 m, 0.4 / 0.8 m, two seeds, RIFT(N)
  and FISTA, noise-free and 0 dB, a tiny radar;
- default (68 minutes measured on 2 shared CPU cores, 450 runs): ±4.8 m, forward 0.4 m,
  inverse 0.8 m (13³ unknowns; the grids nest, and the paper's scenes keep their parts),
  100 training and 20 test views, a radar of 16 frequencies and 8 × 8 antennas, RIFT 300
  steps of 10 views, FISTA at most 100 iterations. (Smaller radars or grids were tried
  and reconstruct less: docs/experiments.md.);
- paper: ±5 m at 0.2 / 0.4 m, 100 training views, the paper's radar, RIFT 1000 steps.

Writes results.json (with a top-level integer ``failures``), results.md, stability.png
(m-SSIM per scene, method and seed, one panel per noise level) and reconstructions.npz
into ``--out``.
"""

from __future__ import annotations

import dataclasses
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
    noise_name,
    rift_options,
    save_figure,
    table,
    write_atomic,
    write_json,
)

LABELS = {"rift-n": "RIFT(N)", "rift-s": "RIFT(S)", "fista": "FISTA"}
BASELINE = "fista"  # the strongest least squares (docs/solvers.md)


@dataclasses.dataclass(frozen=True)
class Config:
    scenes: tuple[str, ...]  # `rift_jax.scenes` builders, or "random-K" (seed K)
    seeds: tuple[int, ...]
    methods: tuple[str, ...]  # `fit` methods
    snrs: tuple[float | None, ...]  # SNR in dB; None: noise-free
    extent: float  # half-width of the scene (m)
    forward: float  # synthesis granularity (m)
    inverse: float  # reconstruction granularity (m)
    n_train: int
    n_test: int
    n_frequencies: int
    n_antennas: int  # transmitters, and receivers
    rift_steps: int  # optimizer steps of 10 views per RIFT run
    ls_iterations: int  # FISTA's budget (it stops once converged, tol 1e-3)


RANDOM_SCENES = tuple(f"random-{k}" for k in range(4))
SCALES = {
    "quick": Config(
        ("random-0",), (0, 1), ("rift-n", "fista"), (None, 0.0), 2.4, 0.4, 0.8,
        n_train=10, n_test=3, n_frequencies=8, n_antennas=4, rift_steps=10, ls_iterations=10,
    ),
    "default": Config(
        PAPER_SCENES + RANDOM_SCENES, (0, 1, 2, 3, 4), ("rift-n", "rift-s", "fista"),
        (None, 20.0, 0.0), 4.8, 0.4, 0.8, n_train=100, n_test=20, n_frequencies=16,
        n_antennas=8, rift_steps=300, ls_iterations=100,
    ),
    "paper": Config(
        PAPER_SCENES + RANDOM_SCENES, (0, 1, 2, 3, 4), ("rift-n", "rift-s", "fista"),
        (None, 20.0, 0.0), 5.0, 0.2, 0.4, n_train=100, n_test=100, n_frequencies=100,
        n_antennas=16, rift_steps=1000, ls_iterations=100,
    ),
}  # fmt: skip


def label(method: str, snr: float | None, seed: int) -> str:
    return f"{LABELS[method]} {noise_name(snr)} seed {seed}"


def runs(cfg: Config) -> list[Run]:
    out = []
    for scene in cfg.scenes:
        for snr in cfg.snrs:
            for method in cfg.methods:
                if method.startswith("rift"):
                    options = rift_options(cfg.n_train, cfg.rift_steps)
                else:
                    options = {"iterations": cfg.ls_iterations}
                if snr is not None:
                    options = options | {"snr_db": snr}
                for seed in cfg.seeds:
                    out.append(
                        Run(scene, label(method, snr, seed), method, cfg.n_train, options, seed)
                    )
    return out


def judge(rows: list[dict]) -> list[dict]:
    """Each row with ``noise``, ``cell_median`` (the median m-SSIM of every run on its scene
    at its noise level) and ``failed`` (None, or why)."""
    cells = defaultdict(list)
    for row in rows:
        row["noise"] = noise_name(row["options"].get("snr_db"))
        cells[row["scene"], row["noise"]].append(row["m_ssim"])
    for row in rows:
        finite = np.isfinite(list(cells[row["scene"], row["noise"]]))
        median = float(np.median(np.asarray(cells[row["scene"], row["noise"]])[finite]))
        row["cell_median"] = median
        values = [row[k] for k in ("m_ssim", "m_cos", "t_iou", "p_rmse", "residual")]
        if not np.all(np.isfinite(values)):
            row["failed"] = "non-finite metric"
        elif row["m_ssim"] < 0.5 * median:
            row["failed"] = f"m-SSIM {row['m_ssim']:.3f} < half the median {median:.3f}"
        else:
            row["failed"] = None
    return rows


def win_rate(rows: list[dict], method: str) -> tuple[int, int]:
    """(wins, comparisons) of ``method`` against the baseline in m-SSIM, over every scene,
    noise level and seed that both ran."""
    ssim = {(r["scene"], r["noise"], r["method"], r["seed"]): r["m_ssim"] for r in rows}
    wins = total = 0
    for (scene, noise, m, seed), value in ssim.items():
        if m == method and (key := (scene, noise, BASELINE, seed)) in ssim:
            total += 1
            wins += value > ssim[key]
    return wins, total


def report(results: dict, volumes: dict, figures: bool, cfg: Config, out: Path) -> None:
    rows = judge(results["rows"])
    failures = [r for r in rows if r["failed"]]
    lines = [
        f"# Numerical stability, scale `{results['scale']}`",
        "",
        f"Forward {cfg.forward} m / inverse {cfg.inverse} m over ±{cfg.extent} m; radar of "
        f"{cfg.n_frequencies} frequencies and {cfg.n_antennas} × {cfg.n_antennas} antennas "
        f"at 10 m; {cfg.n_train} training and {cfg.n_test} test views from the paper's "
        f"51 × 51 grid; RIFT default recipe, {cfg.rift_steps} steps of 10 views; FISTA at "
        f"most {cfg.ls_iterations} iterations (default sparsity). Seeds "
        f"{', '.join(map(str, cfg.seeds))} (the INR's start and the noise). A run fails if a "
        "metric is non-finite or its m-SSIM is below half the median of every run on its "
        "scene at its noise level.",
        "",
        f"**Failures: {len(failures)} of {len(rows)} runs.**",
        "",
    ]
    for method in cfg.methods:
        if method != BASELINE:
            wins, total = win_rate(rows, method)
            if total:
                lines.append(
                    f"- {LABELS[method]} beats {LABELS[BASELINE]} in {wins} of {total} "
                    f"(scene, noise, seed) ({100 * wins / total:.0f} %)."
                )
    retried = [r for r in rows if r.get("remedies")]
    collapsed = [r for r in rows if r.get("collapse")]
    lines.append(
        f"- RIFT's collapse check (docs/rift.md) retried {len(retried)} run(s); "
        f"{len(collapsed)} still collapsed after their retries."
    )
    lines += [f"  - {r['scene']}, {r['run']}: {r['collapse']}." for r in collapsed]
    lines += [
        "",
        "m-SSIM per cell: median [min, max] over seeds, and failures.",
        "",
        "| scene | noise | " + " | ".join(LABELS[m] for m in cfg.methods) + " |",
        "|---|---|" + "---|" * len(cfg.methods),
    ]
    by_cell = defaultdict(list)
    for row in rows:
        by_cell[row["scene"], row["noise"], row["method"]].append(row)
    for scene in cfg.scenes:
        for snr in cfg.snrs:
            cells = []
            for method in cfg.methods:
                group = by_cell.get((scene, noise_name(snr), method), [])
                if not group:
                    cells.append("–")
                    continue
                values = np.array([r["m_ssim"] for r in group])
                failed = sum(bool(r["failed"]) for r in group)
                cells.append(
                    f"{np.median(values):.3f} [{values.min():.3f}, {values.max():.3f}]"
                    + (f" **{failed} failed**" if failed else "")
                )
            lines.append(f"| {scene} | {noise_name(snr)} | " + " | ".join(cells) + " |")
    if failures:
        lines += ["", "## Failures", ""]
        lines += [f"- {r['scene']}, {r['run']}: {r['failed']}." for r in failures]
    columns = [("scene", lambda r: r["scene"]), ("run", lambda r: r["run"]), *METRIC_COLUMNS]
    lines += ["", "## Every run", "", table(rows, columns), "", environment_line(results), ""]
    write_atomic(out / "results.md", "\n".join(lines))
    if figures:
        _figure(rows, cfg, out / "stability.png")


def _figure(rows: list[dict], cfg: Config, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        1, len(cfg.snrs), figsize=(4.5 * len(cfg.snrs), 3.6), squeeze=False, sharey=True
    )
    for ax, snr in zip(axes[0], cfg.snrs, strict=True):
        for k, method in enumerate(cfg.methods):
            offset = (k - (len(cfg.methods) - 1) / 2) * 0.22
            for i, scene in enumerate(cfg.scenes):
                group = [
                    r
                    for r in rows
                    if r["scene"] == scene and r["method"] == method
                    and r["noise"] == noise_name(snr)
                ]  # fmt: skip
                ys = [r["m_ssim"] for r in group]
                colours = ["red" if r["failed"] else f"C{k}" for r in group]
                ax.scatter([i + offset] * len(ys), ys, s=12, c=colours,
                           label=LABELS[method] if i == 0 else None)  # fmt: skip
        ax.set_xticks(range(len(cfg.scenes)), cfg.scenes, rotation=60, fontsize=7)
        ax.set(title=noise_name(snr), ylim=(-0.1, 1.05))
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("m-SSIM (red: failed)")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main(
    cfg: Config,
    *,
    out: Path,
    scale: str = "custom",
    seed: int = 0,
    resume: bool = False,
    progress: bool = True,
) -> dict:
    """Every run of ``cfg``; the results dict as written to ``out/results.json``, with
    ``failures`` (an integer: the target is 0)."""
    scenes = {name: build_scene(name, cfg.forward, cfg.extent) for name in cfg.scenes}
    radar = rj.Radar(n_frequencies=cfg.n_frequencies, n_tx=cfg.n_antennas, n_rx=cfg.n_antennas)
    results = execute(
        "stability",
        scale,
        cfg,
        scenes,
        runs(cfg),
        pool=rj.Viewpoints.grid(),
        radar=radar,
        inverse=cfg.inverse,
        n_test=cfg.n_test,
        seed=seed,
        out=Path(out),
        report=lambda *args: report(*args, cfg, Path(out)),
        resume=resume,
        progress=progress,
    )
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
