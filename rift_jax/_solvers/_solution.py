"""The one result type of every solver, and the loop that drives their jitted steps.

Each solver is a jitted step function (a `lax` loop, an optimistix/jaxopt/lineax step) called
from a Python loop, so that wall time, progress and early stopping stay on the host, outside
the compiled code.
"""

from __future__ import annotations

import dataclasses
import enum
import time
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jaxtyping import Array, Complex
from tqdm.auto import tqdm


@dataclasses.dataclass(frozen=True)
class History:
    """Per-iteration record of a run (host float64 arrays, one entry per iteration).

    - `residual`: relative data residual ‖y − Aρ‖ / ‖y‖ as the solver observed it (each
      solver's docstring says where it is measured).
    - `seconds`: wall time since the start of the run at the end of each iteration.
    - `loss`: the training loss per epoch (INR training only; None for least squares).
    """

    residual: np.ndarray
    seconds: np.ndarray
    loss: np.ndarray | None = None

    def __len__(self) -> int:
        return self.residual.shape[0]


class Outcome(enum.Enum):
    """Why a run ended; every solver, least squares and RIFT, reports one of these."""

    BUDGET = "budget"  # every iteration (sweep, epoch) it was given ran
    CONVERGED = "converged"  # progress stalled: `tol` (least squares) or `patience` (RIFT)
    DIVERGED = "diverged"  # a non-finite residual, loss or gradient; the best before it is kept
    ZERO_SIGNAL = "zero signal"  # all-zero data: ρ = 0, nothing ran
    STOPPED = "stopped"  # the monitor ended it (e.g. `fit`'s ``time_limit``); best so far kept


@dataclasses.dataclass(frozen=True)
class Stop:
    """How a run ended: its `Outcome`, and ``at``, the iteration (sweep or epoch, from 1)
    it ended in: the last one run, or the one that diverged (0 for a zero signal)."""

    outcome: Outcome
    at: int

    def __str__(self) -> str:
        if self.outcome is Outcome.ZERO_SIGNAL:
            return self.outcome.value
        return f"{self.outcome.value} at iteration {self.at}"

    def to_json(self) -> dict:
        return {"outcome": self.outcome.value, "at": self.at}

    @classmethod
    def from_json(cls, record: dict) -> Stop:
        return cls(Outcome(record["outcome"]), int(record["at"]))


@dataclasses.dataclass(frozen=True)
class Solution:
    """What every solver returns.

    - `rho`: the reconstructed complex64 reflectivity, (n_points,), on the operator's grid.
    - `history`: a `History`.
    - `stopped`: why and when the run ended, a `Stop` (a divergence is raised as
      `Diverged`, whose ``.solution`` says ``Outcome.DIVERGED`` and where).
    - `stats`: solver-specific numbers (e.g. the step size used). The least-squares
      solvers return their best iterate, the one with the lowest data residual, and
      ``stats["best"]`` is its index in ``history`` (None: none beat the start, which is
      returned).
    - `field`: the INR solver's continuous scene (a `rift_jax.Field`); None for the grid
      solvers.
    """

    rho: Complex[Array, " n_points"]
    history: History
    stopped: Stop
    stats: dict[str, Any] = dataclasses.field(default_factory=dict)
    field: Any = None

    @property
    def seconds(self) -> float:
        return float(self.history.seconds[-1]) if len(self.history) else 0.0


class Diverged(ValueError):
    """A run met a non-finite residual (least squares) or loss or gradient (RIFT).
    ``.solution`` holds the best `Solution` reached before that, its `stopped` saying
    ``Outcome.DIVERGED`` and the iteration (and, raised from `rift_jax.fit`, ``.result`` the
    `FitResult`), so the run so far is not lost."""

    def __init__(self, message: str, solution: Solution):
        super().__init__(message)
        self.solution = solution
        self.result = None


Monitor = Callable[[int, float, Callable[[], Any]], bool | None]
"""``monitor(iteration, seconds, current)``: a look at a run while it runs (`fit`'s
``monitor``); ``current()`` returns the best reconstruction so far. A monitor that returns
True ends the run after this iteration (`Outcome.STOPPED`), keeping the best so far."""


def call_monitor(monitor: Monitor, iteration: int, seconds: float, current) -> tuple[float, bool]:
    """Call ``monitor``: the seconds it took (which the run's clock leaves out), and whether
    it asked the run to stop."""
    start = time.perf_counter()
    stop = monitor(iteration, seconds, current)
    return time.perf_counter() - start, bool(stop)


_PATIENCE = 3


def iterate(
    step: Callable[[Any], tuple[Any, Array]],
    carry: Any,
    *,
    iterations: int,
    tol: float,
    progress: bool,
    desc: str,
    image: Callable[[Any], Array],
    start_residual: float = 1.0,
    monitor: Monitor | None = None,
) -> tuple[Array, History, Stop, dict]:
    """Call ``carry, residual = step(carry)`` up to ``iterations`` times and return the best
    iterate: ``(ρ, history, stop, {"best": k})``.

    ``residual`` must be the relative data residual of ``image(carry)``, the ρ that `step`
    returned, so that the ρ returned here is the one with the lowest residual seen, the
    start included (``start_residual``, 1 for ρ = 0): a least squares solver never ends
    worse than where it began, however its residual bounces. ``history.residual[k]`` is the
    returned ρ's residual; k is None when no iterate beat the start.

    Stops early when the best relative residual of the last three iterations is not lower
    than the best before them by a factor ``1 - tol``: the run has stagnated (three, not one,
    because Kaczmarz's and FISTA's residuals are not monotone). ``tol=0`` runs the whole
    budget.
    ``monitor(k, seconds, current)``, if given, is called after iteration k (from 1), with
    ``current()`` giving the best iterate so far; the time it takes is left out of
    ``seconds`` and of the history, and if it returns True the run ends there
    (`Outcome.STOPPED`).
    A non-finite residual raises `Diverged` naming the iteration; its ``.solution`` holds the
    best iterate before it. The progress
    bar appears only for runs longer than two seconds.
    """
    residuals, seconds = [], []
    best, best_residual, best_index = image(carry), start_residual, None
    stopped = None
    start = time.perf_counter()
    with tqdm(total=iterations, desc=desc, disable=not progress, delay=2.0, leave=False) as bar:
        for k in range(iterations):
            carry, residual = step(carry)
            residual = float(jax.block_until_ready(residual))
            seconds.append(time.perf_counter() - start)
            if not np.isfinite(residual):
                history = History(np.asarray(residuals), np.asarray(seconds[:-1]))
                raise Diverged(
                    f"{desc}: the data residual became {residual} at iteration {k + 1}; the "
                    "iteration diverged (for FISTA, lower the step size). The best iterate "
                    "before it is kept in this error's `.solution` (and `.result` from fit).",
                    Solution(best, history, Stop(Outcome.DIVERGED, k + 1), {"best": best_index}),
                )
            residuals.append(residual)
            if residual < best_residual:
                best, best_residual, best_index = image(carry), residual, k
            bar.set_postfix(residual=f"{residual:.4g}", refresh=False)
            bar.update()
            if monitor is not None:
                looked, stop = call_monitor(monitor, k + 1, seconds[-1], lambda best=best: best)
                start += looked
                if stop:
                    stopped = Stop(Outcome.STOPPED, k + 1)
                    break
            if (
                tol > 0
                and k >= _PATIENCE
                and min(residuals[-_PATIENCE:]) >= (1 - tol) * min(residuals[:-_PATIENCE])
            ):
                stopped = Stop(Outcome.CONVERGED, k + 1)
                break
    history = History(np.asarray(residuals), np.asarray(seconds))
    stopped = stopped or Stop(Outcome.BUDGET, len(residuals))
    return best, history, stopped, {"best": best_index}
