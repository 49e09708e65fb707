"""`rift`: train an INR through the GRT, check it for collapse, and retry a collapsed run."""

from __future__ import annotations

import dataclasses
import functools
import warnings

import numpy as np
from jaxtyping import Array, Complex, Float

from ..._losses import complex_mse
from ..._models import AbstractINR, Field
from ..._operator import GRTOperator
from ..._validation import is_finite_nonnegative
from .._common import check_problem
from .._solution import Monitor, Outcome, Solution
from .collapse import CollapseWarning, check_collapse
from .recipe import Recipe, resolve
from .training import train
from .warm_start import WARM_STARTS, least_squares_start


def rift(
    operator: GRTOperator,
    signal: Complex[Array, "n_views n_freq n_tx n_rx"],
    *,
    model: str | AbstractINR = "rift-n",
    recipe: str | Recipe = "default",
    width: int | None = None,
    depth: int | None = None,
    init: Field | str | None = None,
    extent: float | None = None,
    fine_points: Float[np.ndarray, "k 3"] | None = None,
    fine_epochs: int | None = None,
    seed: int = 0,
    progress: bool = True,
    monitor: Monitor | None = None,
    noise: float | None = None,
    **overrides,
) -> Solution:
    """Train an INR so that the GRT of its rendering on the operator's grid fits ``signal``.

    **Arguments:**

    - `operator`, `signal`, `progress`: as `kaczmarz`.
    - `model`: ``"rift-n"`` (`RiftN`), ``"rift-s"`` (`RiftS`), ``"hash-grid"``
      (`HashGrid`), or an `AbstractINR` instance.
    - `recipe`: ``"default"``, ``"paper"`` or a `Recipe`.
    - `width`, `depth`: the INR's size when `model` is a name (None: the model's own
      defaults, 64 and 4 for RiftN and RiftS, 64 and 2 for HashGrid).
    - `init`: a `Field` to start from (e.g. a previous result's): a warm start, with a fresh
      optimizer state and learning-rate schedule. Its model must be of the kind `model`
      names (or `model` may be left as is when it is an instance). Or ``"fista"`` /
      ``"lsmr"``: a least-squares start. That solver runs on the same operator and data
      first (with its defaults), the fresh INR is fitted to its image point by point, and
      training starts from there (``stats["warm_start"]``: the solver's residual and
      the relative error of that fit; not with a `holdout`, which it would see).
    - `extent`: the half-width (m) that maps the scene onto the INR's [-1, 1]³; default the
      largest coordinate of the operator's points. `fit` passes its grid's, so that a run on
      a support (fewer points) sees the same coordinates as one on the whole grid.
    - `fine_points`: (k, 3) points (m), e.g. a finer grid's: coarse to fine. The last
      `fine_epochs` epochs (default half; all of them after `patience` ends the coarse
      stage early) train the field on these points instead of the operator's, with the
      same optimizer state; the recipe's `prune` picks their active set from the field at
      once. The signals are then the GRT of the field on these points (`stats["active"]`
      marks the ones trained last); `rho` is still its rendering on the operator's points.
    - `seed`: seeds the INR's initialisation and the order of the viewpoints.
    - `monitor`: ``monitor(epoch, seconds, current)`` after each epoch, ``current()`` the
      best `Field` so far (as `kaczmarz`'s; its time is not counted; True ends the run,
      which is then neither checked for collapse nor retried). The seconds run on over a
      collapse's retries, whose epochs count from 1 again.
    - `noise`: the standard deviation of the data's complex noise per sample, if known
      (`fit` passes it from ``snr_db`` or a `RadarData`'s SNR), in the units of `signal`.
      It tells the loss that noise leaves from progress: `patience` then measures the
      loss's progress above the noise's share of the data's power (``stats["noise_share"]``;
      for complex MSE, or a `holdout`'s residual), and "fits nothing" below asks for 1 % of
      the signal's power instead of the data's. Without it, on data that are mostly noise
      (−10 dB), runs stopped after 18-36 epochs with nothing fitted (docs/rift.md,
      "Noise"). A `noise` that holds all of the data's power or more is not believed: a
      warning says so, and training ignores it.
    - `**overrides`: any `Recipe` field, replacing the recipe's value (e.g. ``epochs=50``).

    **Returns:** a `Solution` whose `field` is the trained `Field` of the epoch with the
    lowest mean training loss (the parameters before that epoch's last update: with one
    step per epoch, exactly those the loss was measured at; from the fine stage when there
    is one), or with a `holdout`, of the epoch whose end left the lowest held-out residual
    (``stats["best_loss"]`` is then that residual); its `rho` is its rendering. The history
    has per epoch the mean loss and the relative residual ‖y − Aρ‖/‖y‖ accumulated over the
    epoch's minibatches (each at its step's parameters). ``stopped`` is a `Stop`:
    ``Outcome.BUDGET`` after every epoch, or ``Outcome.CONVERGED`` when the recipe's
    `patience` ended the run early (``stats["epochs_run"]`` epochs).
    ``stats["active_points"]`` counts the points the returned field was trained on.

    **Collapse.** After training, the run is checked for the ways an INR fails without a
    non-finite value (`diagnose`): a global gain that drifted to zero, a field whose signals
    carry almost none of the data's energy, a field trained with complex MSE that explains
    under 1 % of the data's power on its training views even at its best complex gain
    (residual ≥ 0.995; of the signal's power where `noise` is known; not for coarse to
    fine), a near-constant field, or a
    loss that never fell from its first epoch (not checked for an `init` warm start, which
    may begin converged). A collapsed run is retried up to the recipe's `retries` times,
    each from a fresh initialisation (seed + 1000·k; an `init` field is kept) at half the
    previous learning rate. ``stats["remedies"]`` records each retry (the collapse it answered, its
    seed and learning rate), ``stats["collapse"]`` what remains wrong with the returned run
    (None: nothing), and ``stats["attempts"]`` how many ran. If every attempt collapsed,
    the one with the lowest best loss is returned and a `CollapseWarning` says so.

    **Raises:** `Diverged` (a ValueError) if a loss or gradient becomes non-finite,
    naming the epoch; its ``.solution`` holds the best parameters so far.
    """
    name = model if isinstance(model, str) else type(model).__name__
    where = f"rift ({name})"
    recipe = resolve(where, recipe, overrides)
    if noise is not None:
        if not is_finite_nonnegative(noise):
            raise ValueError(
                f"{where}: `noise` must be a finite number ≥ 0 or None, got {noise!r}."
            )
        checked, _ = check_problem(where, operator, signal, None, recipe.epochs)
        power = float(np.mean(np.abs(np.asarray(checked)) ** 2))
        if noise**2 >= power > 0:  # noise that is all of the data: not to be believed
            warnings.warn(
                f"{where}: `noise` ({noise:.3g} per sample) holds all of the data's power "
                f"({power:.3g} per sample) or more; training ignores it. Does the SNR or noise "
                "level given overstate the noise?",
                UserWarning,
                stacklevel=2,
            )
            noise = None
    warm = None
    if isinstance(init, str):
        if init not in WARM_STARTS:
            raise ValueError(
                f"{where}: `init` must be a Field, one of {sorted(WARM_STARTS)} (a least-"
                f"squares start) or None, got {init!r}."
            )
        if recipe.holdout:
            raise ValueError(
                f"{where}: `init={init!r}` and `holdout` cannot go together: the "
                "least-squares start would see the held-out viewpoints."
            )
        warm = least_squares_start(init, operator, signal, seed=seed)
        init = None
    one_run = functools.partial(
        train, operator, signal, where=where, name=name, model=model, width=width,
        depth=depth, init=init, warm=warm, extent=extent, fine_points=fine_points,
        fine_epochs=fine_epochs, progress=progress, noise=noise,
    )  # fmt: skip
    spent = [0.0]  # the seconds of the attempts so far: a monitor sees one clock over all

    def attempt(**kwargs) -> Solution:
        watch = None
        if monitor is not None:
            offset = spent[0]

            def watch(epoch, seconds, current):
                return monitor(epoch, offset + seconds, current)

        solution = one_run(**kwargs, monitor=watch)
        spent[0] += solution.seconds
        return solution

    solution = attempt(recipe=recipe, seed=seed)
    if solution.stopped.outcome is Outcome.ZERO_SIGNAL:
        return solution

    def checked(solution: Solution) -> tuple[Solution, str | None]:
        if solution.stopped.outcome is Outcome.STOPPED:  # its monitor ended it: not judged,
            return solution, None  # so not retried
        started = init is not None or warm is not None
        least_squares = recipe.loss_fn is complex_mse
        why = check_collapse(
            solution, operator.fn, signal, warm=started, least_squares=least_squares,
            noise_share=solution.stats["noise_share"],
        )  # fmt: skip
        return solution, why

    attempts, remedies = [checked(solution)], []  # (solution, why it collapsed or None)
    learning_rate = solution.stats["recipe"]["learning_rate"]
    for k in range(1, recipe.retries + 1):
        if attempts[-1][1] is None:
            break
        learning_rate /= 2
        retry_seed = seed + 1000 * k
        remedies.append(
            {
                "attempt": k,
                "collapse": attempts[-1][1],
                "seed": retry_seed,
                "learning_rate": learning_rate,
            }
        )
        retry = dataclasses.replace(recipe, learning_rate=learning_rate)
        attempts.append(checked(attempt(recipe=retry, seed=retry_seed)))
    solution, why = attempts[-1]
    if why is not None:  # every attempt collapsed: the one that fitted best, said out loud
        solution, why = min(attempts, key=lambda attempt: attempt[0].stats["best_loss"])
        warnings.warn(
            f"{where}: training collapsed ({why}) in each of {len(attempts)} attempts; "
            "returning the one with the lowest loss. More epochs, another seed or a "
            "finer/coarser grid may help (docs/rift.md, Collapse).",
            CollapseWarning,
            stacklevel=2,
        )
    stats = {"remedies": remedies, "collapse": why, "attempts": len(attempts)}
    return dataclasses.replace(solution, stats=solution.stats | stats)
