"""How a fit says that it likely failed.

- **The checks after every fit** (`check_fit`): how much of the data the returned ρ leaves
  unexplained, whether a RIFT field follows the data's backprojection, and whether the
  support left out part of the scene; `warn_if_failed` turns them into a `FitWarning`
  that names the likely cause and the option that helps.
- **The input's own warnings**, said before any work: a signal without phase
  (`warn_if_phaseless`), an inverse grid that shares few points with the scene's
  (`warn_unless_nested`).
- **`recorded_failures`**: a fit's likely-failure warnings kept as data, for studies that
  run many fits and for `fit(method="auto")`, which judges its candidates by them.

The thresholds are measured; each comment says where.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import jax.numpy as jnp
import numpy as np

from ._geometry import spread
from ._losses import LOSSES
from ._scenes import GridWarning, Scene, nesting_granularities, shared_fraction
from ._sharding import gathered, replicated
from ._solvers import CollapseWarning
from ._solvers._common import DIAGNOSTIC_VIEWS
from ._support import Support

# as many as `estimate_support` backprojects by default, and as RIFT's collapse check reads
# (all of them, up to this many): their products then share compiled programs
_LEAK_VIEWS = DIAGNOSTIC_VIEWS
# cos(|ρ|, |Aᴴy|) below this: a RIFT field unlike the data (a smooth blob). Trained with the
# robust loss, the pyramid's collapsed blobs scored 0.59-0.60, and the 12 failed RIFT(S) runs
# that only this warning caught on the 750-run grid at 4efe342 scored 0.74-0.79: 0.8.
# Trained with complex MSE (the default), good fields sit lower: 0.68-0.80 on 32 of the
# second grid's first 78 RIFT runs, none a failure, and 0.70-0.75 on the weak target's
# resolved bars, which 0.8 warned of: 0.65 there, a thin margin above the blobs (a limit).
# These were read over every point; `check_fit` now reads the field's own points (ρ ≠ 0),
# which can only raise a score (‖Aᴴy‖ over fewer points): the unpruned blobs and every
# unpruned run score as before, and the weak target's pruned fields at its paper grids
# 0.83-0.91 rather than 0.31-0.34, where 0.65 had warned of them (the truth: 0.88, 0.33).
_COHERENCE = 0.8
_COHERENCE_MSE = 0.65
# ... unless the residual beyond the noise's is below this: the stress grid's 37 runs warned
# of a collapse left 0.63-1.00 (and time_to_quality's inverse-grid RIFT runs 0.92-1.01),
# while fields trained coarse to fine left 0.04-0.29 with a cosine of 0.55-0.78 (their
# sharp image against a blurred backprojection), and were no collapse
_EXPLAINED = 0.5


def check_fit(operator, signal, rho, on: Support | None, points, viewpoints) -> dict[str, float]:
    """How well the returned ρ (on the operator's points, in the solver's units) explains
    the data, from at most `_LEAK_VIEWS` viewpoints spread over the training set, so that a
    1000-view fit does not pay minutes for a diagnostic (on the paper's 0.4 m grid each 100
    views cost ~15 s here):

    - ``data_residual``: ‖y − Aρ‖/‖y‖ (1: no better than the zero image);
    - ``coherence``: cos(|ρ|, |Aᴴy|) over the operator's points where ρ ≠ 0 (where the
      field lives: a pruned field is 0 off its active set, and over the whole support the
      backprojection's sidelobes there, not the field, would set the score; at the weak
      target's paper grids the truth itself scores 0.33 over all 17,576 points, 0.88 over
      its own). A reconstruction on the inverse grid follows the data's backprojection
      (read over every point: ≥ 0.96 for every run and for the truth in the default simple
      scenes with the robust loss; RIFT trained with complex MSE 0.68-0.80 on the stress
      grid; a sharp field on a finer grid 0.55-0.78; over their own points the weak
      target's pruned fields score 0.83-0.91); RIFT(N)'s smooth-blob collapse, unpruned,
      scored 0.59-0.60 (docs/experiments.md). What it cannot see: a weaker structure that
      pruning dropped (the field left is like the data where it lives);
    - ``support_leak`` (with a support ``on``; ``points`` are the whole grid's): max
      outside the support of |Aᴴ(y − A_S ρ)|, over max on it of |A_Sᴴ y|: near the level of
      a scatterer the support left out, low when the fit explains what the data backproject
      outside (`Support.leak`: screened, exact at its maximum).
    """
    rows = spread(operator.fn.n_views, _LEAK_VIEWS)
    # placed as the solvers' own diagnostics place them: the same compiled products
    fn, signal, placed = replicated((operator.fn, jnp.asarray(signal)[rows], jnp.asarray(rho)))
    on_support = fn.subset(replicated(jnp.asarray(rows)))
    back = np.abs(np.asarray(gathered(on_support.adjoint(signal))))
    residual = signal - gathered(on_support(placed))
    norm = float(jnp.linalg.norm(signal))
    magnitude = np.abs(np.asarray(rho))
    lives = magnitude > 0  # where the field lives: a pruned RIFT field is 0 off its set
    scale = float(np.linalg.norm(magnitude) * np.linalg.norm(back[lives]))
    out = {
        "data_residual": float(jnp.linalg.norm(residual)) / norm if norm > 0 else 0.0,
        "coherence": float(magnitude @ back) / scale if scale > 0 else 0.0,
    }
    if on is None:
        return out
    leak = 0.0
    if (peak := back.max()) > 0:
        views = viewpoints[rows]
        leak = on.leak(residual, views, points, operator.fn.radar) / float(peak)
    return out | {"support_leak": leak}


class FitWarning(UserWarning):
    """A fit ran to its end but likely failed: it explains the data no better than the zero
    image, or its RIFT field is unlike the data's backprojection while it leaves much of
    the data unexplained (`fit`'s checks), or it was given a signal without phase."""


FAILED = (FitWarning, CollapseWarning)  # the warnings that a fit likely failed


def recorded_failures(call: Callable, *args, **kwargs) -> tuple[Any, list]:
    """Run ``call(*args, **kwargs)`` (e.g. `fit`) and keep the warnings that it likely
    failed as data: returns (its result, those warnings as `warnings.WarningMessage`
    records), a `FitWarning` or RIFT's `CollapseWarning` recorded and not said. Other
    warnings go on from where they were raised, also when ``call`` raises.

    For a study that runs many fits and reports which were warned (the experiments do;
    `fit(method="auto")` so judges its candidates):

        result, failed = rj.recorded_failures(rj.fit, scene, viewpoints, method="fista")
        warned = [str(w.message) for w in failed]
    """
    failed = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            for category in FAILED:
                warnings.simplefilter("always", category)
            result = call(*args, **kwargs)
    finally:  # also when ``call`` raises: what it said is not lost
        for warning in caught:
            if issubclass(warning.category, FAILED):
                failed.append(warning)
            else:
                warnings.warn_explicit(
                    warning.message, warning.category, warning.filename, warning.lineno
                )
    return result, failed


def warn_if_phaseless(signal) -> None:
    """A radar signal is complex: its phase, k·R, is what places a scatterer. A real-valued
    one (magnitudes, or the real part of I/Q data) reconstructs nothing like the scene,
    without any error to say so. (An all-zero signal has a path of its own: ρ = 0.) A
    RadarData's JAX array is checked where it lives, not copied to the host."""
    xp = np if isinstance(signal, np.ndarray) else jnp
    if xp.any(signal) and (not xp.iscomplexobj(signal) or not xp.any(xp.imag(signal))):
        warnings.warn(
            "fit: the signal (`scene_or_signal`) is real-valued: it carries no phase, which "
            "is what places each scatterer (exp(j·k·R)). Pass the complex (I/Q) samples; "
            "magnitudes alone reconstruct nothing like the scene.",
            FitWarning,
            stacklevel=4,
        )


def warn_if_failed(method: str, stats: dict, on_support: bool, noise_floor: float = 0.0) -> None:
    """A `FitWarning` naming the likely cause and the option that helps (see `check_fit`).
    ``noise_floor``: the residual a perfect fit leaves, where the SNR is known; the
    collapse warning reads the residual beyond it."""
    residual, coherence = stats["data_residual"], stats["coherence"]
    unexplained = np.sqrt(max(residual**2 - noise_floor**2, 0.0))
    rift = method.startswith("rift")
    loss = stats.get("recipe", {}).get("loss")
    floor = _COHERENCE_MSE if loss == "mse" or loss is LOSSES["mse"] else _COHERENCE
    if residual >= 1:
        if stats.get("noise_lambda") and coherence == 0:  # FISTA's known noise kept no point
            cause = (
                f"FISTA's λ, at least the known noise's own backprojection (noise_lambda "
                f"{stats['noise_lambda']:.3g}), kept no point: at these viewpoints the data "
                "hold nothing above their noise; add viewpoints, or try `method='rift-n'`"
            )
        elif on_support and stats["support_leak"] >= 0.5:
            cause = (
                f"the support dropped part of the scene (support_leak "
                f"{stats['support_leak']:.2f}): pass `support=None`, or a mask from "
                "`rift_jax.estimate_support` with a lower `threshold`"
            )
        elif rift:
            cause = (
                "the INR did not fit the data: train longer (`epochs`, `patience=None`), "
                "or use `method='fista'`"
            )
        else:
            cause = (
                "the grid cannot explain the data (scatterers between its points): try a "
                "finer `granularity`"
            )
        warnings.warn(
            f"fit ({method}): the reconstruction explains the data no better than the zero "
            f"image (relative residual {residual:.2f} ≥ 1); likely {cause}.",
            FitWarning,
            stacklevel=4,  # the caller of fit
        )
    elif rift and coherence < floor and unexplained >= _EXPLAINED:
        warnings.warn(
            f"fit ({method}): the field is unlike the data's backprojection (cos(|ρ|, |Aᴴy|) "
            f"= {coherence:.2f} < {floor}): the smooth-blob collapse. Try "
            "`method='fista'`, another `seed`, or a longer run (docs/rift.md, Collapse).",
            FitWarning,
            stacklevel=4,
        )


def warn_unless_nested(data: Scene, granularity: float) -> None:
    """Warn when the inverse grid is not nested in the scene's (docs/conventions.md,
    "Grids"): data synthesised on one grid is explained only on a grid whose points it
    shares, and every method then scores near zero, silently (measured: a 20³ scene over
    ±2 m and its default 2× grid share no point; Kaczmarz, RIFT(N) and RIFT(S) scored m-SSIM
    0.02-0.05)."""
    if granularity > data.extent:
        return  # grid_size says why, naming the argument
    shared = shared_fraction((data.extent, granularity), (data.extent, data.granularity))
    if shared == 1.0:
        return
    n = data.reflectivity.shape[0]
    nested = nesting_granularities(data.extent, data.granularity)
    offer = (
        f"granularities that nest: {', '.join(f'{g:.4g}' for g in nested)} m"
        if nested
        else "no coarser grid over this extent nests; an odd number of points per axis "
        "(e.g. Scene.from_array of a 21³ array) nests at 2×"
    )
    warnings.warn(
        f"fit: the inverse grid ({granularity:.4g} m over ±{data.extent:g} m) shares "
        f"{100 * shared:.0f}% of its points with the scene's grid ({data.granularity:.4g} m, "
        f"{n} points per axis): data made on one grid is explained only on a grid whose "
        f"points it shares, so expect every method to score poorly. Pass `granularity=` "
        f"({offer}).",
        GridWarning,
        stacklevel=4,  # the caller of fit
    )
