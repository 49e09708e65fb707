"""The ways an INR fails without a non-finite value, and how a trained run is checked for
them (`rift` retries a collapsed run; docs/rift.md, "Collapse")."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..._geometry import spread
from ..._operator import GRT
from ..._precision import exact_jit
from ..._sharding import replicated
from .._common import DIAGNOSTIC_VIEWS
from .._solution import Solution


class CollapseWarning(UserWarning):
    """RIFT training collapsed (see `rift`'s "Collapse") in every attempt it was given."""


# thresholds of `diagnose`: far from any reconstruction seen to work (docs/rift.md, Collapse)
_ZERO_ENERGY = 1e-2  # ‖Aρ‖/‖y‖ below this: the field predicts (almost) nothing
_FITS_NOTHING = 0.995  # best-gain residual at least this: < 1 % of the data's power explained
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
    noise_share: float = 0.0,
) -> str | None:
    """Why a RIFT run collapsed, or None: the checks `rift` makes after training.

    **Arguments:**

    - `losses`: the training loss per epoch.
    - `rho`: the returned field's rendering on the grid.
    - `energy_ratio`: ‖Aρ‖/‖y‖ on (some of) the training viewpoints.
    - `gain_ratio`: |g| of the returned field over |g| at the start.
    - `warm`: the run started from a given field (a flat loss is then no collapse).
    - `residual`: the least ‖y − g·Aρ‖/‖y‖ over a complex gain g, √(1 − c²) with c the
      coherence |⟨y, Aρ⟩|/(‖y‖‖Aρ‖), on the same viewpoints, for a run trained to lower
      the residual (complex MSE; None: not checked). At 0.995 or more (c² ≤ 1 %) even the
      best rescaling of the field explains under 1 % of the data's power: how complex MSE
      collapses, with a field that still carries energy (on the stress grid 0.998-1.000).
      The margin is thin where nothing explains much: good fits have ended at 0.977-0.991
      (least squares on the complex scenes; the pyramid at −10 dB, 0.988), and at an SNR
      of −20 dB or less the noise alone leaves ≥ 0.995, so every run there counts as a
      collapse. Other losses are not judged by it: under the two-grid protocol the robust loss's
      good fits leave the gain where the residual ends above 1 (1.05 on the weak target at
      the paper's scale, m-SSIM 0.96).
    - `noise_share`: the noise's share of the data's power, where known (complex MSE):
      "fits nothing" then means under 1 % of the *signal's* power, the residual's bar
      rising to √(1 − (1 − 0.995²)(1 − share)) (0.99955 at −10 dB, where a good fit of
      m-SSIM 0.39 left 0.9967 and the noise alone 0.953), and "loss flat from the start"
      compares the losses above the share.

    **Returns:** a sentence naming the failure mode, or None.
    """
    magnitude = np.abs(np.asarray(rho))
    if not gain_ratio >= _GAIN_DRIFT:
        return f"gain drifted to zero: |g| fell to {gain_ratio:.2g} of its start"
    if not energy_ratio >= _ZERO_ENERGY:
        return f"zero field: its signals carry {100 * energy_ratio:.2g} % of the data's norm"
    bar = _FITS_NOTHING
    if noise_share:
        bar = float(np.sqrt(1 - (1 - _FITS_NOTHING**2) * (1 - noise_share)))
    if residual is not None and not residual < bar:
        return (
            f"fits nothing: even at its best gain the residual ‖y − g·Aρ‖/‖y‖ is "
            f"{residual:.{3 if noise_share == 0 else 5}f} (the zero field's: 1"
            + (f"; the bar on data {noise_share:.0%} noise: {bar:.5f})" if noise_share else ")")
        )
    mean = magnitude.mean()
    if mean > 0 and magnitude.std() < _CONSTANT * mean:
        return f"near-constant field: std|ρ| is {magnitude.std() / mean:.1%} of mean|ρ|"
    losses = np.asarray(losses)
    if (
        not warm
        and len(losses) >= 3
        and losses.min() - noise_share > _FLAT * (losses[0] - noise_share)
    ):
        return (
            f"loss flat from the start: best {losses.min():.4g} against the first epoch's "
            f"{losses[0]:.4g}"
        )
    return None


# ‖Aρ‖/‖y‖ and the best-gain residual are read from every training viewpoint when there are
# at most `DIAGNOSTIC_VIEWS`: `fit`'s own checks read them all then, and (without a holdout)
# their compiled forward serves here too. Beyond, from this many evenly spread ones, a
# forward of their own that costs a fraction of a full one.
_COLLAPSE_VIEWS = 10


@exact_jit
def _measures(prediction, signal):
    """‖Aρ‖, ‖y‖ and |⟨y, Aρ⟩|: one program for the check's three numbers. The inner
    product as a sum of products, not `vdot`: a program with no matrix product, as every
    diagnostic around the operator is (tests/test_precision.py)."""
    return (
        jnp.linalg.norm(prediction),
        jnp.linalg.norm(signal),
        jnp.abs(jnp.sum(jnp.conj(signal) * prediction)),
    )


def check_collapse(
    solution: Solution, fn: GRT, signal, *, warm: bool, least_squares: bool,
    noise_share: float = 0.0,
) -> str | None:  # fmt: skip
    """`diagnose` for a trained run, read on the viewpoints it trained on (not those it
    held out): every one up to `DIAGNOSTIC_VIEWS`, else `_COLLAPSE_VIEWS` evenly spread
    ones. The best-gain residual only where ``least_squares`` (the run trained with complex
    MSE) and the returned ``rho`` is what it trained: a coarse-to-fine run's is its
    rendering on the inverse grid, which under the two-grid protocol explains little of
    the data (`fit` checks `trained` on the fine points)."""
    views = np.setdiff1d(np.arange(fn.n_views), solution.stats.get("holdout_views", []))
    if len(views) > DIAGNOSTIC_VIEWS:
        views = views[spread(len(views), _COLLAPSE_VIEWS)]
    index = jnp.asarray(views)
    fn, rho, signal, index = replicated((fn, solution.rho, signal, index))
    predicted, norm, overlap = (
        np.float64(x) for x in _measures(fn.subset(index)(rho), signal[index])
    )
    with np.errstate(divide="ignore", invalid="ignore"):  # inf, or NaN for 0/0: see diagnose
        energy = float(predicted / norm)
        coherence = min(float(overlap / (predicted * norm)), 1.0) if predicted > 0 else 0.0
    residual = None
    if least_squares and "fine_from_epoch" not in solution.stats:
        residual = float(np.sqrt(1.0 - coherence**2))
    if not least_squares:  # the share is complex MSE's floor; another loss's is not known
        noise_share = 0.0
    gain_ratio = float(abs(solution.field.gain)) / solution.stats["initial_gain"]
    rho = np.asarray(solution.rho)[fn.live_points()]  # padding must not move mean or spread
    return diagnose(
        solution.history.loss, rho, energy, gain_ratio, warm=warm, residual=residual,
        noise_share=noise_share,
    )  # fmt: skip
