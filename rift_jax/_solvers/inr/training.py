"""One training run of RIFT: a `Field` fitted through the GRT, one epoch per iteration of
the shared `iterate` (its progress bar, stopping rule and divergence path).

An epoch is a pass over the training viewpoints (several passes when they are fewer than
the recipe's `epoch_views`) in minibatches, each one jitted step
(value-and-grad and the optax update); the host syncs once per epoch, so JAX runs ahead
within it. Between epochs the host picks the active set and, coarse to fine, moves the
field to its fine points.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from ..._geometry import spread
from ..._losses import complex_mse
from ..._models import MODELS, AbstractINR, Field
from ..._operator import GRT, GRTOperator
from ..._precision import exact_jit, split, to_float64
from ..._sharding import replicated
from ..._validation import as_finite_array, check_positive
from .._common import as_complex, as_pair, check_problem, norms, realified, zero_signal
from .._solution import Monitor, Patience, Record, Run, Solution, iterate
from .active_set import Candidates, StepPoints
from .optimizer import optimizer_for
from .recipe import Recipe
from .warm_start import Start, fitted


class _Epochs(NamedTuple):
    """What one epoch hands the next: the parameters and optimizer state, the stage's
    candidate points and active set (None: all) with the step's points, when the stage
    began, and the first epoch on the fine points (None: no fine stage, or not yet known)."""

    epoch: int
    params: Any
    opt_state: Any
    candidates: Candidates
    active: np.ndarray | None
    points: StepPoints
    stage_start: int
    switch: int | None


def train(
    operator: GRTOperator,
    signal,
    *,
    where: str,
    name: str,
    model,
    recipe: Recipe,
    width: int | None,
    depth: int | None,
    init: Field | None,
    warm: Start | None,
    extent: float | None,
    fine_points,
    fine_epochs: int | None,
    seed: int,
    progress: bool,
    monitor: Monitor | None,
    noise: float | None = None,
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
    fine_points, fine_epochs, switch = _fine_stage(where, recipe, fine_points, fine_epochs)
    held = np.zeros(0, np.int64)
    if recipe.holdout:
        if recipe.holdout >= fn.n_views:
            raise ValueError(
                f"{where}: `holdout` ({recipe.holdout}) must leave viewpoints to train on; "
                f"there are {fn.n_views}."
            )
        held = spread(fn.n_views, recipe.holdout)
    trained_views = np.setdiff1d(np.arange(fn.n_views), held)
    field = initial_field(where, model, init, width, depth, extent, seed)
    if recipe.learning_rate is None:
        recipe = dataclasses.replace(recipe, learning_rate=field.model.learning_rate)
    started = None if warm is None else dict(warm.stats)  # a least-squares start: how it went
    if warm is not None and warm.image is not None:
        field, started["image_error"] = fitted(field, coords, warm, fn.live_points())
        init = field  # from here on, as a given field
    if recipe.gain and init is None:
        seen = (fn, signal) if not len(held) else (fn.subset(trained_views), signal[trained_views])
        gain = float(_energy_gain(*replicated((field, seen[0], coords, seen[1]))))
        if np.isfinite(gain) and gain != 0:
            field = Field(field.model, extent, gain)
    initial_gain = float(abs(field.gain))  # for the collapse check: has it drifted to zero?

    # The step trains the field on coordinates already divided by its extent (a float32
    # division, as `Field` does it), so that its compiled program does not depend on the
    # extent, a static field of `Field`: fits of other extents share it.
    scale = field.extent
    field = on_extent(field, 1.0)
    n_views = len(trained_views)
    measurements = int(np.prod(signal.shape[1:]))  # per view: frequencies × TX × RX
    batch = n_views if recipe.batch_views is None else min(recipe.batch_views, n_views)
    passes = recipe.passes(n_views)
    steps = n_steps(passes * n_views, batch)
    spec = jax.tree.map(eqx.is_inexact_array, field)
    if not recipe.gain:
        spec = eqx.tree_at(lambda f: (f.log_gain, f.phase), spec, (False, False))
    params, static = eqx.partition(field, spec)
    optimizer, opt_state = optimizer_for(recipe, steps, params)
    params, opt_state, signal = replicated((params, opt_state, signal))
    energy = np.sum(np.abs(np.asarray(signal)) ** 2, axis=(1, 2, 3))
    held_index = replicated(jnp.asarray(held)) if len(held) else None
    holdout_residuals: list[float] = []
    rng = np.random.default_rng(seed)
    # the candidate points (the operator's, then `fine_points`) and the active ones among
    # them (None: all); the step sees only the active ones
    candidates = Candidates(fn, points, scale)
    active = None
    if recipe.prune is not None and init is not None:
        active = candidates.select(field, recipe.prune)
    step_points = candidates.restricted(active)
    step_sizes = {step_points.n_points}  # the sizes the step compiled for (a stat)
    start = _Epochs(0, params, opt_state, candidates, active, step_points, 1, switch)

    def one_epoch(state: _Epochs) -> tuple[_Epochs, Record]:
        k = state.epoch + 1
        candidates, active = state.candidates, state.active
        step_points, stage_start = state.points, state.stage_start
        current = eqx.combine(state.params, static)
        fresh = k == state.switch
        if fresh:  # coarse to fine: same parameters and optimizer state
            candidates = Candidates(fn.on(split(fine_points)), fine_points, scale)
            active = None if recipe.prune is None else candidates.select(current, recipe.prune)
            step_points, stage_start = candidates.restricted(active), k
            step_sizes.add(step_points.n_points)
        elif (
            recipe.prune is not None
            and k > stage_start
            and (k - stage_start) % recipe.recheck_every == 0
        ):
            chosen = candidates.select(current, recipe.prune)
            if active is None or len(chosen) < 0.8 * len(active):
                active = chosen  # shrink (a new set, one recompilation)
            elif not np.all(np.isin(chosen, active)):
                active = np.union1d(active, chosen)  # grow back where the field rose
            else:
                chosen = None  # no change: no recompilation
            if chosen is not None:
                # each point's work in the epochs left to these candidates (the coarse
                # stage's end, or the run's), forward and back; patience may end it sooner
                end = (
                    state.switch
                    if state.switch is not None and k < state.switch
                    else recipe.epochs + 1
                )
                point_cost = measurements * passes * n_views * (end - k)
                step_points = candidates.restricted(active, step_points, point_cost)
                step_sizes.add(step_points.n_points)
        batches = trained_views[batch_order(rng, n_views, batch, passes)]
        indices = replicated(jnp.asarray(batches))
        # traced, not static: steps on stages of other live counts share a program
        over = replicated(jnp.asarray(candidates.n_live, jnp.float32))
        params, opt_state = state.params, state.opt_state
        step_losses, finite, step_residuals = [], [], []
        for i in range(steps):
            # device values only: one host sync per epoch lets JAX run ahead
            before = params
            params, opt_state, loss, ok, residual = _step(
                params, opt_state, static, optimizer, recipe.loss_fn, step_points, signal,
                indices[i], sparsity=float(recipe.sparsity), over=over,
            )  # fmt: skip
            step_losses.append(loss)
            finite.append(ok)
            step_residuals.append(residual)
        step_losses, finite, step_residuals = jax.device_get((step_losses, finite, step_residuals))
        if bad := [i for i in range(steps) if not (np.isfinite(step_losses[i]) and finite[i])]:
            i = bad[0]
            what = (
                f"the loss was {step_losses[i]}"
                if not np.isfinite(step_losses[i])
                else "the gradient held NaN/inf values"
            )
            return state, Record(math.nan, failure=f"{what} in step {i + 1} of {steps}")
        loss = float(np.mean(step_losses))
        measure, measured = loss, before  # with one step per epoch, exactly the epoch's
        if len(held):  # unseen views, at the parameters the epoch ended with
            measure = float(_residual(params, static, step_points, signal, held_index))
            holdout_residuals.append(measure)
            measured = params
        following = _Epochs(
            k, params, opt_state, candidates, active, step_points, stage_start, state.switch
        )
        fine = state.switch is not None and k >= state.switch
        fine_from = state.switch if fine else None  # the first epoch on the fine points
        return following, Record(
            residual=math.sqrt(float(np.sum(step_residuals)) / energy[batches].sum()),
            measure=measure,
            loss=loss,
            at=(measured, candidates, active, fine_from),  # the best's own training set
            fresh=fresh,
        )

    def fine_after_coarse(state: _Epochs, k: int) -> tuple[_Epochs, int] | None:
        """Patience ended the coarse stage: the fine one starts now, with its epochs."""
        if state.switch is None or k >= state.switch:
            return None
        return state._replace(switch=k + 1), fine_epochs

    def result(run: Run) -> Solution:
        best_params, trained_on, trained_active, fine_from = run.best
        best = on_extent(eqx.combine(best_params, static), scale)
        index = run.stats["best"]
        measures = holdout_residuals if len(held) else run.history.loss
        trained = trained_on.live.copy()
        if trained_active is not None:
            trained[:] = False
            trained[trained_active] = True
        stats = {
            "model": name,
            "recipe": dataclasses.asdict(recipe),
            "best_epoch": 0 if index is None else index + 1,
            "epochs_run": len(run.history),
            "best_loss": math.inf if index is None else float(measures[index]),
            "steps_per_epoch": steps,
            "passes_per_epoch": passes,  # over the trained views (`epoch_views`)
            "batch_views": batch,
            "active_points": int(trained.sum()),
            "step_sizes": sorted(step_sizes),  # padded point counts trained (one program each)
            "initial_gain": initial_gain,
            "noise_share": share,  # of the trained views' power (0: noise-free or unknown)
        }
        if len(held):
            stats |= {"holdout_views": held.tolist(), "holdout_residual": holdout_residuals}
        if started is not None:
            stats["warm_start"] = started
        rho = best.render(coords)
        if fine_from is not None:  # the field trained on `fine_points`: `trained` marks which
            stats |= {"fine_from_epoch": fine_from, "active": trained}
        elif trained_active is not None:  # what was trained: the field on its active set
            rho = jnp.where(jnp.asarray(trained), rho, 0)
        rho = fn.masked(rho)  # ρ = 0 on an operator's padding, as on any other solver's
        return Solution(rho, run.history, run.stopped, stats, field=best)

    share = noise_share(noise, energy[trained_views], measurements)
    patience = None
    if recipe.patience is not None:
        # what a fit of the signal alone leaves of the measure: of a held-out residual, its
        # views' noise's norm; of complex MSE, the noise's power; another loss's: not known
        floor = share if recipe.loss_fn is complex_mse else 0.0
        if len(held):
            floor = math.sqrt(noise_share(noise, energy[held], measurements))
        patience = Patience(recipe.patience, recipe.min_improvement, floor)
    run = iterate(
        one_epoch,
        start,
        iterations=recipe.epochs,
        until=patience,
        progress=progress,
        desc=where,
        unit="epoch",
        image=lambda state: (state.params, state.candidates, state.active, None),
        start_measure=math.inf,
        monitor=monitor,
        shown=lambda best: on_extent(eqx.combine(best[0], static), scale),
        then=fine_after_coarse if switch is not None else None,
        finish=result,
        hint="Try a lower learning_rate or a clip_norm.",
        with_loss=True,
    )
    return result(run)


def _fine_stage(where: str, recipe: Recipe, fine_points, fine_epochs):
    """Checked `fine_points` (float64) and `fine_epochs`, and the first fine epoch when the
    coarse stage runs its whole budget (None: no fine stage)."""
    if fine_points is None:
        if fine_epochs is not None:
            raise ValueError(
                f"{where}: `fine_epochs` needs `fine_points` (from fit: `train_granularity`)."
            )
        return None, None, None
    fine_points = as_finite_array(fine_points, f"{where}: `fine_points`", np.float64)
    if fine_points.ndim != 2 or fine_points.shape[1] != 3 or len(fine_points) == 0:
        raise ValueError(
            f"{where}: `fine_points` must have shape (k, 3) with k ≥ 1, got {fine_points.shape}."
        )
    given = fine_epochs is not None
    fine_epochs = fine_epochs if given else recipe.epochs // 2
    whole = isinstance(fine_epochs, int | np.integer) and not isinstance(fine_epochs, bool)
    if not (whole and 1 <= fine_epochs < recipe.epochs):
        got = f"got {fine_epochs!r}" if given else f"half the epochs by default: {fine_epochs}"
        raise ValueError(
            f"{where}: `fine_epochs` must be an int in [1, {recipe.epochs - 1}] (the epochs "
            f"are {recipe.epochs}), {got}."
        )
    return fine_points, fine_epochs, recipe.epochs - fine_epochs + 1


def initial_field(where, model, init, width, depth, extent, seed) -> Field:
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
        sizes = {k: v for k, v in (("width", width), ("depth", depth)) if v is not None}
        model = MODELS[model](**sizes, key=jax.random.key(seed))
    elif not isinstance(model, AbstractINR):
        raise ValueError(
            f"{where}: `model` must be a name or an AbstractINR, got {type(model).__name__}."
        )
    return Field(model, extent)


def on_extent(field: Field, extent: float) -> Field:
    """``field``'s INR and gain (the same arrays) mapping ±``extent`` onto the INR's cube."""
    if field.extent == extent:
        return field
    moved = Field(field.model, extent)
    return eqx.tree_at(lambda f: (f.log_gain, f.phase), moved, (field.log_gain, field.phase))


def n_steps(n: int, size: int) -> int:
    return -(-n // size)


def batch_order(rng: np.random.Generator, n: int, size: int, passes: int = 1) -> np.ndarray:
    """One epoch's viewpoint indices, (steps, size): ``passes`` fresh permutations one after
    another, filled up to a whole number of batches with their own first entries (one batch
    shape, one compilation)."""
    order = np.concatenate([rng.permutation(n) for _ in range(passes)])
    steps = n_steps(passes * n, size)
    return np.concatenate([order, order[: steps * size - passes * n]]).reshape(steps, size)


def noise_share(noise: float | None, energy: np.ndarray, measurements: int) -> float:
    """The share of the data's power that is noise of standard deviation ``noise`` per
    sample (None: unknown, 0), from the views' ``energy`` of ``measurements`` samples each;
    at most 1."""
    if not noise:
        return 0.0
    power = float(np.sum(energy)) / (len(energy) * measurements)
    return min(noise**2 / power, 1.0) if power > 0 else 0.0


def _energy_gain(field: Field, fn: GRT, coords, signal) -> Float[Array, ""]:
    """The g > 0 with ‖g·Aρ‖ = ‖y‖ for the field's ρ. (Not the least-squares
    gain: data that no ρ on this grid explains, such as the paper's two-grid protocol, make
    that gain ~0, and a zero prediction is where magnitude losses are flat.) On the
    operator's own compiled forward (see `rift_jax._solvers._common.misfit`)."""
    measured, predicted = norms(signal, fn(field.render(coords)))
    return measured / predicted


@exact_jit
def _residual(params, static, points: StepPoints, signal, index) -> Float[Array, ""]:
    """‖y_b − A_b ρ‖/‖y_b‖ over the viewpoints ``index``."""
    rho = points.render(eqx.combine(params, static))
    target = signal[index]
    pred = points.fn.subset(index)(rho)
    return jnp.linalg.norm(pred - target) / jnp.linalg.norm(target)


@exact_jit
def _step(
    params, opt_state, static, optimizer, loss_fn, points: StepPoints, signal, index,
    sparsity: float = 0.0, over: Float[Array, ""] | float = 1.0,
):  # fmt: skip
    """One optimizer step on the viewpoints ``index``: (params, state, loss, all gradients
    finite, ‖y_b − A_b ρ‖²). The loss is the data term, plus ``sparsity`` times
    `concentration` of ρ over the stage's ``over`` live candidate points when it is not 0
    (``sparsity`` is static: without the term, the program is the same as before it
    existed; ``over`` is traced, so that it does not key the compilation)."""
    rows = points.fn.subset(index)
    target = signal[index]

    def objective(params):
        rho = points.render(eqx.combine(params, static))
        pred = as_complex(realified(rows)(as_pair(rho)))
        loss = loss_fn(pred, target)
        if sparsity:
            loss = loss + sparsity * concentration(rho, points.fn.live, over)
        return loss, pred

    (loss, pred), grads = eqx.filter_value_and_grad(objective, has_aux=True)(params)
    updates, opt_state = optimizer.update(grads, opt_state, params)
    finite = jnp.all(jnp.asarray([jnp.all(jnp.isfinite(g)) for g in jax.tree.leaves(grads)]))
    residual = jnp.sum(jnp.abs(pred - target) ** 2)
    return eqx.apply_updates(params, updates), opt_state, loss, finite, residual


def concentration(rho: Complex[Array, " n"], live, k: Float[Array, ""] | int) -> Float[Array, ""]:
    """‖ρ‖₁ / (√k‖ρ‖₂) over the live entries of ``rho``, for a field on k points (the
    stage's candidates) that is 0 off these entries (an active set's): a sparsity measure
    that ignores scale (the gain carries it), 1 for a flat field on all k and 1/√k for a
    single point, and that does not jump when the active set changes."""
    magnitude = jnp.abs(rho) if live is None else jnp.where(live, jnp.abs(rho), 0)
    norm = jnp.sqrt(k * jnp.sum(magnitude**2))
    return jnp.sum(magnitude) / jnp.maximum(norm, jnp.finfo(jnp.float32).tiny)
