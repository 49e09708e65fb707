"""RIFT's optimizer: AdamW with a halving learning rate, clipping, and weight decay on the
INR only."""

from __future__ import annotations

import functools
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import optax

from ..._models import Field
from .recipe import Recipe


def optimizer_for(
    recipe: Recipe, steps_per_epoch: int, params
) -> tuple[optax.GradientTransformation, Any]:
    """AdamW with the recipe's schedule and clipping, and its state for ``params``.

    The learning rate is a value in the state (`optax.inject_hyperparams`), not a constant
    of the optimizer: a collapsed run's retry at half the rate then reuses the compiled
    step, which otherwise compiled again (3-8 s)."""
    every = halving_steps(recipe, steps_per_epoch)
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
    """AdamW on `schedule`, after clipping the gradient to ``clip_norm`` (None: none)."""
    rates = schedule(learning_rate, every)
    adamw = optax.adamw(rates, eps=eps, weight_decay=weight_decay, mask=_decay_mask)
    if clip_norm is None:
        return adamw
    return optax.chain(optax.clip_by_global_norm(clip_norm), adamw)


def halving_steps(recipe: Recipe, steps_per_epoch: int) -> int | None:
    """The recipe's `halve_every` in optimizer steps (None: a constant learning rate)."""
    if recipe.halve_every is None:
        return None
    return max(1, round(recipe.halve_every * steps_per_epoch))


def schedule(learning_rate, every: int | None):
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
