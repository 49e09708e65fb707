"""Gauss-Newton and Levenberg-Marquardt from optimistix on the GRT least-squares problem.

The residual ρ ↦ Aρ − y is linear, so one Gauss-Newton step with an exact inner solve is
the least-squares solution; with a matrix-free inner LSMR of ``inner`` steps, each outer
step refines the last. optimistix linearises the residual; `realified` makes that
linearisation transpose with the hand-written adjoint kernel.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jaxtyping import Array, Complex

from .._operator import GRTOperator
from .._precision import exact_jit
from .._sharding import replicated
from .._validation import check_positive_int
from ._common import (
    as_complex,
    as_pair,
    check_problem,
    realified,
    relative,
    residual_of,
    zero_signal,
)
from ._solution import Monitor, Patience, Solution, iterate


def gauss_newton(
    operator: GRTOperator,
    signal: Complex[Array, "n_views n_freq n_tx n_rx"],
    *,
    iterations: int = 10,
    inner: int = 10,
    damped: bool = False,
    tol: float = 1e-3,
    x0: Complex[Array, " n_points"] | None = None,
    progress: bool = True,
    monitor: Monitor | None = None,
) -> Solution:
    """min ½‖Aρ − y‖² by `optimistix.GaussNewton` (or `optimistix.LevenbergMarquardt` with
    ``damped=True``), each step's linear solve by `lineax.LSMR` for ``inner`` steps.

    optimistix sees ρ as the real pair (Re ρ, Im ρ) (its complex support is experimental).

    **What an iteration is:** one optimistix step: ``inner`` LSMR steps (each a forward and
    an adjoint pass over all viewpoints) plus two forward passes (optimistix's residual and
    the recorded one). An extra first step, in which optimistix only evaluates the residual
    at ``x0``, is done before the loop.

    **Arguments:**

    - `operator`, `signal`, `x0`, `progress`, `monitor`: as `kaczmarz`.
    - `iterations`: outer steps.
    - `inner`: LSMR steps per outer step.
    - `damped`: Levenberg-Marquardt (trust-region damping) instead of plain Gauss-Newton.
      The problem is linear, so damping only slows it down; it is here for comparison.
    - `tol`: stop when the residual stagnates (`Patience.from_tol`); 0 runs every step.

    **Returns:** a `Solution`; the residual is ‖y − Aρ‖/‖y‖ at each step's ρ.
    """
    where = "gauss_newton"
    signal, x = check_problem(where, operator, signal, x0, iterations)
    check_positive_int(f"{where}: `inner`", inner)
    if (solution := zero_signal(where, signal, x)) is not None:
        return solution
    solver, residual, y, state = _problem(operator.fn, signal, x, inner, damped)
    # placed as `_step` returns them, so that the first step does not compile apart
    y, state = replicated((y, state))
    norm = jnp.linalg.norm(signal)

    def step(carry):
        y, state, r = _step(solver, residual, *carry)
        return (y, state), relative(r, norm)

    rho, history, stopped, stats = iterate(
        step,
        step((y, state))[0],
        iterations=iterations,
        until=Patience.from_tol(tol),
        progress=progress,
        monitor=monitor,
        desc=where,
        image=lambda carry: as_complex(carry[0]),
        start_measure=residual_of(operator.fn, signal, x),
    )
    return Solution(rho, history, stopped, stats | {"inner": inner, "damped": damped})


def _problem(fn, signal, x, inner: int, damped: bool):
    """(solver, residual function, start as a real pair, solver state) for `gauss_newton`."""
    linear_solver = lx.LSMR(rtol=0.0, atol=0.0, max_steps=inner)  # no tolerance: `inner` steps
    kind = optx.LevenbergMarquardt if damped else optx.GaussNewton
    solver = kind(rtol=0.0, atol=0.0, linear_solver=linear_solver)
    apply = realified(fn)
    target = as_pair(signal)

    # The residual closes over the data rather than taking optimistix's `args`: optimistix
    # traces `args` (eval_shape) into the linearised residual it keeps in its state, and
    # those tracers must not escape into the jitted step. (As leaves of an `eqx.Partial`
    # they escape the same way.) The price: `_step` compiles once per run, not per size.
    def residual(pair, args):
        del args
        ax = apply(pair)
        return (ax[0] - target[0], ax[1] - target[1]), None

    y = as_pair(x)
    f_struct = eqx.filter_eval_shape(lambda: residual(y, None)[0])
    state = solver.init(residual, y, None, {}, f_struct, None, frozenset())
    return solver, residual, y, state


@exact_jit
def _step(solver, residual, y, state):
    """One optimistix step: (y, state, ‖Aρ − y‖ at the new ρ)."""
    y, state, _ = solver.step(residual, y, None, {}, state, frozenset())
    r = residual(y, None)[0]
    # replicated, as the first step's inputs are: the state holds residuals, which come out
    # of the operator split over views or whole by the view count, and a new sharding
    # would compile the step again
    return replicated((y, state, jnp.sqrt(jnp.sum(r[0] ** 2) + jnp.sum(r[1] ** 2))))
