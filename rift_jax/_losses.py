"""Data terms for training an INR through the GRT: predicted signal P against measured S.

Both are means over every entry (frequency × TX × RX × viewpoint) of an elementwise term,
so a loss does not grow with the batch. They take complex arrays of equal shape and return
a real scalar.

- `paper_loss`: the paper's α1‖|S| − |P|‖₁ + α2‖∠S − ∠P‖₁ (Appendix, Eq. "actual
  optimisation problem"), α2 = 1000 α1.
- `robust_loss`: the default, mean|P − S| / mean|S|. Why it replaces the paper's:
  docs/rift.md. In short, with u_z = z/|z|,

      |P − S|² = (|P| − |S|)² + |P||S|·|u_P − u_S|²,

  so it is a magnitude error and a phase error at once, where the phase error is the
  distance between unit phasors (periodic: no jump at ±π, unlike a raw angle difference)
  weighted by the magnitudes (entries at the noise floor, whose phase is random, weigh
  little). Its gradient has unit length per entry, with no 1/|P| blow-up as |P| → 0, and
  dividing by mean|S| makes it O(1) whatever the data's scale.
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
    """The default loss, (mean| |P| − |S| | + α·mean(|S|·(1 − cos(∠P − ∠S)))) / mean|S|.

    1 − cos Δφ = ½|u_P − u_S|² (u = z/|z|) is computed from the phasors, without angles. A
    zero target gives mean|P|; a zero prediction's phase counts as 0.
    """
    _check("robust_loss", pred, target)
    magnitude, reference = jnp.abs(pred), jnp.abs(target)
    # cos Δφ = Re(P·conj S) / (|P||S|); the guard only acts on exact zeros
    cos = jnp.real(pred * jnp.conj(target)) / jnp.maximum(magnitude * reference, 1e-30)
    terms = jnp.abs(magnitude - reference) + alpha_phase * reference * (1 - cos)
    scale = jnp.mean(reference)
    return jnp.mean(terms) / jnp.where(scale > 0, scale, 1.0)


def complex_mse(
    pred: Complex[Array, " *shape"], target: Complex[Array, " *shape"]
) -> Float[Array, ""]:
    """mean|P − S|² / mean|S|² (a zero target gives mean|P|²): the coherent least-squares
    data term, relative to the data's power."""
    _check("complex_mse", pred, target)
    power = jnp.mean(jnp.abs(target) ** 2)
    return jnp.mean(jnp.abs(pred - target) ** 2) / jnp.where(power > 0, power, 1.0)


LOSSES = {"paper": paper_loss, "robust": robust_loss, "mse": complex_mse}
