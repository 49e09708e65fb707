"""The one run every accuracy benchmark repeats: reconstruct, then score."""

from __future__ import annotations

import rift_jax as rj


def fit_and_evaluate(scene, train, test, *, radar, method, granularity, seed, progress, options):
    """Reconstruct ``scene`` from its signals at ``train`` on the inverse grid of
    ``granularity`` and score it against the truth at ``test``: (FitResult, metrics)."""
    result = rj.fit(
        scene,
        train,
        radar=radar,
        method=method,
        granularity=granularity,
        seed=seed,
        progress=progress,
        **options,
    )
    return result, result.evaluate(scene, test)
