"""Solvers on the shared GRT operator (what `rift_jax.fit` runs): least squares (Kaczmarz,
LSMR, Gauss-Newton, FISTA) and RIFT's INR training (`rift`, configured by a `Recipe`); and,
on no grid, point scatterers at continuous positions (`point_scatterers`)."""

from ._solvers import RECIPES as RECIPES
from ._solvers import CollapseWarning as CollapseWarning
from ._solvers import Diverged as Diverged
from ._solvers import History as History
from ._solvers import Outcome as Outcome
from ._solvers import Patience as Patience
from ._solvers import Recipe as Recipe
from ._solvers import Solution as Solution
from ._solvers import Stop as Stop
from ._solvers import diagnose as diagnose
from ._solvers import fista as fista
from ._solvers import gauss_newton as gauss_newton
from ._solvers import kaczmarz as kaczmarz
from ._solvers import lsmr as lsmr
from ._solvers import point_scatterers as point_scatterers
from ._solvers import rift as rift

__all__ = [
    "kaczmarz",
    "lsmr",
    "gauss_newton",
    "fista",
    "rift",
    "point_scatterers",
    "Recipe",
    "RECIPES",
    "Solution",
    "History",
    "Stop",
    "Outcome",
    "Patience",
    "Diverged",
    "CollapseWarning",
    "diagnose",
]
