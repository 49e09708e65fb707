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
) -> str | None:
    """Why a RIFT run collapsed, or None: the checks `rift` makes after training.

    **Arguments:**

    - `losses`: the training loss per epoch.
    - `rho`: the returned field's rendering on the grid.
    - `energy_ratio`: ‖Aρ‖/‖y‖ on (some of) the training viewpoints.
    - `gain_ratio`: |g| of the returned field over |g| at the start.
    - `warm`: the run started from a given field (a flat loss is then no collapse).

    **Returns:** a sentence naming the failure mode, or None.
    """
    magnitude = np.abs(np.asarray(rho))
    if not gain_ratio >= _GAIN_DRIFT:
        return f"gain drifted to zero: |g| fell to {gain_ratio:.2g} of its start"
    if not energy_ratio >= _ZERO_ENERGY:
        return f"zero field: its signals carry {100 * energy_ratio:.2g} % of the data's norm"
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


def check_collapse(solution: Solution, fn: GRT, signal, *, warm: bool) -> str | None:
    """`diagnose` for a trained run; ‖Aρ‖/‖y‖ from every viewpoint up to
    `DIAGNOSTIC_VIEWS`, else from `_COLLAPSE_VIEWS` evenly spread ones."""
    count = fn.n_views if fn.n_views <= DIAGNOSTIC_VIEWS else _COLLAPSE_VIEWS
    index = jnp.asarray(spread(fn.n_views, count))
    fn, rho, signal, index = replicated((fn, solution.rho, signal, index))
    predicted, measured = (float(x) for x in norms(fn.subset(index)(rho), signal[index]))
    with np.errstate(divide="ignore", invalid="ignore"):  # inf, or NaN for 0/0: see diagnose
        energy = float(np.float64(predicted) / measured)
    gain_ratio = float(abs(solution.field.gain)) / solution.stats["initial_gain"]
    rho = np.asarray(solution.rho)[fn.live_points()]  # padding must not move mean or spread
    return diagnose(solution.history.loss, rho, energy, gain_ratio, warm=warm)
