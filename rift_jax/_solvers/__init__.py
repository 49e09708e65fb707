"""Least-squares solvers on the shared GRT operator, one module per algorithm.

Each takes the `GRTOperator` from `rift_jax.grt_operator` and the measured signal, and
returns a `Solution` (ρ on the operator's grid and a per-iteration `History`); except
`point_scatterers`, which places scatterers on no grid (its `Solution.field`).
"""

from ._solution import Diverged as Diverged
from ._solution import History as History
from ._solution import Outcome as Outcome
from ._solution import Patience as Patience
from ._solution import Solution as Solution
from ._solution import Stop as Stop
from .inr import RECIPES as RECIPES
from .inr import CollapseWarning as CollapseWarning
from .inr import Recipe as Recipe
from .inr import diagnose as diagnose
from .inr import rift as rift
from .kaczmarz import kaczmarz as kaczmarz
from .linear import lsmr as lsmr
from .nonlinear import gauss_newton as gauss_newton
from .points import point_scatterers as point_scatterers
from .sparse import fista as fista
