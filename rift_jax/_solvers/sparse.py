"""FISTA with a sparsity prior, by jaxopt's proximal gradient solver.

jaxopt is the only module in rift_jax that imports jaxopt: the library warns on import
that it is no longer maintained, and that warning (only that one) is silenced here.
"""

from __future__ import annotations

import functools
import time
import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex

from .. import _holdout
from .._operator import GRT, GRTOperator
from .._precision import exact_jit
from .._sharding import replicated
from .._validation import check_positive_int, is_finite_nonnegative
from ._common import as_complex, as_pair, check_problem, relative, residual_of, zero_signal
from ._solution import History, Monitor, Outcome, Patience, Solution, iterate

with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message=".*no longer maintained", category=DeprecationWarning)
    import jaxopt

SPARSITIES = (0.5, 0.3, 0.2, 0.1, 0.05, 0.02)
"""The λ path of ``sparsity="auto"`` (λ relative to max|Aᴴy|), sparsest first. Replayed
on the stress grid, the λ chosen ranged over 0.05-0.5 (0.2 in the median of the noise-free
runs, 0.5 for the sparsest scenes: the parking lot, the weak target from 10-30 views) and
0.02 was never chosen
(docs/experiments.md, "FISTA's λ on held-out views")."""
UNSPLIT = 0.05  # ``sparsity="auto"``'s λ where too few views leave none to hold out
_PAST_BEST = 2  # the path stops after this many λ in a row predict worse than the best


def fista(
    operator: GRTOperator,
    signal: Complex[Array, "n_views n_freq n_tx n_rx"],
    *,
    iterations: int = 100,
    sparsity: float | str = "auto",
    nonnegative: bool = False,
    power_iterations: int = 10,
    tol: float = 1e-3,
    seed: int = 0,
    noise: float | None = None,
    x0: Complex[Array, " n_points"] | None = None,
    progress: bool = True,
    monitor: Monitor | None = None,
) -> Solution:
    """min ½‖Aρ − y‖² + λ‖ρ‖₁ by accelerated proximal gradient (FISTA,
    `jaxopt.ProximalGradient`), optionally with ρ real and ≥ 0.

    The prox of λ‖ρ‖₁ for complex ρ shrinks each magnitude and keeps the phase,
    ρ·max(0, 1 − λt/|ρ|) (t the step); with ``nonnegative=True`` ρ is kept real and
    max(0, Re ρ − λt). ``λ = sparsity · max|Aᴴy|``: at ``sparsity ≥ 1`` the solution is 0.
    With ``sparsity="auto"`` (the default) λ is chosen on held-out viewpoints: a fifth of
    the views (evenly spread) are held out, the path `SPARSITIES` is solved on the rest
    (sparsest first, each started from the one before, until two in a row predict worse
    than the best so far), and the λ whose image predicts the held-out signals best (the
    lowest `rift_jax._holdout.holdout_residual`: at their best complex gain; the sparser on
    a tie) is solved again on every view, from the start: the result is
    ``fista(sparsity=stats["sparsity"])``'s (unless ``monitor`` stopped the path: below).
    With too few views to hold any out, `UNSPLIT`.
    Where the noise is known (``noise``), λ is at least max|Aᴴn| for a draw n of it: the
    smallest λ at which noise alone reconstructs to ρ = 0 (then 0 is optimal: |Aᴴn| ≤ λ
    everywhere), so that the prior keeps no point that the noise could have made. On the
    stress grid's data (100 views) max|Aᴴn| is 0.6-1.0 % of max|Aᴴy| at 20 dB, 6-10 % at
    0 dB and 18-32 % at −10 dB: from about 0 dB down it, not ``sparsity``, sets λ.
    The fixed step t = 1/L uses L = ‖A‖² from ``power_iterations`` power iterations on AᴴA
    (seeded), times 1.1 because the power method approaches ‖A‖² from below. The gradient
    Aᴴ(Aρ − y) comes from the adjoint kernel (jaxopt is given value and gradient together).

    **What an iteration is:** one FISTA step: a forward and an adjoint pass over all
    viewpoints. Estimating L costs ``power_iterations`` more, and λ one adjoint pass (two
    with ``noise``). ``sparsity="auto"`` adds the path's solves on four fifths of the views
    (each up to ``iterations`` steps; the sparser ones stop sooner) before the final one.

    **Arguments:**

    - `operator`, `signal`, `x0`, `progress`, `monitor`: as `kaczmarz`. With
      ``sparsity="auto"`` the monitor watches the λ path's solves too (each counts its
      iterations from 1, and shows its image fitted on the path's views); if it ends one,
      the path ends there and the final solve starts from the chosen λ's image.
    - `iterations`: FISTA steps.
    - `sparsity`: λ relative to max|Aᴴy|, in [0, 1), or "auto": chosen on held-out views.
    - `nonnegative`: constrain ρ to real, non-negative values.
    - `power_iterations`: power iterations for ‖A‖².
    - `tol`: stop when the residual stagnates (`Patience.from_tol`); 0 runs every step.
    - `seed`: seeds the power iteration's start and the draw of ``noise``.
    - `noise`: the noise's standard deviation per sample (complex: E|n|² = σ²), in the
      units of `signal`; `fit` passes it from ``snr_db`` or a `RadarData`'s SNR. None or 0:
      not known, and λ is ``sparsity``'s alone.

    **Returns:** a `Solution` holding the iterate with the lowest residual (FISTA's is not
    monotone). ``history.residual[k]`` is ‖y − Aρ_k‖/‖y‖ of iterate k, exact and free: FISTA
    evaluates the residual at its extrapolated point y_k = (1 + m)ρ_k − mρ_{k−1}, and the
    residual is affine in ρ, so r(ρ_k) = (r(y_k) + m r(ρ_{k−1}))/(1 + m). Iterate k's
    residual is known once step k + 1 has run; the last iterate's costs one forward pass.
    ``stats``: ``lambda`` (λ), ``sparsity``, ``lipschitz`` (1.1·L), ``nonnegative``, with
    ``noise`` ``noise_lambda`` (max|Aᴴn| of its draw), and with ``sparsity="auto"`` and
    enough views ``sparsity_path``: the held-out viewpoints (``views``) and, for each
    sparsity tried on the others in the path's order, its ``lambda``, `rift_jax._holdout.score`
    (``holdout_residual``, ``holdout_errors``) and ``iterations`` (``scores``). Where the
    noise's floor is above some of the path's λ, they are tried once, as sparsity 0: λ at
    the floor (above all of them, nothing is tried, and sparsity is 0). ``stopped`` (True)
    where the monitor ended the path.
    """
    where = "fista"
    signal, x = check_problem(where, operator, signal, x0, iterations)
    check_positive_int(f"{where}: `power_iterations`", power_iterations)
    if sparsity != "auto" and (isinstance(sparsity, str) or not 0 <= sparsity < 1):
        raise ValueError(f"{where}: `sparsity` must be in [0, 1) or 'auto', got {sparsity!r}.")
    if noise is not None and not is_finite_nonnegative(noise):
        raise ValueError(f"{where}: `noise` must be a finite σ ≥ 0 or None, got {noise!r}.")
    if (solution := zero_signal(where, signal, x)) is not None:
        return solution
    fn = operator.fn
    lipschitz = 1.1 * _power_norm(fn, power_iterations, seed)
    solve = functools.partial(
        _minimize, lipschitz=lipschitz, nonnegative=nonnegative, iterations=iterations,
        tol=tol, progress=progress,
    )  # fmt: skip
    path = {}
    if sparsity == "auto":
        sparsity, path, stopped_at = _choose(fn, signal, x, noise, seed, solve, monitor)
        if stopped_at is not None:  # the monitor ended the path: on from its best image
            x = stopped_at
    largest, noise_lam = _scales(fn, signal, noise, seed)
    lam = max(sparsity * largest, noise_lam)
    rho, history, stopped, stats = solve(fn, signal, x, lam, monitor=monitor, desc=where)
    stats |= {"lambda": lam, "sparsity": sparsity, "lipschitz": lipschitz}
    stats["nonnegative"] = nonnegative
    if noise:  # λ's floor from the noise: max|Aᴴn| of its draw
        stats["noise_lambda"] = noise_lam
    if path:
        stats["sparsity_path"] = path
    return Solution(rho, history, stopped, stats)


def _scales(fn: GRT, signal, noise: float | None, seed: int) -> tuple[float, float]:
    """(max|Aᴴy|, the noise's floor on λ: max|Aᴴn| for a draw n of it, 0 without it)."""
    largest = float(_max_backprojection(fn, signal))
    if not noise:
        return largest, 0.0
    return largest, float(_max_backprojection(fn, _noise_draw(signal.shape, noise, seed)))


def _choose(fn: GRT, signal, x, noise, seed, solve, monitor) -> tuple[float, dict, Any]:
    """``sparsity="auto"``: (the sparsity chosen, the path's record, and None, or the chosen
    λ's image where ``monitor`` ended the path; see `fista`). Where the noise's floor is
    above some of `SPARSITIES`' λ, they are one candidate, 0 (λ at the floor), which the
    final solve turns into its own data's floor."""
    views = _holdout.split(fn.n_views)
    if views is None:
        return UNSPLIT, {}, None
    kept, held = views
    fit_on, fit_signal = fn.subset(kept), signal[kept]
    largest, floor = _scales(fit_on, fit_signal, noise, seed)
    candidates = [s for s in SPARSITIES if s * largest > floor]
    if len(candidates) < len(SPARSITIES):
        candidates.append(0.0)
    if len(candidates) == 1:  # the floor is above every λ of the path: nothing to choose
        return candidates[0], {}, None
    judge_on, held_signal = fn.subset(held), np.asarray(signal[held])
    scores, images, worse, stopped = {}, {}, 0, False
    for k, sparsity in enumerate(candidates):
        desc = f"fista, λ {k + 1} of {len(candidates)}, scored on held-out views"
        lam = max(sparsity * largest, floor)
        x, history, stop, _ = solve(fit_on, fit_signal, x, lam, monitor=monitor, desc=desc)
        images[sparsity] = x  # and the next λ starts from it: denser from here
        scores[sparsity] = _holdout.score(judge_on(x), held_signal) | {
            "lambda": lam, "iterations": len(history.residual) - 1,
        }  # fmt: skip
        best = min(r["holdout_residual"] for r in scores.values())
        worse = worse + 1 if scores[sparsity]["holdout_residual"] > best else 0
        stopped = stop.outcome is Outcome.STOPPED  # e.g. `fit`'s time limit: no more λ
        if stopped or worse == _PAST_BEST:  # past the best: denser λ, dearer and worse solves
            break
    record = {"views": held.tolist(), "scores": {str(s): v for s, v in scores.items()}}
    # the lowest held-out residual (the sparser on a tie). Not the one-standard-error rule
    # of `fit`'s method choice: from 10 views 2 are held out, too few for a standard
    # error, and the sparsest λ kept its place where the floor predicted clearly better
    # (0.990 against 0.999, 0.011 lower on one view and 0.002 higher on the other)
    chosen = min(scores, key=lambda s: scores[s]["holdout_residual"])
    if stopped:
        record["stopped"] = True
    return chosen, record, images[chosen] if stopped else None


def _minimize(
    fn: GRT, signal, x, lam: float, *, lipschitz, nonnegative, iterations, tol, progress,
    monitor=None, desc: str,
):  # fmt: skip
    """FISTA for ½‖Aρ − y‖² + λ‖ρ‖₁ on ``fn`` and ``signal`` from ``x``: (ρ, history, stop,
    stats)."""
    # traced scalars, not Python floats, so that a new signal or operator compiles no step
    # again. jaxopt holds its step as a static setting, so it steps by 1 on the objective
    # scaled by t = 1/L and prox'es tλ‖·‖₁: the same iterates, x − 1·(t∇f) and a shrink by tλ
    step_size = jnp.float32(1.0 / lipschitz)
    lam = step_size * jnp.float32(lam)
    norm = jnp.linalg.norm(signal)
    solver = _solver(nonnegative)
    pair = as_pair(x)
    if nonnegative:
        pair = _prox_nonnegative(pair, 0.0)
    last = {}

    def step(carry):
        carry = _update(solver, *carry[:4], lam, fn, signal, step_size)
        last["pair"] = carry[0]
        return carry, relative(jnp.linalg.norm(carry[2]), norm)  # of carry[4], the iterate

    rho, history, stopped, stats = iterate(
        step,
        _init(solver, pair, lam, fn, signal, step_size),
        iterations=iterations,
        until=Patience.from_tol(tol),
        progress=progress,
        monitor=monitor,
        desc=desc,
        image=lambda carry: as_complex(carry[4]),
        start_measure=float("inf"),  # the start's residual is the first step's record
        hint="More `power_iterations` estimate the step 1/L more safely.",
    )
    checked = time.perf_counter()  # the history's clock leaves a monitor's time out
    final = as_complex(last["pair"])
    residual = residual_of(fn, signal, final)
    if residual < history.residual.min():
        rho, stats = final, {"best": len(history)}
    seconds = np.append(history.seconds, history.seconds[-1] + time.perf_counter() - checked)
    return rho, History(np.append(history.residual, residual), seconds), stopped, stats


@functools.cache
def _solver(nonnegative: bool) -> jaxopt.ProximalGradient:
    """One jaxopt solver per constraint, so that jit caches hit across runs (its step is
    1: `_value_and_grad` scales the objective by the step t, a traced argument)."""
    return jaxopt.ProximalGradient(
        fun=_value_and_grad,
        prox=_prox_nonnegative if nonnegative else _prox_l1,
        value_and_grad=True,
        has_aux=True,
        stepsize=1.0,
        acceleration=True,
        jit=False,  # the caller jits the whole update
    )


def _value_and_grad(pair, fn, signal, t):
    """((t·½‖Aρ − y‖², Aρ − y), ∇ = t·Aᴴ(Aρ − y)) with the adjoint kernel: the objective
    scaled by the step t, so that jaxopt's unit step is t."""
    r = fn(as_complex(pair)) - signal
    value = t * 0.5 * jnp.sum(jnp.abs(r) ** 2)
    return (value, r), as_pair(t * fn.adjoint(r))


@exact_jit
def _init(solver, pair, lam, fn, signal, step_size):
    """The carry before the first step: t_{-1} = 1 and m = 0, so FISTA's first extrapolated
    point is its start."""
    state = solver.init_state(pair, lam, fn, signal, step_size)
    one = jnp.ones((), jnp.float32)
    return _settled((pair, state, jnp.zeros_like(signal), one, pair))


def _settled(carry):
    """The carry (ρ_{k+1}, jaxopt's state, r(ρ_k), t_k, ρ_k) as every step takes it, so that
    each step runs one program. jaxopt's init stores the gradient as `aux` where its update
    stores our function's aux (the residual), and types some scalars weakly where update
    does not. jaxopt never reads `aux`, so it becomes a scalar: a residual there would also
    be copied to every device each step (it comes out of the operator split over views, or
    whole, by the view count). Everything is strongly typed and replicated."""
    params, state, misfit, t, pair = carry
    state = state._replace(aux=jnp.zeros((), jnp.complex64))
    carry = (params, state, misfit, t, pair)
    return replicated(jax.tree.map(lambda a: a.astype(a.dtype), carry))


@exact_jit
def _update(solver, pair, state, misfit, t, lam, fn, signal, step_size):
    """One FISTA step from ρ_k (``pair``) with ``misfit`` = r(ρ_{k−1}) and ``t`` = t_{k−1}
    (the momentum's; ``step_size`` is the gradient step): (ρ_{k+1}, state, r(ρ_k), t_k,
    ρ_k)."""
    step = solver.update(pair, state, lam, fn, signal, step_size)
    m = (t - 1) / state.t  # y_k = ρ_k + m (ρ_k − ρ_{k−1})
    misfit = (step.state.aux + m * misfit) / (1 + m)  # aux: r(y_k)
    return _settled((step.params, step.state, misfit, state.t, pair))


# `seed`'s stream for the noise draw, apart from every key that `synthesize` (split into
# two) and the power iteration (the seed's own key) use: with the small counters of a split,
# `fold_in(key(seed), 1)` is `split(key(seed))[1]`, the very key of `synthesize`'s noise, so
# that λ followed the data's own noise (found in review)
_NOISE_STREAM = 0x4E4F4953


def _noise_draw(shape, sigma: float, seed: int) -> Complex[Array, "*shape"]:
    """Complex white noise of σ per sample (E|n|² = σ², each part σ/√2), from ``seed``'s
    own stream (`_NOISE_STREAM`), independent of the noise `synthesize` adds."""
    key = jax.random.fold_in(jax.random.key(seed), _NOISE_STREAM)
    re, im = jax.random.normal(key, (2, *shape))
    return (sigma / np.sqrt(2)) * jax.lax.complex(re, im)


def _max_backprojection(fn, signal):
    """max |Aᴴy|, on the operator's own compiled adjoint (see `_common.misfit`)."""
    fn, signal = replicated((fn, signal))
    return _largest_magnitude(fn.adjoint(signal))


@exact_jit
def _largest_magnitude(x):
    return jnp.max(jnp.abs(x))


def _prox_l1(pair, lam, scaling=1.0):
    """Complex soft threshold: shrink |ρ| by λ·t, keep the phase."""
    re, im = pair
    magnitude = jnp.sqrt(re**2 + im**2)
    shrink = jnp.maximum(0.0, 1.0 - lam * scaling / jnp.maximum(magnitude, 1e-30))
    return re * shrink, im * shrink


def _prox_nonnegative(pair, lam, scaling=1.0):
    """Soft threshold restricted to real ρ ≥ 0."""
    re, im = pair
    return jnp.maximum(re - lam * scaling, 0.0), jnp.zeros_like(im)


def _power_norm(fn, iterations: int, seed: int) -> float:
    """‖A‖² ≈ the Rayleigh quotient ‖Av‖²/‖v‖² after power iterations on AᴴA, from a
    seeded start drawn for the live points only (`GRT.live`): a padded problem starts
    where its unpadded one does, so it finds the same step."""
    live = fn.live_points()
    re, im = jax.random.normal(jax.random.key(seed), (2, int(live.sum())))
    start = np.zeros(fn.n_points, np.complex64)
    start[live] = np.asarray(jax.lax.complex(re, im))
    return float(_power(*replicated((fn, jnp.asarray(start))), iterations))


def _power(fn, v, iterations: int):
    """‖Av‖² after ``iterations`` power steps v ← AᴴAv/‖AᴴAv‖ from v/‖v‖, each on the
    operator's own compiled products (see `_common.misfit`), dispatched from here."""
    v = _unit(v)
    for _ in range(iterations):  # Av comes back split over the devices: replicated, as
        v = _unit(fn.adjoint(replicated(fn(v))))  # every other Aᴴ input (one compilation)
    return _energy(fn(v))


@exact_jit
def _unit(v):
    return v / jnp.linalg.norm(v)


@exact_jit
def _energy(x):
    return jnp.sum(jnp.abs(x) ** 2)
