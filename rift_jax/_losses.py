"""Data terms for training an INR through the GRT: predicted signal P against measured S.

Each is the mean over every entry (frequency × TX × RX × viewpoint) of an elementwise term,
so a loss does not grow with the batch; each takes complex arrays of equal shape and returns
a real scalar. `paper_loss` is the paper's; `complex_mse`, the coherent least-squares
term, is the default; `robust_loss` was the default before it. Why is in docs/rift.md
(the loss study, and complex MSE against the robust loss on the stress grid).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Complex, Float


def _check(where: str, pred, target):
    if pred.shape != target.shape:
        raise ValueError(
            f"{where}: `pred` and `target` must have the same shape, got {pred.shape} and "
            f"{target.shape}."
        )


def paper_loss(
    pred: Complex[Array, " *shape"],
    target: Complex[Array, " *shape"],
    *,
    alpha_magnitude: float = 1.0,
    alpha_phase: float = 1000.0,
) -> Float[Array, ""]:
    """The paper's loss, α1·mean| |S| − |P| | + α2·mean| ∠S − ∠P |.

    The angles are `jnp.angle` values in (−π, π] and their difference is not wrapped, as the
    paper writes it: two nearly equal phases either side of ±π count as ~2π apart.
    """
    _check("paper_loss", pred, target)
    magnitude = jnp.mean(jnp.abs(jnp.abs(target) - jnp.abs(pred)))
    phase = jnp.mean(jnp.abs(jnp.angle(target) - jnp.angle(pred)))
    return alpha_magnitude * magnitude + alpha_phase * phase


def robust_loss(
    pred: Complex[Array, " *shape"],
    target: Complex[Array, " *shape"],
    *,
    alpha_phase: float = 1.0,
) -> Float[Array, ""]:
    """(mean| |P| − |S| | + α·mean(|S|·(1 − cos(∠P − ∠S)))) / mean|S|: the default before
    `complex_mse`, which fits the data coherently where this matches |P| to |S| entry by
    entry, the noise's magnitude included.

    - The phase term is smooth and periodic: 1 − cos Δφ = ½|u_P − u_S|², the squared
      distance between unit phasors u = z/|z|, computed without angles (no jump at ±π).
    - It is weighted by |S|: entries at the noise floor, whose phase is random, weigh little.
    - Dividing by mean|S| makes the loss O(1) whatever the data's scale.
    - Its gradient in P grows like |S|/|P| as |P| → 0 (a phase is undefined at 0): clip the
      gradient (the default recipe does). At P = 0 exactly, the loss and gradient stay
      finite. A zero target gives mean|P|.
    """
    _check("robust_loss", pred, target)
    # |P| with a floor far below float32 resolution: finite gradient at P = 0
    magnitude = jnp.sqrt(jnp.real(pred) ** 2 + jnp.imag(pred) ** 2 + 1e-30)
    reference = jnp.abs(target)
    # cos Δφ = Re(P·conj S) / (|P||S|); the guard only acts on exact zeros
    cos = jnp.real(pred * jnp.conj(target)) / jnp.maximum(magnitude * reference, 1e-30)
    terms = jnp.abs(magnitude - reference) + alpha_phase * reference * (1 - cos)
    scale = jnp.mean(reference)
    return jnp.mean(terms) / jnp.where(scale > 0, scale, 1.0)


def complex_mse(
    pred: Complex[Array, " *shape"], target: Complex[Array, " *shape"]
) -> Float[Array, ""]:
    """mean|P − S|² / mean|S|² (a zero target gives mean|P|²): the coherent least-squares
    data term, relative to the data's power; the default. A zero prediction scores 1; a
    field that no complex gain brings under 0.995² has fitted nothing
    (`rift_jax.solvers.diagnose`'s "fits nothing")."""
    _check("complex_mse", pred, target)
    power = jnp.mean(jnp.abs(target) ** 2)
    return jnp.mean(jnp.abs(pred - target) ** 2) / jnp.where(power > 0, power, 1.0)


LOSSES = {"paper": paper_loss, "robust": robust_loss, "mse": complex_mse}
