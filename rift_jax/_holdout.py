"""Held-out viewpoints: how well a fit predicts views it never saw.

A user has no test views and no truth, so rift_jax makes its own judge from the training
views: a fifth of them (evenly spread in their order, so they cover the angles the whole
set covers) are held out, a fit on the rest predicts their signals, and the prediction is
scored at its best complex gain (a reconstruction's scale is not the data's). Two choices
use it: ``fit(method="auto")``, which picks a method (`rift_jax._selection`), and FISTA's
``sparsity="auto"``, which picks its λ (`rift_jax._solvers.sparse`).

FISTA uses `split` and `score` and takes the lowest held-out residual (from 10 views 2
are held out, too few for a standard error); ``"auto"`` ranks its candidates by `rank`.
A few held-out views are a noisy judge: at −10 dB from 100 views two methods' residuals
differed by less than 0.00025 (at 0.99-0.998) in four cells, and in all four the lower one
scored worse on the truth (docs/experiments.md). So `rank` orders a choice's candidates
by the one-standard-error rule of cross-validation (Hastie, Tibshirani and Friedman, *The
Elements of Statistical Learning*, 2nd ed., §7.10): the first keeps its place unless
another predicts the held-out views better by more than `MARGIN` standard errors of the
paired per-view difference. The caller lists the candidate to keep when the evidence does
not tell them apart first (the simpler model).
"""

from __future__ import annotations

import numpy as np

from ._geometry import spread

HOLDOUT_SHARE = 0.2  # of the training viewpoints, held out to score the candidates ...
MIN_HOLDOUT = 2  # ... but at least this many
MIN_TRAINING = 3  # and this many left to fit on: below, there is no split (`split`)
MARGIN = 1.0  # standard errors by which a candidate must beat an earlier one to rank first


def split(n: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(kept, held): the sorted indices of ``n`` training viewpoints to fit on and to hold
    out (`HOLDOUT_SHARE`, at least `MIN_HOLDOUT`, evenly spread); None where fewer than
    `MIN_TRAINING` would be left to fit on."""
    k = max(MIN_HOLDOUT, round(HOLDOUT_SHARE * n))
    if n - k < MIN_TRAINING:
        return None
    held = spread(n, k)
    return np.setdiff1d(np.arange(n), held), held


def holdout_residual(predicted, signal) -> float:
    """min over a complex gain g of ‖y − g·p‖/‖y‖, √(1 − c²) with c = |⟨y, p⟩|/(‖y‖‖p‖):
    how much of the held-out signals ``signal`` (y) the prediction ``predicted`` (p)
    leaves unexplained, whatever its scale (`FitResult.predict` normalises). Noise in y
    adds the same to every candidate's on average, so it ranks them by the noise-free
    signals' residual; 1 where p is zero."""
    return _residual(holdout_errors(predicted, signal))


def _residual(errors) -> float:
    """The held-out residual from its per-view shares (`holdout_errors`)."""
    return float(np.sqrt(np.sum(errors)))


def holdout_errors(predicted, signal) -> np.ndarray:
    """Each held-out viewpoint's share of ``holdout_residual``²: ‖y_v − g·p_v‖²/‖y‖² for
    the views v along the first axis, at the one gain g best for all of them together.
    They sum to the residual², so two candidates' per-view differences say how much of
    their residuals' difference is more than the chance of which views were held out.
    A zero or non-finite prediction explains nothing: each view keeps its whole share of
    ‖y‖² (the shares of a zero ``signal``: 1/k each, as for a prediction of nothing)."""
    p, y = (np.asarray(x, np.complex128) for x in (predicted, signal))
    p, y = p.reshape(len(p), -1), y.reshape(len(y), -1)
    power, p_power = np.sum(np.abs(y) ** 2), np.sum(np.abs(p) ** 2)
    if not power > 0:
        return np.full(len(y), 1 / len(y))
    gain = np.vdot(p, y) / p_power if np.isfinite(p_power) and p_power > 0 else 0.0
    if gain == 0 or not np.isfinite(gain):  # also NaN in p, which a zero gain would keep
        return np.sum(np.abs(y) ** 2, axis=1) / power
    return np.sum(np.abs(y - gain * p) ** 2, axis=1) / power


def score(predicted, signal, failure=None) -> dict:
    """A candidate's score as `rank` reads it: its held-out residual, each held-out view's
    share of it (`holdout_errors`) and its ``failure`` (None, or why it failed)."""
    errors = holdout_errors(predicted, signal)
    return {
        "holdout_residual": _residual(errors),
        "holdout_errors": errors.tolist(),  # per held-out view, for `clearly_better`
        "failure": failure,
    }


def rank(scores: dict) -> list:
    """The candidates (the keys of ``scores``, in their order) from best to worst: first
    the one that predicted the held-out views best by a clear margin (each, in order, takes
    the lead only if `clearly_better` than the one holding it), then the others by
    held-out residual, then every one that failed (a ``failure`` that is not None)."""
    ok = [m for m in scores if scores[m]["failure"] is None]
    failed = [m for m in scores if scores[m]["failure"] is not None]

    def residual(key) -> float:
        return scores[key]["holdout_residual"]

    if not ok:
        return sorted(failed, key=residual)
    lead = ok[0]
    for key in ok[1:]:
        if clearly_better(scores[key], scores[lead]):
            lead = key
    rest = sorted((m for m in ok if m != lead), key=residual)
    return [lead, *rest, *sorted(failed, key=residual)]


def clearly_better(score: dict, than: dict) -> bool:
    """Whether ``score``'s held-out residual² is below ``than``'s by more than `MARGIN`
    standard errors (`paired_t`). The views' shares share one gain and neighbouring views
    look alike, so the error is if anything understated, and the rule errs towards a
    change. From 2 held-out views it asks for a lower share on both."""
    return paired_t(score, than) > MARGIN


def paired_t(score: dict, than: dict) -> float:
    """How many standard errors ``score``'s held-out residual² lies below ``than``'s: the
    sum of their per-view differences (`holdout_errors`; paired: the same views, the same
    noise) over its standard error, √k times the differences' standard deviation for k
    views. ±inf where every view differs by the same amount, 0 where none differs."""
    difference = np.asarray(than["holdout_errors"]) - np.asarray(score["holdout_errors"])
    total = float(np.sum(difference))
    error = np.sqrt(len(difference)) * np.std(difference, ddof=1) if len(difference) > 1 else 0
    if error > 0:
        return total / float(error)
    return float(np.sign(total) * np.inf) if total else 0.0
