"""The ways an INR fails without a non-finite value, and how a trained run is checked for
them (`rift` retries a collapsed run; docs/rift.md, "Collapse")."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..._geometry import spread
from ..._operator import GRT
from ..._sharding import replicated
from .._common import DIAGNOSTIC_VIEWS, norms
from .._solution import Solution


class CollapseWarning(UserWarning):
    """RIFT training collapsed (see `rift`'s "Collapse") in every attempt it was given."""


# thresholds of `diagnose`: far from any reconstruction seen to work (docs/rift.md, Collapse)
_ZERO_ENERGY = 1e-2  # ‖Aρ‖/‖y‖ below this: the field predicts (almost) nothing
_FITS_NOTHING = 0.995  # residual at least this (the zero field's is 1): complex MSE ≥ 0.99
_GAIN_DRIFT = 1e-2  # |g| fallen below this share of its start: drifting to zero
_CONSTANT = 0.1  # std|ρ| / mean|ρ| below this: no structure
_FLAT = 0.99  # best loss above this share of the first epoch's: no descent


def diagnose(
    losses: np.ndarray,
    rho: np.ndarray,
    energy_ratio: float,
    gain_ratio: float,
    *,
    warm: bool = False,
    residual: float | None = None,
) -> str | None:
    """Why a RIFT run collapsed, or None: the checks `rift` makes after training.

    **Arguments:**

    - `losses`: the training loss per epoch.
    - `rho`: the returned field's rendering on the grid.
    - `energy_ratio`: ‖Aρ‖/‖y‖ on (some of) the training viewpoints.
    - `gain_ratio`: |g| of the returned field over |g| at the start.
    - `warm`: the run started from a given field (a flat loss is then no collapse).
    - `residual`: ‖y − Aρ‖/‖y‖ on the same viewpoints, for a run trained to lower it
      (complex MSE, whose loss is its square; None: not checked). At 0.995 or more the
      field explains the data no better than the zero field (1): how complex MSE
      collapses, with a field that still carries energy. Other losses are not judged by
      it: under the two-grid protocol the robust loss's good fits end above 1 (1.05 on the
      weak target at the paper's scale, m-SSIM 0.96), and the paper's loss scores random
      phases worse than a zero field.

    **Returns:** a sentence naming the failure mode, or None.
    """
    magnitude = np.abs(np.asarray(rho))
    if not gain_ratio >= _GAIN_DRIFT:
        return f"gain drifted to zero: |g| fell to {gain_ratio:.2g} of its start"
    if not energy_ratio >= _ZERO_ENERGY:
        return f"zero field: its signals carry {100 * energy_ratio:.2g} % of the data's norm"
    if residual is not None and not residual < _FITS_NOTHING:
        return f"fits nothing: its residual ‖y − Aρ‖/‖y‖ is {residual:.3f} (the zero field's: 1)"
    mean = magnitude.mean()
    if mean > 0 and magnitude.std() < _CONSTANT * mean:
        return f"near-constant field: std|ρ| is {magnitude.std() / mean:.1%} of mean|ρ|"
    losses = np.asarray(losses)
    if not warm and len(losses) >= 3 and losses.min() > _FLAT * losses[0]:
        return (
            f"loss flat from the start: best {losses.min():.4g} against the first epoch's "
            f"{losses[0]:.4g}"
        )
    return None


# ‖Aρ‖/‖y‖ is read from every viewpoint when there are at most `DIAGNOSTIC_VIEWS`: `fit`'s
# own checks read them all then, and their compiled forward serves here too. Beyond, from
# this many evenly spread ones, a forward of their own that costs a fraction of a full one.
_COLLAPSE_VIEWS = 10


def check_collapse(
    solution: Solution, fn: GRT, signal, *, warm: bool, least_squares: bool
) -> str | None:
    """`diagnose` for a trained run; ‖Aρ‖/‖y‖, and the residual where ``least_squares``
    (the run trained with complex MSE), from every viewpoint up to `DIAGNOSTIC_VIEWS`, else
    from `_COLLAPSE_VIEWS` evenly spread ones."""
    count = fn.n_views if fn.n_views <= DIAGNOSTIC_VIEWS else _COLLAPSE_VIEWS
    index = jnp.asarray(spread(fn.n_views, count))
    fn, rho, signal, index = replicated((fn, solution.rho, signal, index))
    prediction, measured = fn.subset(index)(rho), signal[index]
    predicted, norm, misfit = (
        np.float64(x) for x in norms(prediction, measured, measured - prediction)
    )
    with np.errstate(divide="ignore", invalid="ignore"):  # inf, or NaN for 0/0: see diagnose
        energy, residual = float(predicted / norm), float(misfit / norm)
    gain_ratio = float(abs(solution.field.gain)) / solution.stats["initial_gain"]
    rho = np.asarray(solution.rho)[fn.live_points()]  # padding must not move mean or spread
    return diagnose(
        solution.history.loss,
        rho,
        energy,
        gain_ratio,
        warm=warm,
        residual=residual if least_squares else None,
    )
