"""Argument checks shared by the public functions: each error names the argument and what
was expected. Checks run only on concrete (host-visible) values, never inside a trace."""

from __future__ import annotations

import math

import jax
import numpy as np


def is_concrete(x) -> bool:
    """True unless ``x`` is (or holds) a JAX tracer: only concrete values can be checked."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def check_positive(name: str, value: float) -> None:
    if not isinstance(value, int | float | np.integer | np.floating) or not (
        math.isfinite(value) and value > 0
    ):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}.")


def check_positive_int(name: str, value) -> None:
    """Raise unless ``value`` is a Python or NumPy integer ≥ 1."""
    if not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}.")


def as_finite_array(x, name: str, dtype=None) -> np.ndarray:
    """``np.asarray(x, dtype)``, raising if it holds NaN or inf."""
    try:
        arr = np.array(x, dtype=dtype)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be a numeric array, got {type(x).__name__}.") from err
    if not np.all(np.isfinite(arr)):
        raise ValueError(
            f"{name} must be finite; it holds {np.sum(~np.isfinite(arr))} NaN/inf values."
        )
    return arr


def check_finite(x, name: str) -> None:
    """Raise if a concrete array holds NaN or inf; tracers pass through unchecked."""
    if is_concrete(x) and not bool(np.all(np.isfinite(np.asarray(x)))):
        raise ValueError(f"{name} must be finite; it holds NaN/inf values.")
