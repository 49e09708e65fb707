"""The GRT kernel against the independent float64 NumPy loop in reference.py."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference
from conftest import random_complex, random_points, relative_error

import rift_jax as rj
from rift_jax import grt


def setup(rng, distance, n_points=600, half_width=5.0):
    radar = rj.Radar(distance=distance)
    azimuth, polar = rng.uniform(0, 2 * np.pi), rng.uniform(0.05, np.pi - 0.05)
    tx, rx = reference.antenna_positions(distance, radar.spacing, 16, 16, azimuth, polar)
    points = random_points(rng, n_points, half_width)
    rho = random_complex(rng, n_points)
    return radar, points, rho, tx, rx


@pytest.mark.parametrize(
    "distance, half_width", [(10.0, 5.0), (50.0, 3.0), (100.0, 5.0), (1000.0, 5.0)]
)
@pytest.mark.parametrize("near_field", [True, False])
def test_forward_float32_matches_float64_reference(rng, distance, half_width, near_field):
    radar, points, rho, tx, rx = setup(rng, distance, half_width=half_width)
    ours = grt.forward(points, rho, tx, rx, radar.frequencies, near_field=near_field)
    assert ours.dtype == jnp.complex64 and ours.shape == (100, 16, 16)
    expected = reference.forward(points, rho, tx, rx, radar.frequencies, near_field)
    assert relative_error(ours, expected) < 1e-5


def test_plain_float32_would_fail_the_accuracy_bar(rng):
    """The bar above is not loose: a direct float32 evaluation misses it by ~100x."""
    radar, points, rho, tx, rx = setup(rng, 10.0)
    r_b = (
        np.linalg.norm(points[:, None] - tx[None].astype(np.float32), axis=-1)[:, :, None]
        + np.linalg.norm(points[:, None] - rx[None].astype(np.float32), axis=-1)[:, None, :]
    )
    k = (2 * np.pi * radar.frequencies / rj.C0).astype(np.float32)
    naive = np.einsum("v,fvmn->fmn", rho, np.exp(1j * k[:, None, None, None] * r_b) / r_b**2)
    expected = reference.forward(points, rho, tx, rx, radar.frequencies)
    assert relative_error(naive, expected) > 1e-4


def test_non_uniform_frequencies_take_the_direct_path(rng):
    radar, points, rho, tx, rx = setup(rng, 10.0, n_points=200)
    freqs = np.sort(rng.uniform(95e9, 105e9, 7))
    ours = grt.forward(points, rho, tx, rx, freqs)
    assert relative_error(ours, reference.forward(points, rho, tx, rx, freqs)) < 1e-5


def test_adjoint_matches_reference_and_dot_product_float32(rng):
    radar, points, rho, tx, rx = setup(rng, 10.0)
    signal = random_complex(rng, 100, 16, 16)
    back = grt.adjoint(points, signal, tx, rx, radar.frequencies)
    assert back.shape == (600,) and back.dtype == jnp.complex64
    expected = reference.adjoint(points, signal, tx, rx, radar.frequencies)
    assert relative_error(back, expected) < 1e-5
    lhs = jnp.vdot(signal, grt.forward(points, rho, tx, rx, radar.frequencies))
    rhs = jnp.vdot(back, rho)
    assert abs(lhs - rhs) / abs(lhs) < 1e-5


def test_adjoint_dot_product_x64(rng, x64):
    radar, points, rho, tx, rx = setup(rng, 10.0)
    points = points.astype(np.float64)
    rho = jnp.asarray(rho, jnp.complex128)
    signal = jnp.asarray(random_complex(rng, 100, 16, 16, dtype=np.complex128))
    forward = grt.forward(points, rho, tx, rx, radar.frequencies)
    back = grt.adjoint(points, signal, tx, rx, radar.frequencies)
    assert forward.dtype == jnp.complex128 and back.dtype == jnp.complex128
    lhs, rhs = jnp.vdot(signal, forward), jnp.vdot(back, rho)
    assert abs(lhs - rhs) / abs(lhs) < 1e-12
    expected = reference.forward(points, rho, tx, rx, radar.frequencies)
    assert relative_error(forward, expected) < 1e-5  # the separable 1/(4 r_t r_r) amplitude


@pytest.mark.parametrize("near_field", [True, False])
def test_point_scatterer_phase_and_amplitude(near_field):
    radar = rj.Radar()
    tx, rx = reference.antenna_positions(10.0, radar.spacing, 16, 16, 0.7, 1.2)
    point = np.array([[1.3, -0.4, 2.1]], np.float32)
    s = np.asarray(
        grt.forward(
            point, np.ones(1, np.complex64), tx, rx, radar.frequencies, near_field=near_field
        )
    )
    r_b = (
        np.linalg.norm(point.astype(np.float64) - tx, axis=-1)[:, None]
        + np.linalg.norm(point.astype(np.float64) - rx, axis=-1)[None, :]
    )
    k = 2 * np.pi * radar.frequencies / rj.C0
    expected_phase = np.angle(np.exp(1j * k[:, None, None] * r_b))
    phase_error = np.angle(s * np.exp(-1j * expected_phase))
    assert np.abs(phase_error).max() < 1e-5
    amplitude = 1 / r_b**2 if near_field else np.ones_like(r_b)
    np.testing.assert_allclose(np.abs(s), np.broadcast_to(amplitude, s.shape), rtol=1e-5)


def test_swapping_arrays_transposes_signal(rng):
    radar, points, rho, tx, rx = setup(rng, 10.0, n_points=100)
    s = grt.forward(points, rho, tx, rx, radar.frequencies)
    swapped = grt.forward(points, rho, rx, tx, radar.frequencies)
    np.testing.assert_allclose(
        np.asarray(swapped), np.swapaxes(np.asarray(s), 1, 2), rtol=0, atol=1e-6 * np.abs(s).max()
    )


def test_linearity_and_chunk_invariance(rng):
    radar, points, rho, tx, rx = setup(rng, 10.0, n_points=300)
    other = random_complex(rng, 300)
    f = lambda r, chunk=2048: grt.forward(points, r, tx, rx, radar.frequencies, chunk_size=chunk)  # noqa: E731
    combined = f(2.0 * rho - 1.5j * other)
    assert relative_error(combined, 2.0 * f(rho) - 1.5j * f(other)) < 1e-5
    # a chunk far smaller than the points (raised to the kernel's least, 8): many chunks on
    # each device, the last one short
    assert relative_error(f(rho, chunk=7), f(rho)) < 1e-6


@pytest.mark.slow  # five kernels of their own; the default run checks jit and grad elsewhere
def test_jit_vmap_and_grad_agree_with_eager(rng):
    radar = rj.Radar()
    points, rho = random_points(rng, 200, 5.0), random_complex(rng, 200)
    angles = np.array([[0.2, 0.9], [2.5, 1.9], [4.0, 0.4]], np.float32)
    geometry = [rj.antenna_positions(radar, a, p) for a, p in angles]
    freqs = radar.frequencies

    def signal(rho, azimuth, polar):
        tx, rx = rj.antenna_positions(radar, azimuth, polar)
        return grt.forward(points, rho, tx, rx, freqs)

    eager = np.stack([np.asarray(grt.forward(points, rho, tx, rx, freqs)) for tx, rx in geometry])
    jitted = jax.jit(signal)(rho, angles[1, 0], angles[1, 1])
    batched = jax.vmap(signal, in_axes=(None, 0, 0))(rho, angles[:, 0], angles[:, 1])
    np.testing.assert_allclose(
        np.asarray(jitted), eager[1], rtol=0, atol=1e-5 * np.abs(eager).max()
    )
    np.testing.assert_allclose(np.asarray(batched), eager, rtol=0, atol=1e-5 * np.abs(eager).max())

    # grad of a real loss in ρ: for L = ‖Aρ - y‖², JAX's gradient is conj(2 Aᴴ(Aρ - y)).
    target = random_complex(rng, *eager.shape[1:]) * np.abs(eager).max()

    def loss(rho):
        return jnp.sum(jnp.abs(signal(rho, angles[0, 0], angles[0, 1]) - target) ** 2)

    grad = jax.grad(loss)(jnp.asarray(rho))
    grad_jit = jax.jit(jax.grad(loss))(jnp.asarray(rho))
    tx, rx = geometry[0]
    residual = reference.forward(points, rho, np.asarray(tx), np.asarray(rx), freqs) - target
    expected = np.conj(
        2 * reference.adjoint(points, residual, np.asarray(tx), np.asarray(rx), freqs)
    )
    assert relative_error(grad, expected) < 1e-4
    # points ±5 m from the centre come within 1.7 m of the array: the chunks nearest it
    # take three amplitude terms, summing three times the columns (measured 1.7e-6)
    assert relative_error(grad_jit, grad) < 3e-6


@pytest.mark.parametrize(
    "change, word",
    [
        (dict(points=np.full((5, 3), np.nan, np.float32)), "points"),
        (dict(points=np.zeros((5, 2), np.float32)), "points"),
        (dict(reflectivity=np.array([1, 2, np.inf, 0, 0], np.complex64)), "reflectivity"),
        (dict(reflectivity=np.ones(4, np.complex64)), "reflectivity"),
        (dict(tx=np.zeros((0, 3))), "tx"),
        (dict(frequencies=np.array([95e9, -1.0])), "frequencies"),
        (dict(frequencies=np.zeros((2, 2))), "frequencies"),
    ],
)
def test_forward_rejects_bad_input(change, word):
    radar = rj.Radar(n_frequencies=3, n_tx=2, n_rx=2)
    tx, rx = rj.antenna_positions(radar, 0.1, 0.2)
    args = (
        dict(
            points=np.zeros((5, 3), np.float32),
            reflectivity=np.ones(5, np.complex64),
            tx=tx,
            rx=rx,
            frequencies=radar.frequencies,
        )
        | change
    )
    with pytest.raises(ValueError, match=word):
        grt.forward(**args)


def test_adjoint_rejects_wrong_signal_shape():
    radar = rj.Radar(n_frequencies=3, n_tx=2, n_rx=2)
    tx, rx = rj.antenna_positions(radar, 0.1, 0.2)
    with pytest.raises(ValueError, match="signal"):
        grt.adjoint(np.zeros((5, 3)), np.ones((3, 2, 3)), tx, rx, radar.frequencies)


def test_non_finite_points_under_jit_propagate_instead_of_vanishing():
    """Inside a trace values cannot be checked; a NaN point must then poison S, not be skipped."""
    radar = rj.Radar(n_frequencies=4, n_tx=2, n_rx=2)
    tx, rx = rj.antenna_positions(radar, 0.1, 0.2)
    points = np.zeros((5, 3), np.float32)
    points[0, 0] = np.nan
    rho = jnp.ones(5, jnp.complex64)
    s = jax.jit(lambda p: grt.forward(p, rho, tx, rx, radar.frequencies))(points)
    assert np.isnan(np.asarray(s)).all()


def test_the_benchmarks_baseline_computes_the_same_grt(rng):
    """`benchmarks.grt.authors_forward` (the authors' per-frequency algorithm, the baseline of
    the plain-call speed target) computes this GRT, to its float32 phase error (~1e-3)."""
    from benchmarks.grt import authors_forward

    radar, points, rho, tx, rx = setup(rng, 10.0, n_points=300)
    theirs = authors_forward(points, rho, tx, rx, radar.frequencies, threads=2)
    ours = grt.forward(points, rho, tx, rx, radar.frequencies)
    assert 1e-5 < relative_error(theirs, ours) < 1e-2
