"""Model mismatch: truths that no reconstruction grid holds.

    python -m experiments.mismatch [--scale quick|default|paper] [--out DIR] [--seed 0]
                                   [--resume] [--no-progress] [--part K/N]

The paper's protocol synthesises data on a grid twice finer than the one it reconstructs
on, so an eighth of the scatterers sit on the inverse grid's points. Here less of the
truth does, or none of it:

- **points**: ``n_scatterers`` point scatterers at seeded random continuous positions in
  ±0.7·extent (almost surely off every grid), with random complex amplitudes (magnitude in
  [0.25, 1], phase uniform), synthesised exactly from their positions
  (`rift_jax.PointScatterers`). The image metrics compare against each amplitude spread
  trilinearly onto the 8 inverse-grid points around it (`PointScatterers.resample`);
  p-RMSE on unseen views compares against the exact point synthesis.
- **snapped**, the control: the same scatterers each moved to its nearest inverse-grid
  point, so that the grid holds them exactly. What a method loses between "snapped" and
  "points" is the mismatch's doing; what it misses on "snapped" is its own.
- **fine**: a scene on a grid ``fine`` much finer than every reconstruction grid (4-8× at
  the default scale; the grids nest, so 1/64 to 1/512 of its voxels are inverse points),
  synthesised on that grid and resampled to the inverse grid for the image metrics, as in
  the paper's protocol.

Each truth is reconstructed on every grid of ``resolutions`` from noise-free data and at
20 and 0 dB SNR by RIFT(N), RIFT(S), RIFT(N) trained coarse to fine (its last half of the
steps on the grid of half the inverse granularity: `fit`'s ``train_granularity``), FISTA,
LSMR and Kaczmarz; and, at the default scale, by point scatterers at continuous positions
(``method="points"``, at most twice ``n_scatterers`` rounds), on the point truths only and
once per noise level: it uses no grid, so it runs with the first of ``resolutions`` (its
image metrics spread the points onto that grid, as the truth's are). It is not for
extended bodies (the "fine" truth), and too slow for the paper's scale. The training and
test viewpoints are one seeded draw shared by every run; ``--seed`` also draws the
scatterers, the INRs' starts and the noise.

Scales:
- quick (seconds; the tests): ±2.4 m, a 0.8 m grid, 8 points and a random scene at
  0.2 m, noise-free and 0 dB, RIFT(N) and LSMR, a tiny radar;
- default (~10 minutes on 2 shared CPU cores for 108 grid runs, ~10 more for 6 points
  runs): ±1.8 m, grids 0.6 and 0.3 m (7³ and 13³ unknowns), 8 points and a
  random-primitive scene on a 0.075 m grid (8× and 4× finer), 40 training and 10 test
  views, a radar of 16 frequencies and 8 × 8 antennas,
  RIFT 150 steps of 10 views, FISTA and LSMR at most 30 iterations, Kaczmarz at most 5
  sweeps (each stops once converged);
- paper: ±4.8 m (so that the 0.8 m grid spans it), grids 0.8 and 0.4 m, 40 points and a
  random scene at 0.1 m, 100 training and 100 test views, the paper's radar, RIFT 1000
  steps (hours to days on a CPU).

Writes results.json, results.md (per truth, each metric as method × resolution × noise),
mismatch.png (m-SSIM, t-IoU and p-RMSE against resolution, one line per method, a panel
per truth and noise level) and reconstructions.npz into ``--out``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

import rift_jax as rj

from .runner import (
    METRIC_COLUMNS,
    Run,
    build_scene,
    command,
    environment_line,
    execute,
    figure_lines,
    noise_name,
    rift_options,
    save_figure,
    table,
    write_atomic,
)

LABELS = {
    "rift-n": "RIFT(N)",
    "rift-s": "RIFT(S)",
    "rift-n-fine": "RIFT(N) fine",
    "fista": "FISTA",
    "lsmr": "LSMR",
    "kaczmarz": "Kaczmarz",
    "points": "Points",
}
"""The methods this study knows: `fit` methods, and "rift-n-fine", RIFT(N) trained coarse
to fine (``train_granularity`` = half the inverse granularity)."""
TRUTHS = {
    "points": "off-grid point scatterers",
    "snapped": "the same point scatterers on the inverse grid (the control)",
    "fine": "a scene on a finer grid",
}
METRICS = {
    "m_ssim": ("m-SSIM", "{:.3f}"),
    "m_cos": ("m-COS", "{:.3f}"),
    "t_iou": ("t-IoU", "{:.3f}"),
    "p_rmse": ("p-RMSE (rad)", "{:.3f}"),
    "residual": ("residual", "{:.3f}"),
}


@dataclasses.dataclass(frozen=True)
class Config:
    truths: tuple[str, ...]  # keys of TRUTHS
    resolutions: tuple[float, ...]  # inverse granularities (m), each nesting ``fine``'s grid
    methods: tuple[str, ...]  # keys of LABELS
    snrs: tuple[float | None, ...]  # SNR in dB; None: noise-free
    extent: float  # half-width of the box (m)
    n_scatterers: int  # point scatterers in the "points" truth
    fine_scene: str  # the "fine" truth: "random-K" (random_primitives seed K) or a paper scene
    fine: float  # its granularity (m)
    n_train: int
    n_test: int
    n_frequencies: int
    n_antennas: int  # transmitters, and receivers
    rift_steps: int  # optimizer steps of 10 views per RIFT run
    ls_iterations: int  # FISTA's and LSMR's budget (each stops once converged, tol 1e-3)
    sweeps: int  # Kaczmarz's budget (stops once converged, tol 1e-3)


SCALES = {
    "quick": Config(
        ("points", "snapped", "fine"), (0.8,), ("rift-n", "lsmr"), (None, 0.0), 2.4, 8,
        "random-0", 0.2, n_train=10, n_test=3, n_frequencies=8, n_antennas=4, rift_steps=10,
        ls_iterations=5, sweeps=1,
    ),
    "default": Config(
        tuple(TRUTHS), (0.6, 0.3), tuple(LABELS), (None, 20.0, 0.0), 1.8, 8, "random-0",
        0.075, n_train=40, n_test=10, n_frequencies=16, n_antennas=8, rift_steps=150,
        ls_iterations=30, sweeps=5,
    ),
    "paper": Config(
        tuple(TRUTHS), (0.8, 0.4), tuple(m for m in LABELS if m != "points"),
        (None, 20.0, 0.0), 4.8, 40, "random-0",
        0.1, n_train=100, n_test=100, n_frequencies=100, n_antennas=16, rift_steps=1000,
        ls_iterations=100, sweeps=100,
    ),
}  # fmt: skip


def point_scatterers(count: int, extent: float, seed: int) -> rj.PointScatterers:
    """``count`` scatterers at uniform random positions in ±0.7·``extent`` (as
    `random_primitives` places its objects), magnitudes in [0.25, 1], phases uniform."""
    if not isinstance(count, int) or count < 1:
        raise ValueError(f"point_scatterers: `count` must be an integer ≥ 1, got {count!r}.")
    rng = np.random.default_rng(seed)
    points = rng.uniform(-0.7 * extent, 0.7 * extent, (count, 3))
    amplitude = rng.uniform(0.25, 1.0, count) * np.exp(1j * rng.uniform(-np.pi, np.pi, count))
    return rj.PointScatterers(points, amplitude, extent)


def snapped(scatterers: rj.PointScatterers, granularity: float) -> rj.PointScatterers:
    """``scatterers`` each moved to the nearest point of the grid of ``granularity`` (the
    grid's own model: what the same scatterers would give if the grid held them)."""
    axis = rj.Scene.empty(scatterers.extent, granularity).axis()
    index = np.clip(np.round((scatterers.points - axis[0]) / granularity), 0, len(axis) - 1)
    return rj.PointScatterers(axis[index.astype(int)], scatterers.reflectivity, scatterers.extent)


def key(truth: str, granularity: float) -> str:
    """The runner's scene name of ``truth`` reconstructed on the grid of ``granularity``."""
    return f"{truth} @ {granularity:g} m"


def label(method: str, snr: float | None) -> str:
    return f"{LABELS[method]} {noise_name(snr)}"


def options(method: str, granularity: float, cfg: Config) -> dict:
    """`fit` options of ``method`` on the grid of ``granularity``."""
    if method == "points":  # on no grid: no support, not even the runner's shared one
        return {"max_points": 2 * cfg.n_scatterers, "support": None}
    whole = {"support": None}  # every grid point: a truth off the grid has no support
    if method.startswith("rift"):
        out = rift_options(cfg.n_train, cfg.rift_steps) | whole | {"prune": None}
        if method == "rift-n-fine":  # the last half of the steps on a grid twice finer
            out |= {"train_granularity": granularity / 2}
        return out
    if method == "kaczmarz":
        return {"iterations": cfg.sweeps, "tol": 1e-3} | whole
    return {"iterations": cfg.ls_iterations} | whole


def runs(cfg: Config) -> list[Run]:
    out = []
    for truth in cfg.truths:
        for granularity in cfg.resolutions:
            for snr in cfg.snrs:
                for method in cfg.methods:
                    if method == "points" and (
                        truth == "fine" or granularity != cfg.resolutions[0]
                    ):  # on no grid, and for points: once per point truth and noise
                        continue
                    fit_options = options(method, granularity, cfg)
                    if snr is not None:
                        fit_options |= {"snr_db": snr}
                    fit_method = "rift-n" if method == "rift-n-fine" else method
                    scene = key(truth, granularity)
                    out.append(Run(scene, label(method, snr), fit_method, cfg.n_train, fit_options))
    return out


def _cells(rows: list[dict]) -> dict:
    """{(truth, granularity, noise, method label): row}."""
    out = {}
    for row in rows:
        truth, granularity = row["scene"].split(" @ ")
        method = row["run"].removesuffix(" " + noise_name(row["options"].get("snr_db")))
        noise = noise_name(row["options"].get("snr_db"))
        out[truth, float(granularity.removesuffix(" m")), noise, method] = row
    return out


def report(results: dict, volumes: dict, figures: bool, cfg: Config, out: Path) -> None:
    rows = results["rows"]
    cells = _cells(rows)
    lines = [
        f"# Model mismatch, scale `{results['scale']}`",
        "",
        f"Truths over ±{cfg.extent} m that no reconstruction grid holds: "
        f"{cfg.n_scatterers} point scatterers at random continuous positions (synthesised "
        "exactly; on the inverse grid, for the image metrics, each amplitude spread "
        f"trilinearly onto its 8 neighbouring points) and `{cfg.fine_scene}` on a "
        f"{cfg.fine} m grid (resampled to the inverse grid). Reconstruction grids "
        f"{', '.join(f'{g:g} m' for g in cfg.resolutions)}; radar of {cfg.n_frequencies} "
        f"frequencies and {cfg.n_antennas} × {cfg.n_antennas} antennas at 10 m; "
        f"{cfg.n_train} training and {cfg.n_test} test views from the paper's 51 × 51 "
        f"grid. RIFT default recipe, {cfg.rift_steps} steps of 10 views (RIFT(N) fine: the "
        "last half on the grid of half the inverse granularity, scored on the inverse grid; "
        f"its p-RMSE from the finer grid); FISTA and LSMR at most {cfg.ls_iterations} "
        f"iterations, Kaczmarz at most {cfg.sweeps} sweeps (each stopped once converged, "
        "its best iterate). p-RMSE: phase error on the unseen views (random phase: 1.81 rad); "
        "residual: relative data residual on the training views.",
        "",
    ]
    methods = [LABELS[m] for m in cfg.methods]
    columns = [(g, noise_name(s)) for g in cfg.resolutions for s in cfg.snrs]
    for truth in cfg.truths:
        lines += [f"## {TRUTHS[truth]} (`{truth}`)", ""]
        for metric, (name, fmt) in METRICS.items():
            lines += [
                f"**{name}**",
                "",
                "| method | " + " | ".join(f"{g:g} m, {n}" for g, n in columns) + " |",
                "|---|" + "---|" * len(columns),
            ]
            for method in methods:
                values = []
                for g, noise in columns:
                    row = cells.get((truth, g, noise, method))
                    values.append("–" if row is None else fmt.format(row[metric]))
                lines.append(f"| {method} | " + " | ".join(values) + " |")
            lines.append("")
    every = [("scene", lambda r: r["scene"]), ("run", lambda r: r["run"]), *METRIC_COLUMNS]
    lines += ["## Every run", "", table(rows, every), ""]
    lines += [*figure_lines(("mismatch.png",), figures), environment_line(results), ""]
    write_atomic(out / "results.md", "\n".join(lines))
    if figures:
        _figure(cells, cfg, out / "mismatch.png")


def _figure(cells: dict, cfg: Config, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = ("m_ssim", "t_iou", "p_rmse")
    panels = [(truth, metric) for truth in cfg.truths for metric in shown]
    fig, axes = plt.subplots(
        len(panels), len(cfg.snrs), figsize=(3.6 * len(cfg.snrs), 2.6 * len(panels)),
        squeeze=False, sharex=True, sharey="row",
    )  # fmt: skip
    for i, (truth, metric) in enumerate(panels):
        for j, snr in enumerate(cfg.snrs):
            ax = axes[i, j]
            for k, method in enumerate(cfg.methods):
                points = [
                    (g, cells[key_][metric])
                    for g in cfg.resolutions
                    if (key_ := (truth, g, noise_name(snr), LABELS[method])) in cells
                ]
                if points:
                    xs, ys = zip(*points, strict=True)
                    ax.plot(xs, ys, "o-", color=f"C{k}", label=LABELS[method])
            if metric == "p_rmse":
                ax.axhline(np.pi / np.sqrt(3), color="grey", lw=0.8, ls=":")  # random phase
            ax.set_title(f"{truth}, {noise_name(snr)}", fontsize=9)
            ax.set_ylabel(METRICS[metric][0], fontsize=8)
            ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("inverse granularity (m)")
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
    part: tuple[int, int] | None = None,
) -> dict:
    """Every run of ``cfg``; the results dict as written to ``out/results.json``."""
    unknown = set(cfg.truths) - set(TRUTHS)
    if unknown:
        raise ValueError(f"mismatch: `cfg.truths` holds unknown {sorted(unknown)}.")
    points = point_scatterers(cfg.n_scatterers, cfg.extent, seed)
    fine = build_scene(cfg.fine_scene, cfg.fine, cfg.extent) if "fine" in cfg.truths else None
    truths = {"points": lambda g: points, "snapped": lambda g: snapped(points, g)}
    truths["fine"] = lambda g: fine
    scenes = {key(t, g): truths[t](g) for t in cfg.truths for g in cfg.resolutions}
    radar = rj.Radar(n_frequencies=cfg.n_frequencies, n_tx=cfg.n_antennas, n_rx=cfg.n_antennas)
    results = execute(
        "mismatch",
        scale,
        cfg,
        scenes,
        runs(cfg),
        pool=rj.Viewpoints.grid(),
        radar=radar,
        inverse={key(t, g): g for t in cfg.truths for g in cfg.resolutions},
        n_test=cfg.n_test,
        seed=seed,
        out=Path(out),
        report=lambda *args: report(*args, cfg, Path(out)),
        resume=resume,
        progress=progress,
        per_run=("methods",),  # a method added since runs alone on --resume
        part=part,
    )
    print(f"wrote results.md, results.json, mismatch.png and reconstructions.npz to {out}/")
    return results


def cli(argv=None) -> dict:
    return command(argv, __doc__, SCALES, "mismatch", main)


if __name__ == "__main__":
    cli()
