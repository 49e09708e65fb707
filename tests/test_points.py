"""Point scatterers at continuous positions (`fit(..., method="points")`): the float64
model against the GRT, its exact position gradients, and recovery of off-grid points."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rift_jax as rj
from rift_jax._solvers import points as P


def scatterers(count: int, extent: float, seed: int) -> rj.PointScatterers:
    """``count`` points at random continuous positions within ±0.7·extent (off every grid),
    at least 1 cm (~3λ) apart, amplitudes within 12 dB, random phases."""
    rng = np.random.default_rng(seed)
    chosen: list[np.ndarray] = []
    while len(chosen) < count:
        x = rng.uniform(-0.7 * extent, 0.7 * extent, 3)
        if all(np.linalg.norm(x - c) > 0.01 for c in chosen):
            chosen.append(x)
    amplitude = rng.uniform(0.25, 1.0, count) * np.exp(1j * rng.uniform(-np.pi, np.pi, count))
    return rj.PointScatterers(np.array(chosen), amplitude, extent)


def test_the_model_is_the_grt_and_its_position_gradient_is_exact(small_cube, x64):
    """Σ a g(x) equals `synthesize` (the float32 GRT) at off-grid points, and the gradient of
    a real functional of it in the positions equals float64 central differences."""
    radar, _, train, _ = small_cube
    truth = scatterers(2, 1.0, seed=1)
    data = rj.synthesize(truth, train[:6], radar)
    geometry = P.Geometry.of(radar, train[:6])
    tx, rx, k = geometry.arrays()
    points = jnp.asarray(truth.points)
    amplitudes = jnp.asarray(np.asarray(truth.reflectivity, np.complex128)) / data.scale
    model = P.signals(points, amplitudes, tx, rx, k, geometry.law)
    assert np.linalg.norm(model - data.signal) / np.linalg.norm(data.signal) < 1e-5

    weights = jnp.asarray(np.random.default_rng(0).normal(size=model.shape) + 0j)

    @jax.jit  # one program for the 13 evaluations below (op by op, each shape compiled)
    def functional(points):
        return jnp.real(jnp.vdot(weights, P.signals(points, amplitudes, tx, rx, k, geometry.law)))

    gradient = np.asarray(jax.grad(functional)(points))
    step = 1e-7  # m: k·2·step ≈ 4e-4 rad of phase, far inside the quadratic regime
    for i in range(2):
        for axis in range(3):
            shift = np.zeros((2, 3))
            shift[i, axis] = step
            central = (functional(points + shift) - functional(points - shift)) / (2 * step)
            assert gradient[i, axis] == pytest.approx(float(central), rel=1e-5)

    # the joint refinement's model, whose derivatives are written per point (each point
    # moves only its own atom), has the plain model's values and forward-mode derivatives
    rng = np.random.default_rng(2)
    d_points = jnp.asarray(rng.normal(size=(2, 3)))
    d_amplitudes = jnp.asarray(rng.normal(size=2) + 1j * rng.normal(size=2))
    tangents = (d_points, d_amplitudes)

    def derivative(model):  # jitted, as `functional`
        model = functools.partial(model, tx=tx, rx=rx, k=k, law=geometry.law)
        return jax.jit(lambda *at: jax.jvp(model, at, tangents))(points, amplitudes)

    plain, sparse = derivative(P.signals), derivative(P._sparse_signals)

    @jax.jit
    def sparse_functional(points):
        model = P._sparse_signals(points, amplitudes, tx, rx, k, geometry.law)
        return jnp.real(jnp.vdot(weights, model))

    np.testing.assert_allclose(jax.grad(sparse_functional)(points), gradient, rtol=1e-10)
    for a, b in zip(plain, sparse, strict=True):
        np.testing.assert_allclose(
            np.asarray(b), np.asarray(a), rtol=0, atol=1e-12 * np.abs(a).max()
        )


def test_the_range_profiles_by_fft_are_the_direct_sums(x64):
    """With uniform frequencies the detection's tables come from an FFT over one period of
    the bistatic range: the same values as the direct sum over the frequencies there."""
    rng = np.random.default_rng(5)
    k = 2 * np.pi * np.linspace(95e9, 105e9, 16) / rj.C0
    r = jnp.asarray(rng.normal(size=(3, 16, 4, 2)) + 1j * rng.normal(size=(3, 16, 4, 2)))
    n = 50
    ranges = jnp.asarray(np.broadcast_to(2 * np.pi / (k[1] - k[0]) / n * np.arange(n), (3, n)))
    direct = P._profiles(r, jnp.asarray(k), ranges)
    np.testing.assert_allclose(P._periodic_profiles(r, n), direct, rtol=1e-9)


def test_the_fast_quantile_and_least_squares_are_the_plain_ones(small_cube, x64):
    """The detection's view quantile (the smallest values taken out in turn) is
    `jnp.quantile`, ties included; the amplitudes by the normal equations, with empty
    slots, are `lstsq`'s on the live points, and so is the residual they leave."""
    rng = np.random.default_rng(6)
    for n in (1, 2, 6, 40):
        values = jnp.asarray(rng.integers(0, 4, (30, n)).astype(float))  # many ties
        np.testing.assert_allclose(
            P._low_quantile(values, P._QUANTILE), jnp.quantile(values, P._QUANTILE, axis=1)
        )
    radar, _, train, _ = small_cube
    geometry = P.Geometry.of(radar, train[:4])
    tx, rx, k = geometry.arrays()
    points = jnp.asarray(rng.uniform(-0.5, 0.5, (4, 3)))
    live = jnp.asarray([True, False, True, True])
    y = jnp.asarray(rng.normal(size=(4, *radar.signal_shape)) + 0j)
    amplitudes, residual = P._least_squares(points, live, y, tx, rx, k, geometry.law)
    atoms = np.stack([np.asarray(P.atom(x, tx, rx, k, geometry.law)).ravel() for x in points])
    plain = np.linalg.lstsq(atoms[[0, 2, 3]].T, np.asarray(y).ravel(), rcond=None)[0]
    np.testing.assert_allclose(np.asarray(amplitudes)[[0, 2, 3]], plain, rtol=1e-9)
    assert amplitudes[1] == 0
    np.testing.assert_allclose(residual.ravel(), np.asarray(y).ravel() - plain @ atoms[[0, 2, 3]],
                               atol=1e-12 * np.abs(y).max())  # fmt: skip


@pytest.mark.parametrize("law", ["radar-equation", "far-field"])
def test_any_radar_is_modelled_as_the_grt_models_it(law, x64):
    """The other spreading laws, non-uniform frequencies (the direct phasors, not the
    ladder) and TX apart from RX: Σ a g(x) equals `synthesize` still, and the lattice's
    separable coherent score equals the exact one where the law is separable."""
    rng = np.random.default_rng(3)
    radar = rj.Radar.from_antennas(
        rng.uniform(-0.02, 0.02, (3, 3)) * [1, 1, 0],
        rng.uniform(-0.02, 0.02, (4, 3)) * [1, 1, 0],
        np.sort(rng.uniform(95e9, 105e9, 5)),
        near_field=law != "far-field",
        spreading="radar-equation" if law == "far-field" else law,
    )
    views = rj.Viewpoints.grid(3, 2, polar_range=(0.3, 1.2))
    truth = scatterers(2, 1.0, seed=4)
    data = rj.synthesize(truth, views, radar)
    geometry = P.Geometry.of(radar, views)
    assert not geometry.law.ladder
    tx, rx, k = geometry.arrays()
    amplitudes = jnp.asarray(np.asarray(truth.reflectivity, np.complex128)) / data.scale
    model = P.signals(jnp.asarray(truth.points), amplitudes, tx, rx, k, geometry.law)
    assert np.linalg.norm(model - data.signal) / np.linalg.norm(data.signal) < 1e-5
    probes = jnp.asarray(truth.points[:1] + rng.normal(0, 1e-3, (4, 3)))
    lattice = P._on_lattice("coherent", probes, model, tx, rx, k, geometry.law)
    exact = [float(P.coherent(x, model, tx, rx, k, geometry.law)) for x in probes]
    np.testing.assert_allclose(np.asarray(lattice), exact, rtol=1e-5)  # its products: complex64


@pytest.mark.slow
@pytest.mark.parametrize("snr_db", [None, 20.0])
def test_finds_off_grid_points(small_cube, snr_db, tmp_path):
    """Three off-grid points: every one found, no false point, positions to micrometres and
    unseen views predicted to the noise (noise-free: to float32 rounding)."""
    radar, _, train, test = small_cube
    truth = scatterers(3, 1.0, seed=7)
    result = rj.fit(
        truth, train, radar=radar, method="points", granularity=0.5, snr_db=snr_db, seed=1,
        max_points=6, progress=False,
    )  # fmt: skip
    assert result.points is not None and len(result.points.points) == 3
    metrics = result.evaluate(truth, test)
    assert (metrics["detected"], metrics["missed"], metrics["false_points"]) == (3, 0, 0)
    if snr_db is None:
        assert metrics["position_max"] < 1e-6 and metrics["p_rmse"] < 1e-3
        assert metrics["amplitude_error"] < 1e-5
        assert result.stopped.outcome is rj.solvers.Outcome.CONVERGED
        # one round for three points: the fit says that it ran out of rounds
        with pytest.warns(rj.FitWarning, match="all `max_points` rounds ran"):
            short = rj.fit(
                truth, train, radar=radar, method="points", granularity=0.5, seed=1,
                max_points=1, refine_steps=0, progress=False,
            )  # fmt: skip
        assert short.stopped.outcome is rj.solvers.Outcome.BUDGET and short.residual > 0.1
    else:
        assert metrics["position_rms"] < 50e-6 and metrics["p_rmse"] < 0.05
        assert metrics["amplitude_error"] < 0.05
    assert metrics["m_ssim"] > 0.95  # the points spread onto the inverse grid, as the truth
    # saved and loaded, the scatterers come back as they were; PLY writes them, not the grid
    loaded = rj.load(rj.save(tmp_path / "points.h5", result))
    np.testing.assert_array_equal(loaded.points.points, result.points.points)
    np.testing.assert_array_equal(loaded.points.reflectivity, result.points.reflectivity)
    ply = rj.export_ply(tmp_path / "points.ply", result, threshold=1e-3)
    assert b"element vertex 3" in ply.read_bytes()[:400]


def test_bad_input(small_cube):
    radar, _, train, _ = small_cube
    truth = scatterers(1, 1.0, seed=0)
    mask = np.ones((5, 5, 5), bool)
    with pytest.raises(ValueError, match="takes no `support`"):
        rj.fit(truth, train, radar=radar, method="points", granularity=0.5, support=mask)
    with pytest.raises(ValueError, match=r"takes no option\(s\) \['epochs'\]"):
        rj.fit(truth, train, radar=radar, method="points", granularity=0.5, epochs=3)
    with pytest.raises(ValueError, match="`monitor`"):
        rj.fit(truth, train, radar=radar, method="points", granularity=0.5, monitor=lambda *a: None)
    signal = np.zeros((len(train), *radar.signal_shape), np.complex64)
    for options, word in [
        ({"max_points": 0}, "max_points"),
        ({"tol": 1.5}, "tol"),
        ({"floor": -1.0}, "floor"),
        ({"noise": -1.0}, "noise"),
        ({"noise": float("inf")}, "noise"),
        ({"noise": True}, "noise"),
        ({"refine_steps": 2.5}, "refine_steps"),
    ]:
        with pytest.raises(ValueError, match=f"`{word}`"):
            rj.solvers.point_scatterers(signal, train, radar, 1.0, **options)
    with pytest.raises(ValueError, match="`signal` must have shape"):
        rj.solvers.point_scatterers(signal[:3], train, radar, 1.0)


def test_a_lattice_around_a_point_that_left_the_box_is_not_empty():
    """A Newton step can leave the box near its faces (a 20-point run failed on an empty
    lattice): the lattice around such a point is taken around its nearest point inside."""
    lattice = P._lattice(np.array([1.2, 0.0, -1.3]), 0.01, 0.005, extent=1.0)
    assert len(lattice) == 3 * 3 * 5 and np.all(np.abs(lattice) <= 1.0)
    assert [1.0, 0.0, -1.0] in lattice.tolist()


@pytest.mark.parametrize("suffix", [".npz", ".h5"])
def test_a_points_result_is_saved_rendered_and_written_as_its_points(small_cube, tmp_path, suffix):
    """The scatterers travel with their FitResult (not only their rendering on the grid),
    `render` spreads them onto any grid that holds them, and PLY writes the points."""
    radar, _, train, _ = small_cube
    found = scatterers(3, 1.0, seed=2)
    history = rj.solvers.History(np.array([0.5, 0.01]), np.array([1.0, 2.0]))
    stopped = rj.solvers.Stop(rj.solvers.Outcome.CONVERGED, 2)
    result = rj.FitResult(
        found.resample(0.5), history, 2.0, "points", {}, stopped, radar, train, {}, points=found
    )
    loaded = rj.load(rj.save(tmp_path / f"result{suffix}", result))
    np.testing.assert_array_equal(loaded.points.points, found.points)
    np.testing.assert_array_equal(loaded.points.reflectivity, found.reflectivity)
    wider = result.render(0.25, extent=1.5)
    total = complex(np.sum(np.asarray(found.reflectivity)))
    assert wider.extent == 1.5
    assert complex(np.sum(np.asarray(wider.reflectivity))) == pytest.approx(total, rel=1e-5)
    with pytest.raises(ValueError, match="`extent`"):
        result.render(0.1, extent=0.2)
    ply = rj.export_ply(tmp_path / "points.ply", result, threshold=1e-3)
    assert b"element vertex 3" in ply.read_bytes()[:400]
