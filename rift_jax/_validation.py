"""Argument checks shared by the public functions: each error names the argument and what
was expected. Checks run only on concrete (host-visible) values, never inside a trace."""

from __future__ import annotations

import math

import jax
import numpy as np


def is_concrete(x) -> bool:
    """True unless ``x`` is (or holds) a JAX tracer: only concrete values can be checked."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def _is_number(value) -> bool:
    """A real Python or NumPy number, not a bool (True is an int, but never a size or a
    distance someone meant)."""
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )


def is_finite_nonnegative(value) -> bool:
    """A real number (not a bool), finite and ≥ 0: e.g. a noise level, which may be 0."""
    return _is_number(value) and math.isfinite(value) and value >= 0


def check_positive(name: str, value: float) -> None:
    if not _is_number(value) or not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}.")


def check_positive_int(name: str, value) -> None:
    """Raise unless ``value`` is a Python or NumPy integer ≥ 1."""
    if not _is_number(value) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}.")


def check_instance(name: str, value, cls: type, expected: str) -> None:
    """Raise unless ``value`` is a ``cls``, saying what was ``expected`` (e.g. "a
    rift_jax.Radar") and what came instead."""
    if not isinstance(value, cls):
        raise ValueError(f"{name} must be {expected}, got {type(value).__name__}.")


def check_nonnegative_int(name: str, value) -> None:
    """Raise unless ``value`` is a Python or NumPy integer ≥ 0 (a count that may be zero, or
    a seed: what NumPy's generators accept; JAX's keys take any integer, but the solvers
    seed both)."""
    if not _is_number(value) or not isinstance(value, int | np.integer) or value < 0:
        raise ValueError(f"{name} must be an integer ≥ 0, got {value!r}.")


def check_numeric(arr: np.ndarray, name: str) -> None:
    """Raise unless ``arr`` holds numbers (or booleans): strings and objects would otherwise
    fail deep inside NumPy or JAX with a message naming neither the function nor the
    argument."""
    if not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        raise ValueError(f"{name} must be a numeric array, got dtype {arr.dtype}.")


def as_finite_array(x, name: str, dtype=None) -> np.ndarray:
    """``np.asarray(x, dtype)``, raising if it holds NaN or inf."""
    try:
        arr = np.array(x)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be a numeric array, got {type(x).__name__}.") from err
    check_numeric(arr, name)
    if dtype is not None:
        if np.iscomplexobj(arr) and not np.issubdtype(dtype, np.complexfloating):
            # NumPy would drop the imaginary part with only a warning
            raise ValueError(f"{name} must be real, got complex values.")
        arr = arr.astype(dtype)
    if not np.all(np.isfinite(arr)):
        raise ValueError(
            f"{name} must be finite; it holds {np.sum(~np.isfinite(arr))} NaN/inf values."
        )
    return arr


def check_finite(x, name: str) -> None:
    """Raise if a concrete array holds NaN or inf (or is not numeric); tracers, and arrays
    spread over several processes (which no one process can read), pass through unchecked."""
    if not is_concrete(x) or (isinstance(x, jax.Array) and not x.is_fully_addressable):
        return
    arr = np.asarray(x)
    check_numeric(arr, name)
    if not bool(np.all(np.isfinite(arr))):
        raise ValueError(f"{name} must be finite; it holds NaN/inf values.")
