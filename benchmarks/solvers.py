"""Run time against error for every least-squares solver (issue: solvers, metrics, fit).

    python -m benchmarks.solvers [--scale quick|default|paper] [--out DIR] [--seed 0]

The cube (2 m, ρ = 1) is synthesised on the forward grid and reconstructed on the 2x coarser
inverse grid (nested, NOTES.md) from LS-100/200/500/1000 training viewpoints drawn from the
paper's 2,601; 100 other viewpoints are held out for p-RMSE. Each solver gets the iteration
budget of the scale. Prints and writes (atomically) ``solvers.md`` (table beside the
paper's LS rows), ``solvers.json`` and ``solvers.png`` (residual against wall time, and
m-SSIM against wall time). Also times Kaczmarz blocks at the paper's resolution
(V = 26³) to extrapolate the paper's LS-1000 x 100 sweeps, and prints this machine's
complex matmul rate for reading the times.

Scales (the paper radar throughout: 100 frequencies, 16 x 16 antennas):
- quick: forward 1.0 m / inverse 2.0 m over ±4 m, LS-10/20, tiny budgets (seconds; tests);
- default: forward 0.4 m / inverse 0.8 m over ±4.8 m (V = 13³), small budgets (each
  solver a few passes over the data) that finish in about half an hour on a 2-core CPU;
- paper: forward 0.2 m / inverse 0.4 m (V = 26³), the paper's 100 Kaczmarz sweeps: hours.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

import rift_jax as rj
from experiments._output import save_figure, write_atomic, write_json
from experiments._runner import fit_and_evaluate

from ._timing import complex_matmul_rate

# Paper Table 1 (cube), LS rows: m-SSIM, m-COS, t-IoU, p-RMSE.
PAPER = {
    100: (0.0704, 0.5698, 0.0578, 0.0155),
    200: (0.0908, 0.6689, 0.1663, 0.0153),
    500: (0.1128, 0.7822, 0.1243, 0.0151),
    1000: (0.1706, 0.8511, 0.2183, 0.0150),
}


@dataclasses.dataclass(frozen=True)
class Config:
    extent: float
    forward: float  # forward (synthesis) granularity, m
    inverse: float  # reconstruction granularity, m
    n_train: tuple[int, ...]
    n_test: int
    budgets: dict  # method -> solver options
    paper_blocks: int  # Kaczmarz blocks timed at the paper's resolution (0: skip)


SCALES = {
    "quick": Config(
        extent=4.0,
        forward=1.0,
        inverse=2.0,
        n_train=(10, 20),
        n_test=5,
        budgets={
            "kaczmarz": {"iterations": 2},
            "lsmr": {"iterations": 4, "check_every": 2, "tol": 0.0},
            "gauss-newton": {"iterations": 2, "inner": 2, "tol": 0.0},
            "fista": {"iterations": 4, "power_iterations": 2, "tol": 0.0},
        },
        paper_blocks=0,
    ),
    "default": Config(
        # ±4.8 m so that the 0.8 m inverse grid nests in the 0.4 m forward grid (0.8 m does
        # not divide 10 m). docs/results/solvers_default was measured at ±5 m, not nested.
        extent=4.8,
        forward=0.4,
        inverse=0.8,
        n_train=(100, 200, 500, 1000),
        n_test=100,
        budgets={
            "kaczmarz": {"iterations": 3, "tol": 0.0},
            "lsmr": {"iterations": 10, "check_every": 5, "tol": 0.0},
            "gauss-newton": {"iterations": 2, "inner": 3, "tol": 0.0},
            "fista": {"iterations": 8, "power_iterations": 3, "tol": 0.0},
        },
        paper_blocks=16,
    ),
    "paper": Config(
        extent=5.0,
        forward=0.2,
        inverse=0.4,
        n_train=(100, 200, 500, 1000),
        n_test=100,
        budgets={
            "kaczmarz": {"iterations": 100, "tol": 0.0},
            "lsmr": {"iterations": 100, "check_every": 10, "tol": 0.0},
            "gauss-newton": {"iterations": 10, "inner": 10, "tol": 0.0},
            "fista": {"iterations": 100, "power_iterations": 10, "tol": 0.0},
        },
        paper_blocks=16,
    ),
}


def run(cfg: Config, seed: int = 0, progress: bool = True, checkpoint=None) -> dict:
    """Every (LS-n, solver) run of ``cfg``; ``checkpoint(results)`` after each one, so an
    interrupted benchmark keeps what it measured."""
    radar = rj.Radar()
    scene = rj.scenes.cube(cfg.forward, extent=cfg.extent)
    pool = rj.Viewpoints.grid()
    rows, histories = [], {}
    for n in cfg.n_train:
        train, test = pool.split(n, cfg.n_test, seed=seed)
        for method, options in cfg.budgets.items():
            result, metrics = fit_and_evaluate(
                scene,
                train,
                test,
                radar=radar,
                method=method,
                granularity=cfg.inverse,
                seed=seed,
                progress=progress,
                options=options,
            )
            rows.append(
                {"n_train": n, "method": method, "seconds": result.seconds, **metrics}
                | {"iterations": len(result.history), "options": options}
            )
            histories[f"{method}/{n}"] = {
                "seconds": result.history.seconds.tolist(),
                "residual": result.history.residual.tolist(),
            }
            print(_row_md(rows[-1]), flush=True)
            if checkpoint:
                checkpoint({"rows": rows, "histories": histories})
    return {"rows": rows, "histories": histories}


def paper_kaczmarz_cost(blocks: int, seed: int = 0) -> dict:
    """Seconds per Kaczmarz block (one viewpoint) at the paper's inverse grid (V = 26³),
    from one timed sweep over ``blocks`` viewpoints after a compiling one."""
    radar = rj.Radar()
    grid = rj.Scene.empty(5.0, 0.4)
    views, _ = rj.Viewpoints.grid().split(blocks, 1, seed=seed)  # split needs a test set
    operator = rj.grt_operator(radar, views, grid.points())
    signal = np.asarray(rj.synthesize(rj.scenes.cube(0.2), views, radar).signal)
    solution = rj.solvers.kaczmarz(operator, signal, iterations=2, progress=False)
    sweep = float(np.diff(solution.history.seconds)[-1])
    per_block = sweep / blocks
    return {
        "n_points": grid.points().shape[0],
        "seconds_per_block": per_block,
        "ls1000_sweep_seconds": 1000 * per_block,
        "ls1000_100_sweeps_hours": 100 * 1000 * per_block / 3600,
        "sweeps_in_10_minutes_ls1000": 600 / (1000 * per_block),
    }


def _row_md(row: dict) -> str:
    return (
        f"| LS-{row['n_train']} | {row['method']} | {row['iterations']} | "
        f"{row['m_ssim']:.4f} | {row['m_cos']:.4f} | {row['t_iou']:.4f} | {row['p_rmse']:.4f} | "
        f"{row['residual']:.4f} | {row['seconds']:.1f} |"
    )


def report(cfg: Config, scale: str, results: dict, matmul: float, paper_cost: dict | None) -> str:
    lines = [
        f"# Solvers on the cube ({scale} scale)",
        "",
        f"Forward grid {cfg.forward} m, inverse grid {cfg.inverse} m over ±{cfg.extent} m; "
        f"{cfg.n_test} held-out viewpoints for p-RMSE; paper radar. This machine's complex64 "
        f"matmul rate in the same run: {matmul:.2f} G/s. Seconds include compilation.",
        "",
        "| data | method | iterations | m-SSIM | m-COS | t-IoU | p-RMSE (rad) | residual | s |",
        "|---|---|---|---|---|---|---|---|---|",
        *(_row_md(r) for r in results["rows"]),
        "",
        "Paper (Table 1, cube, block-Kaczmarz x 100 iterations, forward 0.2 m / inverse 0.4 m):",
        "",
        "| data | m-SSIM | m-COS | t-IoU | p-RMSE |",
        "|---|---|---|---|---|",
        *(
            f"| LS-{n} | " + " | ".join(f"{v:.4f}" for v in vals) + " |"
            for n, vals in PAPER.items()
        ),
    ]
    if paper_cost:
        lines += [
            "",
            f"Kaczmarz at the paper's inverse grid (V = {paper_cost['n_points']}): "
            f"{paper_cost['seconds_per_block']:.3f} s per block (viewpoint), so one LS-1000 "
            f"sweep takes {paper_cost['ls1000_sweep_seconds']:.0f} s and the paper's 100 sweeps "
            f"{paper_cost['ls1000_100_sweeps_hours']:.1f} h; 10 minutes buy "
            f"{paper_cost['sweeps_in_10_minutes_ls1000']:.1f} sweeps.",
        ]
    return "\n".join(lines) + "\n"


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    colours = {m: f"C{i}" for i, m in enumerate(("kaczmarz", "lsmr", "gauss-newton", "fista"))}
    sizes = sorted({r["n_train"] for r in results["rows"]})
    styles = dict(zip(sizes, ("-", "--", "-.", ":"), strict=False))
    for key, h in results["histories"].items():
        method, n = key.split("/")
        left.plot(h["seconds"], h["residual"], styles[int(n)], color=colours[method], marker=".")
    for method, colour in colours.items():
        rows = [r for r in results["rows"] if r["method"] == method]
        right.plot(
            [r["seconds"] for r in rows],
            [r["m_ssim"] for r in rows],
            "o-",
            color=colour,
            label=method,
        )
        for r in rows:
            right.annotate(str(r["n_train"]), (r["seconds"], r["m_ssim"]), fontsize=7)
    left.set(
        xscale="log",
        xlabel="wall time (s)",
        ylabel="relative data residual",
        title="residual during the run (line style: LS-n)",
    )
    right.set(
        xscale="log",
        xlabel="wall time (s)",
        ylabel="m-SSIM",
        title="scene quality against run time (labels: LS-n)",
    )
    right.legend()
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description="Least-squares solvers: run time vs error")
    parser.add_argument("--scale", choices=sorted(SCALES), default="default")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--sizes", type=int, nargs="+", help="LS-n subset (default: scale's)")
    parser.add_argument("--methods", nargs="+", choices=sorted(SCALES["paper"].budgets))
    args = parser.parse_args(argv)
    cfg = SCALES[args.scale]
    if args.sizes:
        cfg = dataclasses.replace(cfg, n_train=tuple(args.sizes))
    if args.methods:
        cfg = dataclasses.replace(cfg, budgets={m: cfg.budgets[m] for m in args.methods})
    out = args.out or Path("docs/results") / f"solvers_{args.scale}"

    matmul = complex_matmul_rate()
    print(f"complex64 matmul: {matmul:.2f} G/s", flush=True)
    start = time.perf_counter()
    paper_cost = None

    def write(results):
        record = {
            "scale": args.scale,
            "config": dataclasses.asdict(cfg),
            "matmul_gflops": matmul,
            "paper_kaczmarz_cost": paper_cost,
            "total_seconds": time.perf_counter() - start,
            "versions": {"rift_jax": rj.__version__, "python": sys.version.split()[0]},
            **results,
        }
        write_atomic(out / "solvers.md", report(cfg, args.scale, results, matmul, paper_cost))
        write_json(out / "solvers.json", json.loads(json.dumps(record, default=float)))
        plot(results, out / "solvers.png")
        return record

    results = run(cfg, seed=args.seed, progress=not args.no_progress, checkpoint=write)
    paper_cost = paper_kaczmarz_cost(cfg.paper_blocks, args.seed) if cfg.paper_blocks else None
    record = write(results)
    print(report(cfg, args.scale, results, matmul, paper_cost))
    print(f"wrote {out}/solvers.md, solvers.json, solvers.png")
    return record


if __name__ == "__main__":
    main()
