"""Carrying float64 geometry through float32-only JAX, and keeping float32 products exact.

Phases k·R reach 10⁴-10⁵ rad, so positions and frequencies need ~15 digits; a float32 leaf
would round a 5 m coordinate by 0.3 µm and a 10 m array position by 1.7 µm: 10⁻³ of phase
error. Without turning on x64 for the user's whole program, such values travel as a pair of
float32 arrays (hi, lo), hi + lo exact to ~2⁻⁴⁸, and are joined in float64 only inside the
kernels' ``jax.enable_x64`` blocks.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._validation import is_concrete


class Float64Pair(NamedTuple):
    """A float64 array as two float32 arrays of the same shape: value = hi + lo."""

    hi: Array
    lo: Array

    @property
    def shape(self) -> tuple[int, ...]:
        return self.hi.shape


def split(x) -> Float64Pair:
    """Host (or concrete) values as a `Float64Pair`."""
    x = np.asarray(x, np.float64)
    hi = x.astype(np.float32)
    return Float64Pair(jnp.asarray(hi), jnp.asarray((x - hi).astype(np.float32)))


def as_geometry(x):
    """Geometry as the kernels take it: host values and concrete float64 arrays become a
    `Float64Pair` (full precision); traced values and float32 device arrays pass unchanged (their
    precision is what it is)."""
    if isinstance(x, Float64Pair):
        return x
    if isinstance(x, np.ndarray | list | tuple | float | int):
        return split(x)
    if is_concrete(x) and jnp.asarray(x).dtype == jnp.float64:
        return split(np.asarray(x))
    return jnp.asarray(x)


def to_float64(x) -> Array:
    """float64 value of a `Float64Pair` or array (call inside ``jax.enable_x64``)."""
    if isinstance(x, Float64Pair):
        return x.hi.astype(jnp.float64) + x.lo.astype(jnp.float64)
    return jnp.asarray(x).astype(jnp.float64)


def host_float64(x) -> np.ndarray:
    """float64 NumPy value of a concrete `Float64Pair` or array."""
    if isinstance(x, Float64Pair):
        return np.asarray(x.hi, np.float64) + np.asarray(x.lo, np.float64)
    return np.asarray(x, np.float64)


def leading(x) -> int:
    """Length of the leading axis of an array or pair."""
    return jax.tree.leaves(x)[0].shape[0]


def exact_products(fn):
    """``fn`` traced with JAX's default matmul precision at "highest": every float32 product
    it makes (its own and those of Equinox layers it calls) requests full float32, not the
    backend's default. On NVIDIA GPUs that default is TensorFloat-32, 10 mantissa bits
    (measured on an H100: the GRT off by 2.7e-4, least squares off its float64 answer)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with jax.default_matmul_precision("highest"):
            return fn(*args, **kwargs)

    return wrapper


def exact_jit(fn):
    """``eqx.filter_jit(fn)``, traced *and lowered* under `exact_products`' setting. Lowering
    matters for libraries whose primitives are expanded only then (lineax's `linear_solve`,
    and so LSMR's inner products and norms): a setting active only while tracing misses
    them. ``.__wrapped__`` is ``fn`` itself, unjitted."""
    call = exact_products(eqx.filter_jit(fn))
    call.__wrapped__ = fn
    return call
