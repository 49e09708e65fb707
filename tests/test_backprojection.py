"""The fast approximate backprojection (`rift_jax._backprojection`) against the exact
adjoint: within its documented error on radars of every shape it takes, and exact where
`estimate_support` and the support-leak check rely on it only to screen."""

import numpy as np
import pytest
from conftest import random_complex

import rift_jax as rj
from rift_jax._backprojection import fast_backprojection


@pytest.mark.parametrize(
    "radar",
    [
        rj.Radar(n_frequencies=8, n_tx=4, n_rx=4),  # small_cube's radar
        rj.Radar(n_frequencies=8, n_tx=4, n_rx=4, near_field=False),
        rj.Radar(n_frequencies=8, n_tx=1, n_rx=3, distance=50.0),
        rj.Radar(n_frequencies=1, f_min=1e11, f_max=1e11, n_tx=4, n_rx=4),
    ],
    ids=["small", "far-field", "one-tx-at-50m", "one-frequency"],
)
def test_fast_backprojection_follows_the_adjoint(radar, rng):
    """On 30 random scatterers among ±1 m at 0.2 m, from 30 views: within 8 % of the exact
    adjoint in relative (vector) error, and its peak at the exact one's."""
    train, _ = rj.Viewpoints.grid(8, 6, polar_range=(0.2, 1.4)).split(30, 1)
    points = rj.Scene.empty(1.0, 0.2).points()
    rho = np.zeros(len(points), np.complex64)
    rho[rng.choice(len(points), 30, replace=False)] = random_complex(rng, 30)
    operator = rj.grt_operator(radar, train, points)
    signal = np.asarray(operator.mv(rho))
    exact = np.asarray(operator.fn.adjoint(signal))
    fast = np.asarray(fast_backprojection(signal, train, points, radar))
    assert fast.shape == exact.shape and fast.dtype == np.complex64
    assert np.linalg.norm(fast - exact) < 0.08 * np.linalg.norm(exact)
    assert np.argmax(np.abs(fast)) == np.argmax(np.abs(exact))


def test_fast_backprojection_is_linear_and_sums_views(rng):
    """Σ over views: two halves backprojected apart add up to the whole; a scaled signal
    backprojects scaled."""
    radar = rj.Radar(n_frequencies=8, n_tx=4, n_rx=4)
    train, _ = rj.Viewpoints.grid(8, 6, polar_range=(0.2, 1.4)).split(30, 1)
    points = rj.Scene.empty(1.0, 0.2).points()
    signal = random_complex(rng, len(train), *radar.signal_shape)
    whole = np.asarray(fast_backprojection(signal, train, points, radar))
    halves = sum(
        np.asarray(fast_backprojection(signal[rows], train[rows], points, radar))
        for rows in (slice(0, 15), slice(15, 30))
    )
    np.testing.assert_allclose(halves, whole, rtol=0, atol=1e-5 * np.abs(whole).max())
    doubled = np.asarray(fast_backprojection((2 - 1j) * signal, train, points, radar))
    np.testing.assert_allclose(doubled, (2 - 1j) * whole, rtol=0, atol=1e-5 * np.abs(doubled).max())
