"""A field started from a least-squares image: RIFT's ``init="fista"`` / ``init="lsmr"``.

The least-squares solver runs once on the same operator (the same points, support and
data); each training attempt then fits its fresh INR to that image point by point
(complex MSE, full batch, Adam), with the gain fixed at the image's peak so that the INR's
bounded output spans it. Training through the GRT starts there, as from any `init` field.
"""

from __future__ import annotations

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, Complex, Float

from ..._models import Field
from ..._operator import GRTOperator
from ..._precision import exact_jit
from ..._sharding import gathered
from ..linear import lsmr
from ..sparse import fista

WARM_STARTS = {"fista": fista, "lsmr": lsmr}
_STEPS = 500  # Adam steps fitting the INR to the image (full batch: each costs one render)


@dataclasses.dataclass(frozen=True)
class Start:
    """A least-squares image to start from (on the operator's points; None when the solver
    returned ρ = 0, which leaves nothing to start from) and ``stats``: the method, its
    residual and its seconds."""

    image: np.ndarray | None
    stats: dict


def least_squares_start(method: str, operator: GRTOperator, signal, *, seed: int) -> Start:
    """``method``'s image (with its defaults) on the operator's points."""
    began = time.perf_counter()
    seeded = {"seed": seed} if method == "fista" else {}  # FISTA's power iteration
    solution = WARM_STARTS[method](operator, signal, progress=False, **seeded)
    image = np.asarray(gathered(solution.rho))
    stats = {
        "method": method,
        "residual": float(solution.history.residual.min(initial=1.0)),
        "seconds": time.perf_counter() - began,
    }
    live = operator.fn.live_points()
    return Start(image if np.abs(image[live]).max(initial=0.0) > 0 else None, stats)


def fitted(
    field: Field, coords: Float[Array, "n 3"], start: Start, live: np.ndarray
) -> tuple[Field, float]:
    """``field`` (a fresh INR) fitted to ``start.image`` on the live points of ``coords``,
    at the model's own learning rate (whatever the recipe's for training through the GRT),
    and the fit's relative error."""
    peak = float(np.abs(start.image[live]).max())
    field = Field(field.model, field.extent, peak)
    model, error = _fit_image(
        field, coords, jnp.asarray(start.image / peak), jnp.asarray(live),
        field.model.learning_rate,
    )  # fmt: skip
    return eqx.tree_at(lambda f: f.model, field, model), float(error)


@exact_jit
def _fit_image(
    field: Field, coords, target: Complex[Array, " n"], live, learning_rate: float
) -> tuple:
    """The INR after `_STEPS` Adam steps on mean|INR(x) − target|² over the live points
    (the gain left out: ``target`` is the image over its peak), and the relative error
    ‖INR − target‖/‖target‖ it ends with."""
    params, static = eqx.partition(field.model, eqx.is_inexact_array)
    optimizer = optax.adam(learning_rate)
    weight = live / jnp.sum(live)

    def error(params):
        model = eqx.combine(params, static)
        out = jax.vmap(model)(coords / field.extent)
        return jnp.sum(weight * jnp.abs(jax.lax.complex(out[:, 0], out[:, 1]) - target) ** 2)

    def step(carry, _):
        params, state = carry
        grads = jax.grad(error)(params)
        updates, state = optimizer.update(grads, state, params)
        return (optax.apply_updates(params, updates), state), None

    (params, _), _ = jax.lax.scan(step, (params, optimizer.init(params)), None, _STEPS)
    relative = jnp.sqrt(error(params) / jnp.sum(weight * jnp.abs(target) ** 2))
    return eqx.combine(params, static), relative
