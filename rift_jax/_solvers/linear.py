"""LSMR from lineax on the GRT operator: the classic semi-convergent least-squares baseline."""

from __future__ import annotations

import jax.numpy as jnp
import lineax as lx
import numpy as np
from jaxtyping import Array, Complex, Int

from .._operator import GRTOperator
from .._precision import exact_jit
from .._validation import check_positive_int
from ._common import check_problem, relative, residual_of, zero_signal
from ._solution import Monitor, Patience, Solution, iterate


def lsmr(
    operator: GRTOperator,
    signal: Complex[Array, "n_views n_freq n_tx n_rx"],
    *,
    iterations: int = 100,
    check_every: int = 10,
    tol: float = 1e-3,
    x0: Complex[Array, " n_points"] | None = None,
    progress: bool = True,
    monitor: Monitor | None = None,
) -> Solution:
    """Least squares min ‖y − Aρ‖ by `lineax.LSMR`, stopped early.

    On data that no image on the grid explains exactly (noise, or the paper's coarser
    inverse grid: docs/conventions.md, 'Two-grid protocol'), LSMR first fits the
    well-determined components and later the noise: stopping early is the regularisation.
    Here the run is checked every ``check_every`` LSMR steps: lineax is restarted from the
    current ρ (its ``y0`` option), the residual is recorded, and the run stops when it
    stagnates (``tol``).

    **What an iteration is:** one LSMR step (one forward and one adjoint pass over all
    viewpoints); `stopped` counts them. The history has one entry per check, every
    ``check_every`` steps (each check adds a forward pass for the restart's residual).
    ``check_every=iterations`` runs one uninterrupted LSMR; restarts slow it slightly.

    **Arguments:**

    - `operator`, `signal`, `x0`, `progress`, `monitor`: as `kaczmarz`.
    - `iterations`: LSMR steps in all (rounded up to a multiple of ``check_every``).
    - `check_every`: LSMR steps between checks.
    - `tol`: stop when the residual stagnates (`Patience.from_tol`); 0 runs every step.

    **Returns:** a `Solution`, one history entry per check; the residual is lineax's
    ‖y − Aρ‖ estimate at the check.
    """
    signal, x = check_problem("lsmr", operator, signal, x0, iterations)
    check_positive_int("lsmr: `check_every`", check_every)
    if (solution := zero_signal("lsmr", signal, x)) is not None:
        return solution
    steps = min(check_every, iterations)
    norm = jnp.linalg.norm(signal)

    # traced, not static: runs that check every 5, 10 or 100 steps share one program
    n_steps = np.asarray(steps, np.int32)

    def step(x):
        x, norm_r = _segment(operator, signal, x, n_steps)
        return x, relative(norm_r, norm)

    x, history, stopped, stats = iterate(
        step,
        x,
        iterations=-(-iterations // steps),
        until=Patience.from_tol(tol),
        progress=progress,
        monitor=monitor,
        desc="lsmr",
        image=lambda x: x,
        start_measure=residual_of(operator.fn, signal, x),
        per_step=steps,
    )
    return Solution(x, history, stopped, stats | {"check_every": steps})


@exact_jit
def _segment(operator: GRTOperator, signal, x, steps: Int[Array, ""]):
    """``steps`` LSMR steps from ``x``: (new x, ‖y − Ax‖). Module-level and with ``steps``
    traced (lineax only compares its step count with it), so repeated runs of one problem
    size compile once, whatever their ``check_every``."""
    solver = lx.LSMR(rtol=0.0, atol=0.0, max_steps=steps)  # no tolerance: always `steps`
    solution = lx.linear_solve(operator, signal, solver, options={"y0": x}, throw=False)
    return solution.value, solution.stats["norm_r"]
