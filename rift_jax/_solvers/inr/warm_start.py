"""A field started from a least-squares image: RIFT's ``init="fista"`` / ``init="lsmr"``.

The least-squares solver runs on the same operator (the same points, support and data);
the INR is then fitted to its image point by point (complex MSE, full batch, Adam), with
the gain fixed at the image's peak so that the INR's bounded output spans it. Training
through the GRT then starts there, as from any `init` field.
"""

from __future__ import annotations

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


def warm_start(
    method: str,
    operator: GRTOperator,
    signal,
    field: Field,
    coords: Float[Array, "n 3"],
    *,
    seed: int,
) -> tuple[Field, dict]:
    """``field`` (a fresh INR) fitted to ``method``'s least-squares image on the operator's
    points ``coords``, at the model's own learning rate (whatever the recipe's for training
    through the GRT); and stats: the solver's residual and the fit's relative error."""
    seeded = {"seed": seed} if method == "fista" else {}  # FISTA's power iteration
    solution = WARM_STARTS[method](operator, signal, progress=False, **seeded)
    image = np.asarray(gathered(solution.rho))
    live = operator.fn.live_points()
    peak = float(np.abs(image[live]).max(initial=0.0))
    stats = {"method": method, "residual": float(solution.history.residual.min(initial=1.0))}
    if peak == 0:  # nothing to start from: the fresh field, as without a warm start
        return field, stats | {"image_error": 1.0}
    field = Field(field.model, field.extent, peak)
    model, error = _fit_image(
        field, coords, jnp.asarray(image / peak), jnp.asarray(live), field.model.learning_rate
    )
    return eqx.tree_at(lambda f: f.model, field, model), stats | {"image_error": float(error)}


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
