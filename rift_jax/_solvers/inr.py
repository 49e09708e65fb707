"""RIFT: an implicit neural representation trained through the GRT with optax.

The scene is a `Field` (an INR plus a global complex gain) rendered on the operator's grid;
its signals are the GRT of that rendering, and the loss compares them with the data. One
jitted step does value-and-grad and the optax update for a minibatch of viewpoints; the
Python loop outside keeps the epochs, the best parameters, the progress bar and the
non-finite check.

The signal's cotangent reaches ρ through `realified`, i.e. through the hand-written adjoint
kernel: JAX's own transpose of the forward kernel is exact but ~12x slower (measured,
docs/benchmarks.md).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
import warnings
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import scipy.spatial
from jaxtyping import Array, Complex, Float
from tqdm.auto import tqdm

from .._geometry import spread
from .._losses import LOSSES
from .._models import MODELS, AbstractINR, Field
from .._operator import GRT, GRTOperator
from .._padding import ladder_size
from .._precision import exact_jit, split, to_float64
from .._sharding import replicated
from .._validation import (
    as_finite_array,
    check_nonnegative_int,
    check_positive,
    check_positive_int,
)
from ._common import as_complex, as_pair, check_problem, realified, zero_signal
from ._solution import Diverged, History, Monitor, Outcome, Solution, Stop, call_monitor


@dataclasses.dataclass(frozen=True)
class Recipe:
    """How an INR is trained. ``Recipe()`` is the default; ``RECIPES["paper"]`` the paper's.

    - `loss`: ``"robust"`` (default), ``"paper"`` (see `rift_jax.losses`), or a callable
      ``loss(pred, target) -> scalar``.
    - `epochs`: passes over the training viewpoints.
    - `learning_rate`, `weight_decay`, `adam_eps`: `optax.adamw`'s (weight decay applies to
      the INR, not to the gain). ``learning_rate=None`` takes the model's own default
      (`AbstractINR.learning_rate`: 1e-2 for RiftN, 1e-3 for RiftS).
    - `halve_every`: halve the learning rate every this many epochs, a fraction allowed
      (counted in optimizer steps, at least one; None: constant).
    - `batch_views`: viewpoints per optimizer step (None: all, one step per epoch). An epoch
      visits the viewpoints in a fresh seeded order; when the batch does not divide them,
      the last batch is filled up with the epoch's first viewpoints.
    - `clip_norm`: clip the gradient to this global norm (None: no clipping).
    - `gain`: learn the global complex gain, started where the initial field's signals have
      the data's energy (False: fixed at 1, as the paper).
    - `patience`: stop early when the epoch's mean training loss has not improved on the best
      so far by a relative `min_improvement` for this many epochs (default 10, so that
      `epochs` is a budget: "until converged, at most N"; None: run every epoch, as the
      paper). The run then ends with ``Outcome.CONVERGED``, as the least-squares solvers
      do, and keeps the best parameters. At the paper's scale the loss is flat after ~20 of
      100 epochs, so a `patience` of 10 can save most of a run.
    - `min_improvement`: see `patience`.
    - `prune`: train only an *active set* of the operator's points: those where |ρ| is at
      least ``prune`` times its largest value, and their neighbours (within √3 point
      spacings). The set is chosen from the field itself every `recheck_every` epochs (the
      first time after `recheck_every` epochs, or at once from an `init` field), and grows
      back wherever the field has risen since; each step's cost follows the active points.
      The result is what was trained: the best epoch's field on that epoch's active set,
      zero elsewhere. Default 0.05: RIFT trains where the field lives (on the paper's cube,
      the same m-SSIM in a fraction of the time: docs/rift.md). None: train every point.
    - `recheck_every`: see `prune`.
    - `holdout`: hold out this many of the training viewpoints (evenly spread in their
      order) and never train on them. Each epoch then measures their relative residual
      ‖y − Aρ‖/‖y‖ (``stats["holdout_residual"]``), and the best parameters and `patience`
      follow it instead of the training loss: early stopping on unseen data. 0: none.
    - `retries`: how many times a collapsed run is retried from a fresh start at half the
      learning rate (see `rift`, "Collapse"). 0: never.
    """

    loss: str | Callable = "robust"
    epochs: int = 100
    learning_rate: float | None = None
    weight_decay: float = 1e-2
    halve_every: float | None = 25
    batch_views: int | None = 10
    clip_norm: float | None = 1.0
    gain: bool = True
    adam_eps: float = 1e-8
    patience: int | None = 10
    min_improvement: float = 1e-3
    prune: float | None = 0.05
    recheck_every: int = 10
    holdout: int = 0
    retries: int = 2

    def __post_init__(self):
        if not callable(self.loss) and self.loss not in LOSSES:
            raise ValueError(
                f"Recipe: unknown `loss` {self.loss!r}; choose one of {sorted(LOSSES)} or pass "
                "a callable loss(pred, target)."
            )
        check_positive_int("Recipe: `epochs`", self.epochs)
        if self.learning_rate is not None:
            check_positive("Recipe: `learning_rate` (or None)", self.learning_rate)
        check_positive("Recipe: `adam_eps`", self.adam_eps)
        if not isinstance(self.weight_decay, int | float | np.number) or not self.weight_decay >= 0:
            raise ValueError(f"Recipe: `weight_decay` must be ≥ 0, got {self.weight_decay!r}.")
        if self.halve_every is not None:
            check_positive("Recipe: `halve_every` (or None)", self.halve_every)
        if self.batch_views is not None:
            check_positive_int("Recipe: `batch_views` (or None)", self.batch_views)
        if self.clip_norm is not None:
            check_positive("Recipe: `clip_norm` (or None)", self.clip_norm)
        if not isinstance(self.gain, bool):
            raise ValueError(f"Recipe: `gain` must be True or False, got {self.gain!r}.")
        if self.patience is not None:
            check_positive_int("Recipe: `patience` (or None)", self.patience)
        if self.prune is not None and not 0 < self.prune < 1:
            raise ValueError(f"Recipe: `prune` must be in (0, 1) or None, got {self.prune!r}.")
        check_positive_int("Recipe: `recheck_every`", self.recheck_every)
        check_nonnegative_int("Recipe: `holdout`", self.holdout)
        check_nonnegative_int("Recipe: `retries`", self.retries)
        if not 0 <= self.min_improvement < 1:
            raise ValueError(
                f"Recipe: `min_improvement` must be in [0, 1), got {self.min_improvement!r}."
            )

    @property
    def loss_fn(self) -> Callable:
        return self.loss if callable(self.loss) else LOSSES[self.loss]


RECIPES = {
    "default": Recipe(),
    # Appendix "Optimization Details": AdamW 1e-2, weight decay 1e-2, 500 epochs, learning
    # rate halved every 100, lowest-loss parameters kept; magnitude + phase L1 with α2 = 1000
    # α1. The batch is not stated: one step per epoch over all viewpoints.
    "paper": Recipe(
        loss="paper",
        epochs=500,
        learning_rate=1e-2,
        halve_every=100,
        batch_views=None,
        clip_norm=None,
        gain=False,
        patience=None,  # the paper trains every epoch
        prune=None,  # ... on every point
    ),
}


def rift(
    operator: GRTOperator,
    signal: Complex[Array, "n_views n_freq n_tx n_rx"],
    *,
    model: str | AbstractINR = "rift-n",
    recipe: str | Recipe = "default",
    width: int = 64,
    depth: int = 4,
    init: Field | None = None,
    extent: float | None = None,
    fine_points: Float[np.ndarray, "k 3"] | None = None,
    fine_epochs: int | None = None,
    seed: int = 0,
    progress: bool = True,
    monitor: Monitor | None = None,
    **overrides,
) -> Solution:
    """Train an INR so that the GRT of its rendering on the operator's grid fits ``signal``.

    **Arguments:**

    - `operator`, `signal`, `progress`: as `kaczmarz`.
    - `model`: ``"rift-n"`` (`RiftN`), ``"rift-s"`` (`RiftS`), or an `AbstractINR` instance.
    - `recipe`: ``"default"``, ``"paper"`` or a `Recipe`.
    - `width`, `depth`: the INR's size when `model` is a name.
    - `init`: a `Field` to start from (e.g. a previous result's): a warm start, with a fresh
      optimizer state and learning-rate schedule. Its model must be of the kind `model`
      names (or `model` may be left as is when it is an instance).
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
    carry almost none of the data's energy, a near-constant field, or a loss that never
    fell from its first epoch (not checked for an `init` warm start, which may begin
    converged). A collapsed run is retried up to the recipe's `retries` times, each from a
    fresh initialisation (seed + 1000·k; an `init` field is kept) at half the previous
    learning rate. ``stats["remedies"]`` records each retry (the collapse it answered, its
    seed and learning rate), ``stats["collapse"]`` what remains wrong with the returned run
    (None: nothing), and ``stats["attempts"]`` how many ran. If every attempt collapsed,
    the one with the lowest best loss is returned and a `CollapseWarning` says so.

    **Raises:** `Diverged` (a ValueError) if a loss or gradient becomes non-finite,
    naming the epoch; its ``.solution`` holds the best parameters so far.
    """
    name = model if isinstance(model, str) else type(model).__name__
    where = f"rift ({name})"
    recipe = _recipe(where, recipe, overrides)
    train = functools.partial(
        _train, operator, signal, where=where, name=name, model=model, width=width,
        depth=depth, init=init, extent=extent, fine_points=fine_points,
        fine_epochs=fine_epochs, progress=progress,
    )  # fmt: skip
    spent = [0.0]  # the seconds of the attempts so far: a monitor sees one clock over all

    def attempt(**kwargs) -> Solution:
        watch = None
        if monitor is not None:
            offset = spent[0]

            def watch(epoch, seconds, current):
                return monitor(epoch, offset + seconds, current)

        solution = train(**kwargs, monitor=watch)
        spent[0] += solution.seconds
        return solution

    solution = attempt(recipe=recipe, seed=seed)
    if solution.stopped.outcome is Outcome.ZERO_SIGNAL:
        return solution

    def checked(solution: Solution) -> tuple[Solution, str | None]:
        if solution.stopped.outcome is Outcome.STOPPED:  # its monitor ended it: not judged,
            return solution, None  # so not retried
        return solution, _check_collapse(solution, operator.fn, signal, warm=init is not None)

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


class CollapseWarning(UserWarning):
    """RIFT training collapsed (see `rift`'s "Collapse") in every attempt it was given."""


# thresholds of `diagnose`: far from any reconstruction seen to work (docs/rift.md, Collapse)
_ZERO_ENERGY = 1e-2  # ‖Aρ‖/‖y‖ below this: the field predicts (almost) nothing
_GAIN_DRIFT = 1e-2  # |g| fallen below this share of its start: drifting to zero
_CONSTANT = 0.1  # std|ρ| / mean|ρ| below this: no structure
_FLAT = 0.99  # best loss above this share of the first epoch's: no descent


def diagnose(
    losses: np.ndarray,
    rho: np.ndarray,
    energy_ratio: float,
    gain_ratio: float,
    *,
    warm: bool = False,
) -> str | None:
    """Why a RIFT run collapsed, or None: the checks `rift` makes after training.

    **Arguments:**

    - `losses`: the training loss per epoch.
    - `rho`: the returned field's rendering on the grid.
    - `energy_ratio`: ‖Aρ‖/‖y‖ on (some of) the training viewpoints.
    - `gain_ratio`: |g| of the returned field over |g| at the start.
    - `warm`: the run started from a given field (a flat loss is then no collapse).

    **Returns:** a sentence naming the failure mode, or None.
    """
    magnitude = np.abs(np.asarray(rho))
    if not gain_ratio >= _GAIN_DRIFT:
        return f"gain drifted to zero: |g| fell to {gain_ratio:.2g} of its start"
    if not energy_ratio >= _ZERO_ENERGY:
        return f"zero field: its signals carry {100 * energy_ratio:.2g} % of the data's norm"
    mean = magnitude.mean()
    if mean > 0 and magnitude.std() < _CONSTANT * mean:
        return f"near-constant field: std|ρ| is {magnitude.std() / mean:.1%} of mean|ρ|"
    losses = np.asarray(losses)
    if not warm and len(losses) >= 3 and losses.min() > _FLAT * losses[0]:
        return (
            f"loss flat from the start: best {losses.min():.4g} against the first epoch's "
            f"{losses[0]:.4g}"
        )
    return None


def _check_collapse(solution: Solution, fn: GRT, signal, *, warm: bool) -> str | None:
    """`diagnose` for a trained run; ‖Aρ‖/‖y‖ from up to 10 evenly spread viewpoints."""
    index = spread(fn.n_views, 10)
    energy = float(_energy_ratio(*replicated((fn, solution.rho, signal, jnp.asarray(index)))))
    gain_ratio = float(abs(solution.field.gain)) / solution.stats["initial_gain"]
    rho = np.asarray(solution.rho)[fn.live_points()]  # padding must not move mean or spread
    return diagnose(solution.history.loss, rho, energy, gain_ratio, warm=warm)


@exact_jit
def _energy_ratio(fn: GRT, rho, signal, index) -> Float[Array, ""]:
    return jnp.linalg.norm(fn.subset(index)(rho)) / jnp.linalg.norm(signal[index])


def _train(
    operator: GRTOperator,
    signal,
    *,
    where: str,
    name: str,
    model,
    recipe: Recipe,
    width: int,
    depth: int,
    init: Field | None,
    extent: float | None,
    fine_points,
    fine_epochs: int | None,
    seed: int,
    progress: bool,
    monitor: Monitor | None,
) -> Solution:
    """One training run of `rift` (no collapse check): see there."""
    signal, _ = check_problem(where, operator, signal, None, recipe.epochs)
    fn = operator.fn
    if (solution := zero_signal(where, signal, jnp.zeros(fn.n_points, jnp.complex64))) is not None:
        return solution
    with jax.enable_x64(True):
        points = np.asarray(to_float64(fn.points))
    if extent is None:
        extent = float(np.max(np.abs(points))) or 1.0
    check_positive(f"{where}: `extent`", extent)
    coords = jnp.asarray(points, jnp.float32)
    last = recipe.epochs
    switch = None  # the first epoch on `fine_points`
    if fine_points is not None:
        fine_points = as_finite_array(fine_points, f"{where}: `fine_points`", np.float64)
        if fine_points.ndim != 2 or fine_points.shape[1] != 3 or len(fine_points) == 0:
            raise ValueError(
                f"{where}: `fine_points` must have shape (k, 3) with k ≥ 1, got "
                f"{fine_points.shape}."
            )
        fine_epochs = recipe.epochs // 2 if fine_epochs is None else fine_epochs
        whole = isinstance(fine_epochs, int | np.integer) and not isinstance(fine_epochs, bool)
        if not (whole and 1 <= fine_epochs < recipe.epochs):
            raise ValueError(
                f"{where}: `fine_epochs` must be an int in [1, {recipe.epochs - 1}] (the "
                f"epochs are {recipe.epochs}), got {fine_epochs!r}."
            )
        switch = recipe.epochs - fine_epochs + 1
    elif fine_epochs is not None:
        raise ValueError(
            f"{where}: `fine_epochs` needs `fine_points` (from fit: `train_granularity`)."
        )
    held = np.zeros(0, np.int64)
    if recipe.holdout:
        if recipe.holdout >= fn.n_views:
            raise ValueError(
                f"{where}: `holdout` ({recipe.holdout}) must leave viewpoints to train on; "
                f"there are {fn.n_views}."
            )
        held = spread(fn.n_views, recipe.holdout)
    trained_views = np.setdiff1d(np.arange(fn.n_views), held)
    field = _initial_field(where, model, init, width, depth, extent, seed)
    if recipe.learning_rate is None:
        recipe = dataclasses.replace(recipe, learning_rate=field.model.learning_rate)
    if recipe.gain and init is None:
        seen = (fn, signal) if not len(held) else (fn.subset(trained_views), signal[trained_views])
        gain = float(_energy_gain(*replicated((field, seen[0], coords, seen[1]))))
        if np.isfinite(gain) and gain != 0:
            field = Field(field.model, extent, gain)
    initial_gain = float(abs(field.gain))  # for the collapse check: has it drifted to zero?

    n_views = len(trained_views)
    batch = n_views if recipe.batch_views is None else min(recipe.batch_views, n_views)
    steps = _steps(n_views, batch)
    spec = jax.tree.map(eqx.is_inexact_array, field)
    if not recipe.gain:
        spec = eqx.tree_at(lambda f: (f.log_gain, f.phase), spec, (False, False))
    params, static = eqx.partition(field, spec)
    optimizer, opt_state = _optimizer(recipe, steps, params)
    params, opt_state, signal = replicated((params, opt_state, signal))
    energy = np.sum(np.abs(np.asarray(signal)) ** 2, axis=(1, 2, 3))
    held_index = replicated(jnp.asarray(held)) if len(held) else None
    holdout_residuals: list[float] = []
    rng = np.random.default_rng(seed)
    # the candidate points (the operator's, then `fine_points`) and the active ones among
    # them (None: all); the step sees only the active ones
    candidates = _Candidates(fn, points)
    active = None
    if recipe.prune is not None and init is not None:
        active = candidates.select(field, recipe.prune)
    step_points = candidates.restricted(active)
    stage_start = 1

    losses, residuals, seconds = [], [], []
    best_loss, best_params, best_epoch = math.inf, params, 0
    # the best parameters' own training set: (candidates, active set, fine stage or not)
    best_set = (candidates, active, False)
    reference, improved_epoch = math.inf, 0

    def result(stopped: Stop) -> Solution:
        best = eqx.combine(best_params, static)
        history = History(np.asarray(residuals), np.asarray(seconds), np.asarray(losses))
        trained_on, trained_active, fine = best_set
        trained = trained_on.live.copy()
        if trained_active is not None:
            trained[:] = False
            trained[trained_active] = True
        stats = {
            "model": name,
            "recipe": dataclasses.asdict(recipe),
            "best_epoch": best_epoch,
            "epochs_run": len(losses),
            "best_loss": best_loss,
            "steps_per_epoch": steps,
            "batch_views": batch,
            "active_points": int(trained.sum()),
            "initial_gain": initial_gain,
        }
        if len(held):
            stats |= {"holdout_views": held.tolist(), "holdout_residual": holdout_residuals}
        rho = best.render(coords)
        if fine:  # the field trained on `fine_points`: `trained` marks which
            stats |= {"fine_from_epoch": switch, "active": trained}
        elif trained_active is not None:  # what was trained: the field on its active set
            rho = jnp.where(jnp.asarray(trained), rho, 0)
        rho = fn.masked(rho)  # ρ = 0 on an operator's padding, as on any other solver's
        return Solution(rho, history, stopped, stats, field=best)

    start = time.perf_counter()
    bar = tqdm(total=recipe.epochs, desc=where, disable=not progress, delay=2.0, leave=False)
    with bar:
        epoch = 0
        while epoch < last:
            epoch += 1
            epoch_start = time.perf_counter()
            current = eqx.combine(params, static)
            if epoch == switch:  # coarse to fine: same parameters and optimizer state
                fine_fn = fn.on(split(fine_points))
                candidates = _Candidates(fine_fn, fine_points)
                active = None if recipe.prune is None else candidates.select(current, recipe.prune)
                step_points = candidates.restricted(active)
                stage_start = epoch
                # the best is now the fine stage's (a divergence before it keeps the coarse one)
                best_loss, reference, improved_epoch = math.inf, math.inf, epoch - 1
            elif (
                recipe.prune is not None
                and epoch > stage_start
                and (epoch - stage_start) % recipe.recheck_every == 0
            ):
                chosen = candidates.select(current, recipe.prune)
                if active is None or len(chosen) < 0.8 * len(active):
                    active = chosen  # shrink (a new set, one recompilation)
                elif not np.all(np.isin(chosen, active)):
                    active = np.union1d(active, chosen)  # grow back where the field rose
                else:
                    chosen = None  # no change: no recompilation
                if chosen is not None:
                    step_points = candidates.restricted(active, step_points)
            batches = trained_views[_batches(rng, n_views, batch)]
            indices = replicated(jnp.asarray(batches))
            step_losses, finite, step_residuals = [], [], []
            for k in range(steps):
                # device values only: one host sync per epoch lets JAX run ahead
                before = params
                params, opt_state, loss, ok, residual = _step(
                    params,
                    opt_state,
                    static,
                    optimizer,
                    recipe.loss_fn,
                    step_points,
                    signal,
                    indices[k],
                )
                step_losses.append(loss)
                finite.append(ok)
                step_residuals.append(residual)
            step_losses, finite, step_residuals = jax.device_get(
                (step_losses, finite, step_residuals)
            )
            if bad := [k for k in range(steps) if not (np.isfinite(step_losses[k]) and finite[k])]:
                k = bad[0]
                what = (
                    f"the loss was {step_losses[k]}"
                    if not np.isfinite(step_losses[k])
                    else "the gradient held NaN/inf values"
                )
                raise Diverged(
                    f"{where}: {what} at epoch {epoch} (step {k + 1} of {steps}); training "
                    f"stopped. The parameters of epoch {best_epoch} (loss {best_loss:.4g}) "
                    "are kept in this error's `.solution` (and `.result` from fit). Try a "
                    "lower learning_rate or a clip_norm.",
                    result(Stop(Outcome.DIVERGED, epoch)),
                )
            losses.append(float(np.mean(step_losses)))
            residuals.append(math.sqrt(float(np.sum(step_residuals)) / energy[batches].sum()))
            seconds.append(time.perf_counter() - start)
            progress_measure, measured = losses[-1], before
            if len(held):  # unseen views, at the parameters the epoch ended with
                held_residual = float(_residual(params, static, step_points, signal, held_index))
                holdout_residuals.append(held_residual)
                progress_measure, measured = held_residual, params
            if progress_measure < (1 - recipe.min_improvement) * reference:
                # progress that counts for `patience`: measured from the last epoch that made
                # such progress, so small steps cannot keep resetting the bar
                reference, improved_epoch = progress_measure, epoch
            if progress_measure < best_loss:
                # the parameters that the measure was taken at (for the loss, with one step
                # per epoch, exactly the epoch's): never ones whose own measure is unknown
                best_loss, best_params, best_epoch = progress_measure, measured, epoch
                best_set = (candidates, active, switch is not None and epoch >= switch)
            stop = False
            if monitor is not None:  # the best field so far, as `result` would return it
                best_field = functools.partial(eqx.combine, best_params, static)
                looked, stop = call_monitor(monitor, epoch, seconds[-1], best_field)
                start += looked
            bar.set_postfix(
                loss=f"{losses[-1]:.4g}",
                best=f"{best_loss:.4g}",
                s_per_epoch=f"{time.perf_counter() - epoch_start:.2f}",
                refresh=False,
            )
            bar.update()
            if stop:
                return result(Stop(Outcome.STOPPED, epoch))
            if recipe.patience is not None and epoch - improved_epoch >= recipe.patience:
                if switch is None or epoch >= switch:
                    return result(Stop(Outcome.CONVERGED, epoch))
                # the coarse stage has converged: the fine one starts now, with its epochs
                switch, last = epoch + 1, epoch + fine_epochs
                bar.total = last
    return result(Stop(Outcome.BUDGET, epoch))


class _Candidates:
    """The points a RIFT stage may train (the GRT `fn`'s) and how to pick its active set."""

    def __init__(self, fn: GRT, points: np.ndarray):  # points: fn's, in float64
        self.fn, self.points = fn, points
        # the points that exist: an operator padded to a shared size (`grt_operator`'s
        # pad_to) holds copies of one of them, which must never join an active set
        self.live = fn.live_points()
        self.coords = jnp.asarray(points, jnp.float32)
        self.tree = scipy.spatial.cKDTree(points)
        if len(points) > 1:  # neighbours: within √3 spacings (the 26 around a grid point)
            distance, _ = self.tree.query(points, k=2)
            spacing = np.min(distance[:, 1][distance[:, 1] > 0], initial=np.inf)
            self.radius = 1.01 * math.sqrt(3) * spacing if np.isfinite(spacing) else 0.0
        else:
            self.radius = 0.0

    def select(self, field: Field, prune: float) -> np.ndarray:
        """The sorted indices of the live points where |ρ| ≥ prune · max |ρ|, and their
        live neighbours."""
        magnitude = np.where(self.live, np.abs(np.asarray(field.render(self.coords))), 0)
        seeds = np.flatnonzero(self.live & (magnitude >= prune * magnitude.max()))
        near = self.tree.query_ball_point(self.points[seeds], self.radius, return_sorted=False)
        chosen = np.unique(np.concatenate([seeds, *map(np.asarray, near)]).astype(np.int64))
        return chosen[self.live[chosen]]

    def restricted(
        self, active: np.ndarray | None, current: _StepPoints | None = None
    ) -> _StepPoints:
        """The points a step trains: the active ones (all for None), replicated.

        An active set is padded to a size that changes rarely: the step is compiled for
        the number of points, and at the paper's cube each new size added 6-9 s to its
        epoch, against ~0.8 s for an epoch that compiles nothing (measured). ``current``'s
        size is kept while the set fits in it and fills at least two thirds of it (each
        step's cost follows the padded size); otherwise the set gets the next size of a
        ladder growing ~1.25x (`rift_jax._padding.ladder_size`). Padding repeats the first
        active point, not live (`GRT.live`: ρ = 0 there), so it adds nothing to the signals
        or gradients."""
        if active is None:
            return replicated(_StepPoints(self.fn, self.coords))
        n, limit = len(active), len(self.points)
        size = None if current is None else current.n_points
        if size is None or not n <= size <= 1.5 * n:
            size = min(ladder_size(n), limit)
        index = np.concatenate([active, np.full(size - n, active[0])])
        live = np.arange(size) < n
        points = jax.tree.map(lambda a: a[index], self.fn.points)
        fn = self.fn.on(points, None if live.all() else jnp.asarray(live))
        return replicated(_StepPoints(fn, self.coords[index]))


class _StepPoints(eqx.Module):
    """What a RIFT step trains: the GRT on its points and their float32 coordinates (the
    GRT's `live` marks padding, where ρ counts as 0)."""

    fn: GRT
    coords: Float[Array, "k 3"]

    @property
    def n_points(self) -> int:
        return len(self.coords)

    def render(self, field: Field) -> Complex[Array, " k"]:
        return field.render(self.coords)


def _recipe(where: str, recipe, overrides) -> Recipe:
    if isinstance(recipe, str):
        if recipe not in RECIPES:
            raise ValueError(
                f"{where}: unknown `recipe` {recipe!r}; choose one of {sorted(RECIPES)} or pass "
                "a rift_jax.solvers.Recipe."
            )
        recipe = RECIPES[recipe]
    if not isinstance(recipe, Recipe):
        raise ValueError(f"{where}: `recipe` must be a name or a Recipe, got {recipe!r}.")
    fields = {f.name for f in dataclasses.fields(Recipe)}
    if unknown := set(overrides) - fields:
        raise ValueError(
            f"{where}: unknown option(s) {sorted(unknown)}; the Recipe's fields are "
            f"{sorted(fields)}, besides model, recipe, width, depth, init, extent, fine_points, "
            "fine_epochs, seed and progress."
        )
    return dataclasses.replace(recipe, **overrides)


def _initial_field(where, model, init, width, depth, extent, seed) -> Field:
    if init is not None:
        if not isinstance(init, Field):
            raise ValueError(
                f"{where}: `init` must be a rift_jax.Field, got {type(init).__name__}."
            )
        if isinstance(model, str) and model in MODELS and type(init.model) is not MODELS[model]:
            raise ValueError(
                f"{where}: `init` holds a {type(init.model).__name__}, but the method asks for "
                f"{model!r} ({MODELS[model].__name__})."
            )
        return init  # it keeps its own extent (coordinate scale), whatever this grid's
    if isinstance(model, str):
        if model not in MODELS:
            raise ValueError(f"{where}: unknown `model` {model!r}; choose one of {sorted(MODELS)}.")
        model = MODELS[model](width=width, depth=depth, key=jax.random.key(seed))
    elif not isinstance(model, AbstractINR):
        raise ValueError(
            f"{where}: `model` must be a name or an AbstractINR, got {type(model).__name__}."
        )
    return Field(model, extent)


def _steps(n: int, size: int) -> int:
    return -(-n // size)


def _batches(rng: np.random.Generator, n: int, size: int) -> np.ndarray:
    """One epoch's viewpoint indices, (steps, size): a fresh permutation, filled up to a
    whole number of batches with its own first entries (one batch shape, one compilation)."""
    order = rng.permutation(n)
    steps = _steps(n, size)
    return np.concatenate([order, order[: steps * size - n]]).reshape(steps, size)


def _optimizer(
    recipe: Recipe, steps_per_epoch: int, params
) -> tuple[optax.GradientTransformation, Any]:
    """AdamW with the recipe's schedule and clipping, and its state for ``params``.

    The learning rate is a value in the state (`optax.inject_hyperparams`), not a constant
    of the optimizer: a collapsed run's retry at half the rate then reuses the compiled
    step, which otherwise compiled again (3-8 s)."""
    every = _halving_steps(recipe, steps_per_epoch)
    optimizer = _adamw(every, recipe.adam_eps, recipe.weight_decay, recipe.clip_norm)
    state = optimizer.init(params)
    rate = state.hyperparams["learning_rate"]
    state.hyperparams["learning_rate"] = jnp.asarray(recipe.learning_rate, rate.dtype)
    return optimizer, state


@functools.cache  # one optimizer per setting: the step's jit cache keys on it
def _adamw(
    every: int | None, eps: float, weight_decay: float, clip_norm: float | None
) -> optax.GradientTransformation:
    return optax.inject_hyperparams(
        _adamw_factory, static_args=("every", "eps", "weight_decay", "clip_norm")
    )(learning_rate=1.0, every=every, eps=eps, weight_decay=weight_decay, clip_norm=clip_norm)


def _adamw_factory(learning_rate, every, eps, weight_decay, clip_norm):
    """AdamW on `_schedule`, after clipping the gradient to ``clip_norm`` (None: none)."""
    schedule = _schedule(learning_rate, every)
    adamw = optax.adamw(schedule, eps=eps, weight_decay=weight_decay, mask=_decay_mask)
    if clip_norm is None:
        return adamw
    return optax.chain(optax.clip_by_global_norm(clip_norm), adamw)


def _halving_steps(recipe: Recipe, steps_per_epoch: int) -> int | None:
    """The recipe's `halve_every` in optimizer steps (None: a constant learning rate)."""
    if recipe.halve_every is None:
        return None
    return max(1, round(recipe.halve_every * steps_per_epoch))


def _schedule(learning_rate, every: int | None):
    """The learning rate per optimizer step: constant, or halved every ``every`` steps."""
    if every is None:
        return learning_rate
    return optax.exponential_decay(learning_rate, every, decay_rate=0.5, staircase=True)


def _decay_mask(params: Field) -> Field:
    """Weight decay on the INR, not on the gain (decay would pull |g| towards 1)."""
    mask = jax.tree.map(lambda _: True, params)
    if params.log_gain is None:  # gain frozen: not among the parameters
        return mask
    return eqx.tree_at(lambda f: (f.log_gain, f.phase), mask, (False, False))


@exact_jit
def _energy_gain(field: Field, fn: GRT, coords, signal) -> Float[Array, ""]:
    """The g > 0 with ‖g·Aρ‖ = ‖y‖ for the field's ρ. (Not the least-squares gain: data
    that no ρ on this grid explains, such as the paper's two-grid protocol, make that gain
    ~0, and a zero prediction is where magnitude losses are flat.)"""
    return jnp.linalg.norm(signal) / jnp.linalg.norm(fn(field.render(coords)))


@exact_jit
def _residual(params, static, points: _StepPoints, signal, index) -> Float[Array, ""]:
    """‖y_b − A_b ρ‖/‖y_b‖ over the viewpoints ``index``."""
    rho = points.render(eqx.combine(params, static))
    target = signal[index]
    pred = points.fn.subset(index)(rho)
    return jnp.linalg.norm(pred - target) / jnp.linalg.norm(target)


@exact_jit
def _step(params, opt_state, static, optimizer, loss_fn, points: _StepPoints, signal, index):
    """One optimizer step on the viewpoints ``index``: (params, state, loss, all gradients
    finite, ‖y_b − A_b ρ‖²)."""
    rows = points.fn.subset(index)
    target = signal[index]

    def objective(params):
        rho = points.render(eqx.combine(params, static))
        pred = as_complex(realified(rows)(as_pair(rho)))
        return loss_fn(pred, target), pred

    (loss, pred), grads = eqx.filter_value_and_grad(objective, has_aux=True)(params)
    updates, opt_state = optimizer.update(grads, opt_state, params)
    finite = jnp.all(jnp.asarray([jnp.all(jnp.isfinite(g)) for g in jax.tree.leaves(grads)]))
    residual = jnp.sum(jnp.abs(pred - target) ** 2)
    return eqx.apply_updates(params, updates), opt_state, loss, finite, residual
