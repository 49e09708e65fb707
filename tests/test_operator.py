"""The many-viewpoint operator: agreement with the reference, exact adjoint, row blocks."""

import re

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest
import reference
from conftest import (
    assert_compilations_are_logged,
    compilations,
    random_complex,
    relative_error,
)

import rift_jax as rj


@pytest.fixture(scope="module")
def problem():
    rng = np.random.default_rng(1)
    radar = rj.Radar(n_frequencies=20, n_tx=6, n_rx=5)
    viewpoints = rj.Viewpoints.grid(3, 3)  # 9 views: an odd count exercises device padding
    points = rj.scenes.cube(0.4, edge=1.6).occupied()[0]
    op = rj.grt_operator(radar, viewpoints, points)
    return radar, viewpoints, points, op, rng


def test_is_a_lineax_operator_matching_the_reference(problem):
    radar, viewpoints, points, op, rng = problem
    assert isinstance(op, lx.AbstractLinearOperator) and isinstance(op.fn, rj.GRT)
    assert op.in_structure().shape == (len(points),)
    assert op.out_structure().shape == (9, 20, 6, 5)
    rho = random_complex(rng, len(points))
    signal = eqx.filter_jit(op.mv)(jnp.asarray(rho))
    # Against the nominal float64 geometry: the operator must not round points or angles.
    for i in (0, 4, 8):
        az, pol = viewpoints.azimuth[i], viewpoints.polar[i]
        tx, rx = reference.antenna_positions(radar.distance, radar.spacing, 6, 5, az, pol)
        expected = reference.forward(points, rho, tx, rx, radar.frequencies)
        assert relative_error(signal[i], expected) < 1e-5
        assert relative_error(op.fn.view(rho, i), expected) < 1e-5
    with pytest.raises(ValueError, match="index"):
        op.fn.view(rho, 9)


def test_far_field_operator_at_50_m(rng):
    radar = rj.Radar(n_frequencies=20, n_tx=6, n_rx=5, distance=50.0, near_field=False)
    viewpoints = rj.Viewpoints.grid(2, 2, (0.1 * np.pi, 0.3 * np.pi), (0.1 * np.pi, 0.3 * np.pi))
    points = rj.scenes.weak_target(0.5, granularity=0.24).occupied()[0]
    op = rj.grt_operator(radar, viewpoints, points)
    rho = random_complex(rng, len(points))
    signal = eqx.filter_jit(op.mv)(jnp.asarray(rho))
    for i in range(4):
        az, pol = viewpoints.azimuth[i], viewpoints.polar[i]
        tx, rx = reference.antenna_positions(50.0, radar.spacing, 6, 5, az, pol)
        expected = reference.forward(points, rho, tx, rx, radar.frequencies, near_field=False)
        assert relative_error(signal[i], expected) < 1e-5


def test_adjoint_transpose_and_gradient_agree(problem):
    _, _, points, op, rng = problem
    rho = jnp.asarray(random_complex(rng, len(points)))
    y = jnp.asarray(random_complex(rng, *op.out_structure().shape))

    @eqx.filter_jit
    def everything(op, rho, y):
        forward = op.mv(rho)
        back = op.fn.adjoint(y)
        # lineax's transpose (jax.linear_transpose through shard_map) is the plain transpose
        transposed = op.transpose().mv(jnp.conj(y))
        # every view's row block, summed: one traced index, not 9 unrolled copies
        views = jnp.arange(op.fn.n_views)
        blocks = jnp.sum(jax.vmap(lambda i: op.fn.view_adjoint(y[i], i))(views), axis=0)
        grad = jax.grad(lambda r: jnp.sum(jnp.abs(op.mv(r) - y) ** 2))(rho)
        return forward, back, transposed, blocks, grad, op.fn.adjoint(forward - y)

    forward, back, transposed, blocks, grad, residual_back = everything(op, rho, y)
    lhs = jnp.vdot(y, forward)
    assert abs(lhs - jnp.vdot(back, rho)) / abs(lhs) < 1e-5
    assert relative_error(jnp.conj(transposed), back) < 1e-5
    assert relative_error(blocks, back) < 1e-5
    assert relative_error(grad, jnp.conj(2 * residual_back)) < 1e-5


def test_vmap_over_reflectivities_and_views(problem):
    _, _, points, op, rng = problem
    rho = jnp.asarray(random_complex(rng, len(points)))
    batched = jax.vmap(op.mv)(jnp.stack([rho, 1j * rho]))
    single = op.mv(rho)
    assert relative_error(batched[1], 1j * single) < 1e-6
    views = jax.vmap(op.fn.view, in_axes=(None, 0))(rho, jnp.array([2, 5]))
    assert relative_error(views, single[jnp.array([2, 5])]) < 1e-6


@pytest.mark.slow  # compiles the forward for four block sizes
def test_plain_calls_run_in_view_blocks_sharing_one_program(problem, caplog):
    """A call on concrete values runs its views in blocks of `views_per_block`, the last
    one padded (fewer views: one smaller block): the same signals as all views in one
    program, bit for bit where each view runs whole on one device. Another view count
    that pads to the same blocks, and inputs copied to every device (as `fit`'s residual
    passes them), compile no forward of their own; no view at all gives no signal."""
    from rift_jax._operator import views_per_block
    from rift_jax._sharding import replicated

    _, _, points, op, rng = problem
    rho = jnp.asarray(random_complex(rng, len(points)))
    size = views_per_block()
    assert size % jax.device_count() == 0
    many = op.fn.subset(np.arange(size + 1) % op.fn.n_views)  # two blocks, one padded
    assert len(many._blocks()) == 2
    np.testing.assert_array_equal(many(rho), many._signals(rho))
    for n in (1, 3):  # one view (its voxels split over the devices), and a smaller block
        few = op.fn.subset(np.arange(n))
        expected = few._signals(rho)
        np.testing.assert_allclose(
            few(rho), expected, rtol=1e-6, atol=1e-6 * np.abs(expected).max()
        )
    more = op.fn.subset(np.arange(size + 2) % op.fn.n_views)  # two blocks, as `many`'s
    assert not [m for m in compilations(caplog, lambda: more(rho)) if "_signals" in m]
    copied = replicated((more, rho))
    assert not [m for m in compilations(caplog, lambda: copied[0](copied[1])) if "_signals" in m]
    np.testing.assert_array_equal(more(rho)[: size + 1], many(rho))
    assert op.fn.subset(np.array([], int))(rho).shape == (0, *op.fn.radar.signal_shape)


PRODUCTS = r"Compiling jit\((_signals|adjoint|_row|render)\)"


def test_products_trace_once_whatever_the_callers_matmul_precision(problem, caplog):
    """The operator's products (all views, one view and its adjoint) and a field's
    rendering are traced under "highest" whatever the caller's setting, so a plain call
    made under another setting finds the program a plain call made before: it compiles
    none of them again (the eager conversions around them are the caller's)."""
    _, _, points, op, rng = problem
    rho = jnp.asarray(random_complex(rng, len(points)))
    field = rj.Field(rj.RiftN(width=8, depth=1, key=jax.random.key(0)), 1.0)
    calls = (
        lambda: op.fn(rho),
        lambda: op.fn.adjoint(op.fn(rho)),
        lambda: op.fn.view_adjoint(op.fn.view(rho, 1), 1),
        lambda: field.render(points),
    )
    for call in calls:
        jax.block_until_ready(call())
    assert_compilations_are_logged(caplog)
    for setting in ("highest", "bfloat16"):
        with jax.default_matmul_precision(setting):
            for call in calls:
                compiled = compilations(caplog, call)
                assert not [m for m in compiled if re.match(PRODUCTS, m)], setting


def test_operator_rejects_bad_input(problem):
    radar, viewpoints, points, op, _ = problem
    with pytest.raises(ValueError, match="grid_points"):
        rj.grt_operator(radar, viewpoints, np.zeros((0, 3)))
    with pytest.raises(ValueError, match="grid_points"):
        rj.grt_operator(radar, viewpoints, np.full((4, 3), np.nan))
    with pytest.raises(ValueError, match="viewpoints"):
        rj.grt_operator(radar, [(0.0, 1.0)], points)
    with pytest.raises(ValueError, match="radar"):
        rj.grt_operator("paper", viewpoints, points)
    with pytest.raises(ValueError, match="signal"):
        op.fn.adjoint(jnp.zeros((2, 20, 6, 5), jnp.complex64))
    with pytest.raises(ValueError, match=r"`grid_points` reach 10 m .* radar stands 10 m"):
        rj.grt_operator(radar, viewpoints, np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 10.0]]))


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::rift_jax.FitWarning")  # RIFT from one view fits little
def test_degenerate_geometry_stays_finite():
    """Coincident viewpoints, a single viewpoint and a single frequency are legitimate
    (if poor) data: every method returns a finite reconstruction and finite metrics. Least
    squares sees one frequency with both view cases (each case compiles every method);
    RIFT, one case (4 frequencies: on one frequency and one view its loss is flat, a
    collapse it retries and warns about)."""
    scene = rj.scenes.cube(0.5, extent=1.5)
    one = rj.Viewpoints(np.array([0.3]), np.array([1.1]))
    twice = rj.Viewpoints(np.array([0.3, 0.3]), np.array([1.1, 1.1]))
    single = rj.Radar(n_frequencies=1, n_tx=2, n_rx=2)
    cases = [(m, single, v, {"iterations": 3}) for v in (one, twice) for m in ("kaczmarz", "lsmr")]
    cases.append(("rift-n", rj.Radar(n_frequencies=4, n_tx=2, n_rx=2), one, {"epochs": 3}))
    for method, radar, views, options in cases:
        result = rj.fit(scene, views, radar=radar, method=method, progress=False, **options)
        assert np.all(np.isfinite(np.asarray(result.scene.reflectivity))), method
        metrics = result.evaluate(scene, views)
        assert all(np.isfinite(v) for v in metrics.values()), (method, metrics)
        assert method == "rift-n" or metrics["residual"] <= 1.0, (method, metrics)


@pytest.mark.slow  # LSMR's path; LSMR itself: test_solvers
def test_lineax_variants_use_the_kernels_and_a_lineax_solver_runs():
    rng = np.random.default_rng(2)
    radar = rj.Radar(n_frequencies=8, n_tx=3, n_rx=3)
    points = rj.scenes.cube(0.5, edge=1.0).occupied()[0]
    op = rj.grt_operator(radar, rj.Viewpoints.grid(3, 2), points)
    x = jnp.asarray(random_complex(rng, op.in_size()))
    y = jnp.asarray(random_complex(rng, *op.out_structure().shape))
    matrix = op.as_matrix()
    assert matrix.shape == (op.out_size(), op.in_size())
    assert relative_error(matrix @ x, op.mv(x).ravel()) < 1e-5
    assert relative_error(op.transpose().mv(y), matrix.T @ y.ravel()) < 1e-5
    assert relative_error(lx.conj(op).mv(x).ravel(), matrix.conj() @ x) < 1e-5
    assert relative_error(lx.conj(op.transpose()).mv(y), op.fn.adjoint(y)) < 1e-6
    assert op.transpose().transpose().mv(x).shape == op.out_structure().shape
    assert not lx.is_symmetric(op) and lx.materialise(op) is op
    # lineax's matrix-free LSMR solves the (overdetermined, consistent) system.
    solution = lx.linear_solve(op, op.mv(x), lx.LSMR(rtol=1e-6, atol=1e-6), throw=False)
    assert relative_error(solution.value, x) < 5e-2
