"""``fit(method="auto")``: choose a method by how well it predicts viewpoints it never saw.

No one method was best everywhere: on the stress grid at every method's defaults, with
FISTA's λ then fixed, FISTA was within 0.05 m-SSIM of the best method in 103 of 150 cells
and RIFT(N) in 105, and each lost by far where the other won (docs/solvers.md, "Which
method"). A cell's unseen test views told them apart: picking the method whose predicted
test signals had the lower phase error would have been within 0.05 of the best in 139.
A user has no test views, so ``"auto"`` makes its own from the training views: it holds
out a few (evenly spread in their order, as RIFT's `holdout`), fits each candidate on the
rest on one shared support, scores each by how well it predicts the held-out signals, and
fits the winner again on every viewpoint. Its cost is the candidates' fits on four fifths
of the views on top of the winner's own fit. It was `fit`'s default until FISTA chose its
own λ on held-out views: FISTA alone is now within 0.05 of the best in 148 of the 150
cells, and beside it the held-out views chose RIFT(N) where FISTA's image was better
(docs/experiments.md, "FISTA's λ on held-out views").

The held-out views are a noisy judge, so the candidates are ranked by the one-standard-error
rule (`rift_jax._holdout.rank`), with FISTA, convex and the faster, first: it keeps its
place unless another predicts the held-out views clearly better.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Mapping, Sequence

import numpy as np

from ._checks import FAILED, recorded_failures
from ._fit import (
    AUTO,
    FitResult,
    _data,
    _noise,
    check_options,
    check_train_granularity,
    fit,
)
from ._geometry import Radar, Viewpoints
from ._holdout import paired_t, rank, score, split
from ._operator import check_inside
from ._scenes import GridWarning, Scene
from ._solvers import Diverged, Outcome
from ._solvers.methods import METHODS
from ._support import estimate_support

CANDIDATES = ("fista", "rift-n")
"""``"auto"``'s candidates, the two methods that were best in some cells of the stress grid
(FISTA, its λ then fixed, in 77 of 150, RIFT(N) in 73; no other in any): the first keeps
its place unless another is clearly better (`rift_jax._holdout.rank`), and runs alone
where too few viewpoints leave none to hold out."""
_OURS = (*FAILED, GridWarning)  # rift_jax's warnings about a fit or its input


def fit_auto(
    data,
    viewpoints: Viewpoints,
    *,
    radar: Radar | None,
    granularity: float | None,
    extent: float | None,
    snr_db: float | None,
    support,
    seed: int,
    progress: bool,
    monitor,
    time_limit: float | None,
    candidates: Sequence[str] | Mapping[str, Mapping] = CANDIDATES,
    **options,
) -> FitResult:
    """`fit` with ``method="auto"``: its arguments, and ``candidates``, the methods to
    choose from (see `fit`). `PointScatterers` are fitted on the grid, as by any grid
    method (``method="points"``, which fits them off the grid, is no candidate)."""
    if options:
        raise ValueError(
            f"fit: method {AUTO!r} takes no solver option(s) {sorted(options)}: they differ "
            f"between its candidates; name a method to pass them (or `candidates`)."
        )
    if monitor is not None or time_limit is not None:
        raise ValueError(
            f"fit: method {AUTO!r} runs several fits, so it takes no `monitor` or `time_limit` "
            "(each is one run's); name a method to use them."
        )
    candidates = _check_candidates(candidates)
    # Every fit below would repeat the input's warnings (a grid that does not nest, a
    # phaseless signal): rift_jax's are collected and each said once, at the caller's line,
    # also when a fit raises; the others (JAX's, ...) go on from where they were raised.
    # The input's own are said before any fit, so that a filter that makes one an error
    # stops the call at once, as it stops a single method's `fit`.
    said: set = set()
    prepared = _saying(
        said, _data, data, viewpoints, radar, extent, granularity, snr_db, seed
    )  # fmt: skip
    return _saying(
        said, _choose, data, prepared, viewpoints, candidates, granularity=granularity,
        extent=extent, snr_db=snr_db, support=support, seed=seed, progress=progress,
    )  # fmt: skip


def _saying(said: set, call, *args, **kwargs):
    """``call(*args, **kwargs)`` with rift_jax's warnings collected, then each said once
    (`_say`; not again if in ``said``, which grows). One that the user's filters make an
    error is raised after the call, or, if the call raised, added to its error's notes."""
    caught: list = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            for category in _OURS:
                warnings.simplefilter("always", category)
            result = call(*args, **kwargs)
    except BaseException as error:  # said, but never in place of the error itself
        for raised in _say(caught, said):
            error.add_note(f"{type(raised).__name__}: {raised}")
        raise
    for raised in _say(caught, said):  # the user's filter made a warning an error
        raise raised
    return result


def _say(caught, said: set) -> list[Warning]:
    """Say each of rift_jax's ``caught`` warnings once, at the line that called `fit`, and
    the others where they were raised; returns those the user's filters raised instead.
    ``said`` holds the (category, message) of those said before, and grows."""
    raised = []
    for warning in caught:
        try:
            if not issubclass(warning.category, _OURS):
                warnings.warn_explicit(
                    warning.message, warning.category, warning.filename, warning.lineno
                )
            elif (key := (warning.category, str(warning.message))) not in said:
                said.add(key)
                # _say, _saying, fit_auto, fit, the caller
                warnings.warn(warning.message, warning.category, stacklevel=5)
        except Warning as error:
            raised.append(error)
    return raised


def _choose(
    data, prepared, viewpoints, candidates, *, granularity, extent, snr_db, support, seed,
    progress,
) -> FitResult:  # fmt: skip
    """`fit_auto`'s work, on checked arguments and the data `_data` ``prepared``."""
    given = {"granularity": granularity, "extent": extent, "snr_db": snr_db}
    signal, scale, radar, extent, granularity, known = prepared
    signal = np.asarray(signal) * scale  # in the input's units, as a given `init` field is
    # the candidates fit arrays, which say no noise level: the one `fit` would know is
    # passed to those that use it (RIFT, FISTA), as `noise` in these units
    noise = _noise({}, signal, 1.0, known)
    for own in candidates.values():
        check_train_granularity(own, granularity)
    grid = Scene.empty(extent, granularity)
    check_inside(radar, viewpoints, grid.points())  # as fit does, before the estimate
    start = time.perf_counter()
    estimate = {}
    nonzero = bool(np.any(signal))  # zero data: zero, and no support to estimate
    if isinstance(support, str) and support == "auto" and nonzero:
        support = estimate_support(signal, viewpoints, grid, radar=radar)  # once, for all
        estimate["support_seconds"] = time.perf_counter() - start
    scores: dict[str, dict] = {}
    ranking, held = list(candidates), np.array([], np.int64)
    views = split(len(viewpoints))
    if views is not None and len(candidates) > 1 and nonzero:
        kept, held = views
        for method in candidates:
            options = candidates[method]
            if "noise" in METHODS[method].options:
                options = noise | options
            scores[method] = _score(
                method, options, signal, viewpoints, kept, held, grid, support, radar, seed,
                progress,
            )  # fmt: skip
        ranking = rank(scores)
        first, *later = candidates
        for method in later:  # how clearly each beat the first (> MARGIN: it did)
            scores[method]["paired_t"] = paired_t(scores[method], scores[first])
    rejected, attempts = {}, []
    for method in ranking:  # a final fit that fails gives way to the next candidate
        attempts.append(
            _final(method, data, viewpoints, support, seed, progress, radar, given, candidates)
        )
        result, caught, failure = attempts[-1]
        if failure is None:
            break
        rejected[method] = str(failure)
    else:  # every one failed: the best ranked, saying so (and raising, if it diverged);
        # returned, not rejected: its own failure is in its stats or its error
        result, caught, failure = attempts[0]
        del rejected[ranking[0]]
    for warning in caught:  # the final fit's: `_saying` says them to the caller
        warnings.warn(warning.message, warning.category, stacklevel=2)
    # as fit's: from the estimate on (the final fits' synthesis of a Scene included)
    seconds = time.perf_counter() - start
    selection = {
        "candidates": list(candidates),
        "chosen": result.method,
        "holdout_views": held.tolist(),
        "scores": scores,
        "rejected": rejected,
        "seconds": seconds - result.seconds,
    }
    stats = result.stats | estimate | {"selection": selection}
    result = dataclasses.replace(result, seconds=seconds, stats=stats)
    if isinstance(failure, Diverged):
        failure.result = result
        raise failure
    return result


def _final(method, data, viewpoints, support, seed, progress, radar, given, candidates):
    """The fit of ``method`` on every viewpoint: (result, the warnings that it likely
    failed, recorded, and its failure: RIFT's collapse, a `Diverged`, or None)."""
    try:
        result, caught = recorded_failures(
            fit, data, viewpoints, method=method, support=support, seed=seed,
            progress=progress, radar=radar, **given, **candidates[method],
        )  # fmt: skip
    except Diverged as error:
        return error.result, [], error
    return result, caught, result.stats.get("collapse")


def _check_candidates(candidates) -> dict[str, dict]:
    """``candidates`` as {method: its options}: a sequence of names (each at its defaults)
    or a mapping of names to option dicts."""
    grid_methods = sorted(m for m, method in METHODS.items() if not method.scatterers)
    out = {}
    if isinstance(candidates, Mapping):
        out = dict(candidates)
    elif isinstance(candidates, Sequence) and not isinstance(candidates, str):
        if all(isinstance(name, str) for name in candidates):
            out = {name: {} for name in candidates}
        if len(out) != len(candidates):  # a name twice
            out = {}
    if not out or not set(out) <= set(grid_methods):
        raise ValueError(
            f"fit: `candidates` must name distinct grid methods (from {grid_methods}), as a "
            f"sequence or a mapping to each one's options, got {candidates!r}."
        )
    for name, options in out.items():
        if not isinstance(options, Mapping):
            raise ValueError(
                f"fit: `candidates[{name!r}]` must be a mapping of `fit` options, got "
                f"{type(options).__name__}."
            )
        check_options(name, options)  # `monitor` and the like are no method's options
    return {name: dict(options) for name, options in out.items()}


def _score(method, options, signal, viewpoints, kept, held, grid, support, radar, seed, progress):
    """One candidate fitted on the ``kept`` viewpoints and scored on the ``held`` ones: its
    held-out `score` (residual, each held-out view's share of it, failure: RIFT's collapse,
    a divergence, or None), seconds,
    stop, and the messages of the warnings
    that it likely failed (recorded, not raised: the final fit raises its own; given an
    array, the fit knows no noise level, so their judgement assumes none; RIFT's own
    stopping and collapse check, and FISTA's λ, get it as `noise`)."""
    start = time.perf_counter()

    def run():
        try:
            return fit(
                signal[kept], viewpoints.subset(kept), radar=radar, method=method,
                extent=grid.extent, granularity=grid.granularity, support=support, seed=seed,
                progress=progress, **options,
            )  # fmt: skip
        except Diverged as error:  # scored on its best iterate, and ranked last
            return error.result

    result, caught = recorded_failures(run)
    failure = result.stats.get("collapse")
    if result.stopped.outcome is Outcome.DIVERGED:
        failure = f"diverged ({result.stopped})"
    predicted = result.predict(viewpoints.subset(held)).signal
    return score(predicted, signal[held], failure) | {
        "seconds": time.perf_counter() - start,
        "stopped": result.stopped.outcome.value,
        "warnings": [str(w.message) for w in caught],
    }
