"""Kaczmarz's relaxation on data no grid image explains: the residual of the whole iterate
after each sweep, from several starting λ and for the default, beside LSMR's least-squares
floor and the zero image's 1; then the default run until it stalls at the paper's grids.

    python -m benchmarks.relaxation [--sweeps 6] [--stall-views 500] [--repeats 3]

The cube (edge 2 m) synthesised at 0.3 m over ±2.4 m and reconstructed on the nested
0.6 m grid from 100 views of the paper's radar (the simple scenes' default protocol), and
the same cube synthesised on the 0.6 m grid itself (consistent data): ``--sweeps`` sweeps
from each starting λ (each sweep kept as far as its line search finds it helps, and the
next λ set from it; `rift_jax.solvers.kaczmarz`), the residuals measured independently
here (‖y − Aρ‖/‖y‖ of each sweep's ρ), not read from the solver's history. Then `fit`'s
Kaczmarz on the parking lot at the paper's grids (±5 m, 0.2 / 0.4 m, its support
estimated) from ``--stall-views`` views, until its residual stalls (``tol=1e-3``, at most
100 sweeps): its sweeps, residual, λ and line-search steps, and its time (the median of
``--repeats`` fits after a warm-up fit, the support estimated once outside the timing).
"""

from __future__ import annotations

import argparse

import jax.numpy as jnp
import numpy as np

import rift_jax as rj

from ._timing import complex_matmul_rate, median_seconds


def residuals(operator, signal, relaxation: float, sweeps: int) -> list[float]:
    """The relative residual of ρ after each of ``sweeps`` sweeps from ρ = 0, λ starting at
    ``relaxation``: measured here from each sweep's ρ (the solver's ``monitor``)."""
    norm = float(jnp.linalg.norm(signal))
    out = []

    def measure(sweep, seconds, current):
        out.append(float(jnp.linalg.norm(signal - operator.mv(current()))) / norm)

    rj.solvers.kaczmarz(
        operator, signal, iterations=sweeps, relaxation=relaxation, tol=0.0, monitor=measure,
        progress=False,
    )  # fmt: skip
    return out


def until_stalled(n_views: int, repeats: int) -> None:
    """`fit`'s Kaczmarz on the parking lot at the paper's grids, until it stalls."""
    radar, scene = rj.Radar(), rj.scenes.parking_lot(0.2, extent=5.0)
    _, train = rj.Viewpoints.grid().split(20, n_views, seed=0)
    signal = rj.synthesize(scene, train, radar).signal
    support = rj.estimate_support(signal, train, rj.Scene.empty(5.0, 0.4), radar=radar)
    options = dict(radar=radar, method="kaczmarz", granularity=0.4, extent=5.0, support=support)
    fits = []

    def run():
        fits.append(rj.fit(signal, train, **options, iterations=100, progress=False))
        return fits[-1].scene.reflectivity

    seconds = median_seconds(run, repeats=repeats)
    result = fits[-1]
    steps = result.stats["steps"]
    print(
        f"\nparking lot, 0.2 / 0.4 m, {n_views} views, {int(np.sum(support))} support points: "
        f"{len(steps)} sweeps to the stall in {seconds:.1f} s (median of {repeats}), residual "
        f"{result.history.residual[-1]:.4f}\n  λ "
        + " ".join(f"{v:.3g}" for v in result.stats["relaxations"])
        + "\n  t "
        + " ".join(f"{v:.3f}" for v in steps)
    )


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.relaxation")
    parser.add_argument("--sweeps", type=int, default=6)
    parser.add_argument("--stall-views", type=int, default=500)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    print(f"complex64 matmul: {complex_matmul_rate():.1f} G/s")
    radar = rj.Radar()
    _, train = rj.Viewpoints.grid().split(20, 100, seed=0)
    grid = rj.Scene.empty(2.4, 0.6)
    operator = rj.grt_operator(radar, train, grid.points())
    for forward in (0.3, 0.6):
        scene = rj.scenes.cube(forward, extent=2.4)
        signal = jnp.asarray(rj.synthesize(scene, train, radar).signal)
        kind = "two grids, inconsistent" if forward != 0.6 else "one grid, consistent"
        print(f"\ncube at {forward} m, reconstructed at 0.6 m ({kind}); residual per sweep")
        for relaxation in (1.0, 0.5, 0.25, 0.1, 0.05):
            values = residuals(operator, signal, relaxation, args.sweeps)
            print(f"  λ from {relaxation:<5g}", " ".join(f"{v:.4f}" for v in values))
        lsmr = rj.solvers.lsmr(operator, signal, iterations=40, tol=0.0, progress=False)
        floor = float(jnp.linalg.norm(signal - operator.mv(lsmr.rho)) / jnp.linalg.norm(signal))
        print(f"  LSMR, 40 steps (the least-squares floor): {floor:.4f}")
        default = rj.solvers.kaczmarz(
            operator, signal, iterations=args.sweeps, tol=0.0, progress=False
        )
        print(
            "  default (λ from 0.25):",
            " ".join(f"{v:.4f}" for v in np.asarray(default.history.residual)),
            "steps t",
            " ".join(f"{v:.2f}" for v in default.stats["steps"]),
        )
    until_stalled(args.stall_views, args.repeats)


if __name__ == "__main__":
    main()
