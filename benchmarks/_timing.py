"""Timing helpers shared by the benchmarks: compile first, block until ready, take the median
of repeats, and measure the machine's own complex matmul rate in the same run."""

from __future__ import annotations

import statistics
import time

import jax
import jax.numpy as jnp


def median_seconds(fn, *args, repeats: int = 5) -> float:
    """Median wall time of ``fn(*args)`` after one warm-up (compile) call."""
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def complex_matmul_rate(n: int = 1024, repeats: int = 5) -> float:
    """This machine's complex64 matmul rate, in G complex multiply-adds per second."""
    key_a, key_b = jax.random.split(jax.random.key(0))
    a = jax.lax.complex(*jax.random.normal(key_a, (2, n, n)))
    b = jax.lax.complex(*jax.random.normal(key_b, (2, n, n)))
    seconds = median_seconds(jax.jit(jnp.matmul), a, b, repeats=repeats)
    return n**3 / seconds / 1e9
