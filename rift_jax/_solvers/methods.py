"""The methods `rift_jax.fit` runs: each one's solver and the options it declares.

A method's options are the solver's keyword arguments that a user may set through `fit`
(fit passes the operator, signal, ``progress`` and ``monitor`` itself, and ``seed`` to a
seeded method). tests/test_fit.py checks each declaration against its solver's signature.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

from ._solution import Solution
from .inr import Recipe, rift
from .kaczmarz import kaczmarz
from .linear import lsmr
from .nonlinear import gauss_newton
from .points import point_scatterers
from .sparse import fista


@dataclasses.dataclass(frozen=True)
class Method:
    """A reconstruction method as `fit` runs it.

    - `solve`: ``solve(operator, signal, *, progress, monitor, **options) -> Solution``.
    - `options`: the options a user may pass through `fit`.
    - `seeded`: it takes a ``seed`` (fit passes its own).
    - `inr`: it trains a `Field` (RIFT): fit passes its grid's ``extent``, turns
      ``train_granularity`` into ``fine_points``, and scales an ``init`` field.
    - `scatterers`: it finds point scatterers at continuous positions, on no grid: fit
      calls ``solve(signal, viewpoints, radar, extent, **options)`` (no operator, no
      support) and renders the points on the inverse grid for the image metrics.
    """

    solve: Callable[..., Solution]
    options: frozenset[str]
    seeded: bool = False
    inr: bool = False
    scatterers: bool = False

    def check(self, name: str, options: dict) -> None:
        """A ValueError naming any option this method does not take."""
        if unknown := set(options) - self.options:
            raise ValueError(
                f"fit: method {name!r} takes no option(s) {sorted(unknown)}; it takes "
                f"{sorted(self.options)}."
            )


# `train_granularity` is fit's own: it chooses the points a method solves for (for RIFT,
# its last epochs'), and every grid method takes it
_LEAST_SQUARES = frozenset({"iterations", "tol", "x0", "train_granularity"})
_RIFT = frozenset(
    {"model", "recipe", "width", "depth", "init", "fine_epochs", "train_granularity", "noise"}
    | {field.name for field in dataclasses.fields(Recipe)}  # each overrides the recipe's
)

METHODS = {
    "kaczmarz": Method(kaczmarz, _LEAST_SQUARES | {"relaxation"}, seeded=True),
    "lsmr": Method(lsmr, _LEAST_SQUARES | {"check_every"}),
    "gauss-newton": Method(gauss_newton, _LEAST_SQUARES | {"inner", "damped"}),
    "fista": Method(
        fista,
        _LEAST_SQUARES | {"sparsity", "nonnegative", "power_iterations", "noise"},
        seeded=True,
    ),
    "rift-n": Method(functools.partial(rift, model="rift-n"), _RIFT, seeded=True, inr=True),
    "rift-s": Method(functools.partial(rift, model="rift-s"), _RIFT, seeded=True, inr=True),
    "points": Method(
        point_scatterers,
        frozenset({"max_points", "noise", "tol", "floor", "refine_steps"}),
        scatterers=True,
    ),
}
