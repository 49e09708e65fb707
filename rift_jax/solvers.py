"""Least-squares solvers on the shared GRT operator (what `rift_jax.fit` runs)."""

from ._solvers import History as History
from ._solvers import Solution as Solution
from ._solvers import fista as fista
from ._solvers import gauss_newton as gauss_newton
from ._solvers import kaczmarz as kaczmarz
from ._solvers import lsmr as lsmr

__all__ = ["kaczmarz", "lsmr", "gauss_newton", "fista", "Solution", "History"]
