"""The one result type of every solver, and the loop that drives their jitted steps.

Each solver is a jitted step function (a `lax` loop, an optimistix/jaxopt/lineax step) called
from a Python loop, so that wall time, progress and early stopping stay on the host, outside
the compiled code.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
import time
from collections.abc import Callable
from typing import Any, NamedTuple

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
    it ended in: the last one run, or the one that diverged (0 for a zero signal). LSMR,
    checked every ``check_every`` steps, ends at a check: ``at`` is that check's step."""

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
    - `field`: the continuous scene, where there is one: the INR solver's `rift_jax.Field`,
      or the `rift_jax.PointScatterers` that `point_scatterers` finds; None for the grid
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


@dataclasses.dataclass(frozen=True)
class Patience:
    """The stopping rule of every solver: stop once ``iterations`` in a row have not lowered
    the measure (a least-squares residual, RIFT's loss) below ``1 - min_improvement`` times
    its value at the last iteration that did: progress is measured from there, so that small
    steps cannot keep resetting the bar.

    ``floor``: the measure's value at a perfect fit, where the noise is known (its share of
    a complex-MSE loss). Progress is then measured on the part above it: on data that are
    mostly noise the loss can fall only a little, and steps small beside the noise but
    large beside what can be explained must not read as converged (RIFT(N) at −10 dB
    stopped at epoch 18 with its loss 0.999, and reached m-SSIM 0.39 when trained on:
    docs/rift.md, "Noise"). The first iteration that reaches the floor counts; after it,
    nothing does: further descent only fits the noise."""

    iterations: int
    min_improvement: float
    floor: float = 0.0

    def progressed(self, measure: float, reference: float) -> bool:
        """Whether ``measure`` is progress on ``reference``, the last one that was."""
        return max(measure - self.floor, 0.0) < (1 - self.min_improvement) * (
            reference - self.floor
        )

    @classmethod
    def from_tol(cls, tol: float) -> Patience | None:
        """The least-squares solvers' ``tol``: three iterations (FISTA's residual is not
        monotone, and a Kaczmarz sweep can gain little before the next gains more);
        ``tol=0`` runs the whole budget (None)."""
        return cls(3, tol) if tol > 0 else None


@dataclasses.dataclass(frozen=True)
class Record:
    """What one iteration observed, when it is more than a residual (RIFT's epochs).

    - `residual`: the relative data residual, for the history.
    - `measure`: what the best iterate and `Patience` follow (None: the residual), e.g. a
      training loss or a held-out residual.
    - `loss`: a training loss, for the history.
    - `at`: the iterate ``measure`` was taken at (None: ``image(carry)``).
    - `failure`: what went non-finite and where, when something did (the run diverged).
    - `fresh`: a new stage starts with this iteration (RIFT's coarse to fine): the best
      and the patience start again from it.
    """

    residual: float
    measure: float | None = None
    loss: float | None = None
    at: Any = None
    failure: str | None = None
    fresh: bool = False


class Run(NamedTuple):
    """What `iterate` returns: the best iterate (by the measure), the `History`, the `Stop`,
    and ``stats = {"best": k}``, the best's index in the history (None: the start)."""

    best: Any
    history: History
    stopped: Stop
    stats: dict

    def solution(self) -> Solution:
        return Solution(*self)


def iterate(
    step: Callable[[Any], tuple[Any, Array | Record]],
    carry: Any,
    *,
    iterations: int,
    until: Patience | None,
    progress: bool,
    desc: str,
    unit: str = "iteration",
    image: Callable[[Any], Any],
    start_measure: float = 1.0,
    monitor: Monitor | None = None,
    shown: Callable[[Any], Any] | None = None,
    then: Callable[[Any, int], tuple[Any, int] | None] | None = None,
    finish: Callable[[Run], Solution] = Run.solution,
    hint: str = "",
    with_loss: bool = False,
    per_step: int = 1,
) -> Run:
    """Call ``carry, record = step(carry)`` up to ``iterations`` times and return the best
    iterate as a `Run`: the one loop, progress bar, stopping rule and divergence path of
    every solver.

    ``record`` is the relative data residual of ``image(carry)``, the ρ that `step`
    returned (a scalar, waited for here), or a `Record` when the best is judged by another
    measure. The iterate returned is the one with the lowest measure seen, the start
    included (``start_measure``, 1 for ρ = 0): a least squares solver never ends worse
    than where it began, however its residual bounces. ``history.residual[k]`` is the
    k-th iteration's residual; ``stats["best"]`` is None when no iterate beat the start.

    ``until`` (a `Patience`) ends the run once the measure stalls (`Outcome.CONVERGED`);
    None runs the whole budget. ``then(carry, k)``, if given, is asked when it does: it
    may return ``(carry, more)`` to go on for ``more`` iterations (a next stage; its first
    `Record` says ``fresh``).
    ``monitor(k, seconds, current)``, if given, is called after iteration k (from 1), with
    ``current()`` giving ``shown(best)`` (default the best itself); the time it takes is
    left out of ``seconds`` and of the history, and if it returns True the run ends there
    (`Outcome.STOPPED`).
    ``with_loss``: the history keeps the records' losses (RIFT's).
    ``per_step``: the solver's iterations in one ``step`` (LSMR's steps between checks):
    the `Stop`, the divergence message and the monitor count the solver's iterations, the
    history one entry per step.
    A non-finite bare residual or a record's ``failure`` raises `Diverged` naming the
    iteration (a ``unit``: "epoch" for RIFT) and ``hint``; its ``.solution`` is ``finish``
    of the run before it. The progress bar appears only for runs longer than two seconds.
    """
    residuals, losses, seconds = [], [], []
    best, best_measure, best_index = image(carry), start_measure, None
    reference, improved = math.inf, 0  # `until`'s: the measure of the last progress, and when
    shown = shown or (lambda best: best)
    stopped = None

    def run(stop: Stop, n: int) -> Run:
        loss = np.asarray(losses[:n]) if with_loss else None
        history = History(np.asarray(residuals[:n]), np.asarray(seconds[:n]), loss)
        return Run(best, history, stop, {"best": best_index})

    start = time.perf_counter()
    with tqdm(total=iterations, desc=desc, disable=not progress, delay=2.0, leave=False) as bar:
        k = 0
        while k < iterations:
            k += 1
            carry, record = step(carry)
            failure = None
            if not isinstance(record, Record):  # a bare residual: finite, or diverged
                record = Record(float(jax.block_until_ready(record)))
                if not np.isfinite(record.residual):
                    failure = f"the data residual became {record.residual}"
            seconds.append(time.perf_counter() - start)
            failure = failure or record.failure
            if failure is not None:
                kept = (
                    "the start" if best_index is None else f"{unit} {(best_index + 1) * per_step}"
                )
                raise Diverged(
                    f"{desc}: at {unit} {k * per_step}, {failure}; the run diverged. The best "
                    f"before it ({kept}) is kept in this error's `.solution` (and `.result` "
                    "from fit)." + (f" {hint}" if hint else ""),
                    finish(run(Stop(Outcome.DIVERGED, k * per_step), k - 1)),
                )
            residuals.append(record.residual)
            if record.loss is not None:
                losses.append(record.loss)
            measure = record.residual if record.measure is None else record.measure
            if record.fresh:
                best_measure, reference, improved = math.inf, math.inf, k - 1
            if until.progressed(measure, reference) if until else measure < reference:
                reference, improved = measure, k
            if measure < best_measure:
                best = image(carry) if record.at is None else record.at
                best_measure, best_index = measure, k - 1
            postfix = {"residual": f"{record.residual:.4g}"}
            if record.loss is not None:
                postfix |= {"loss": f"{record.loss:.4g}", "best": f"{best_measure:.4g}"}
            bar.set_postfix(postfix, refresh=False)
            bar.update()
            if monitor is not None:
                current = functools.partial(shown, best)
                looked, stop = call_monitor(monitor, k * per_step, seconds[-1], current)
                start += looked
                if stop:
                    stopped = Stop(Outcome.STOPPED, k * per_step)
                    break
            if until is not None and k - improved >= until.iterations:
                if then is None or (going_on := then(carry, k)) is None:
                    stopped = Stop(Outcome.CONVERGED, k * per_step)
                    break
                carry, more = going_on
                iterations = k + more
                reference, improved = math.inf, k  # the next stage's patience, from here
                bar.total = iterations
    return run(stopped or Stop(Outcome.BUDGET, k * per_step), k)
