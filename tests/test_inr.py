"""RIFT: the INRs, the losses, training through the GRT, and `fit(method="rift-n"/"rift-s")`."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference
from conftest import assert_compilations_are_logged, compilations, random_complex, run_docs_block

import rift_jax as rj
from rift_jax._solvers._common import as_complex, as_pair, realified
from rift_jax._solvers.inr.active_set import Candidates, StepPoints
from rift_jax._solvers.inr.optimizer import _decay_mask, optimizer_for
from rift_jax._solvers.inr.training import _step, batch_order, on_extent
from rift_jax._support import mask_at

# These tests train tiny budgets to test training's mechanics, not its quality: whether a
# fit failed is `fit`'s FitWarning, tested in test_fit.py and test_stability.py.
pytestmark = pytest.mark.filterwarnings("ignore::rift_jax.FitWarning")


# -- models -------------------------------------------------------------------------------


@pytest.mark.parametrize("cls", [rj.RiftN, rj.RiftS])
def test_model_shapes_and_dtypes(cls):
    model = cls(width=16, depth=3, key=jax.random.key(0))
    out = model(jnp.zeros(3))
    assert out.shape == (2,) and out.dtype == jnp.float32
    xyz = jax.random.uniform(jax.random.key(1), (50, 3), minval=-1, maxval=1)
    batch = jax.vmap(model)(xyz)
    assert batch.shape == (50, 2) and bool(jnp.all(jnp.abs(batch) <= 1))  # tanh / sine
    assert len(model.hidden) == 3 and model.hidden[0].weight.shape == (16, 3)
    field = rj.Field(model, extent=5.0, gain=2.0 - 1.0j)
    rho = field.render(5.0 * xyz)
    assert rho.shape == (50,) and rho.dtype == jnp.complex64
    expected = (2.0 - 1.0j) * jax.lax.complex(batch[:, 0], batch[:, 1])
    np.testing.assert_allclose(rho, expected, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(field.scaled(3.0).render(5.0 * xyz), 3 * rho, rtol=1e-5)


@pytest.mark.slow  # the third model, not a default
def test_hash_grid_encoding_blends_its_corners(tiny):
    """`HashGrid`: a dense level's corner holds its own table entry and a cell's centre the
    mean of its 8 corners; a level with more corners than entries hashes into the table;
    the model's output is bounded like RiftN's, and `fit` trains it by name."""
    model = rj.HashGrid(width=8, depth=1, levels=2, features=2, table_size=64, coarsest=2,
                        finest=8, key=jax.random.key(0))  # fmt: skip
    assert model.resolutions == (2, 8)  # 27 corners fit in 64 entries; 729 do not
    tables = jnp.arange(2 * 64 * 2, dtype=jnp.float32).reshape(2, 64, 2)
    model = eqx.tree_at(lambda m: m.tables, model, tables)
    corner = jnp.asarray([0.0, -1.0, 1.0])  # level 0: corner (1, 0, 2) of 3 per axis
    assert np.allclose(model.encode(corner)[:2], tables[0, 1 + 3 * (0 + 3 * 2)])
    centre = jnp.asarray([-0.5, -0.5, -0.5])  # level 0: the middle of cell (0, 0, 0)
    corners = [i + 3 * (j + 3 * k) for k in (0, 1) for j in (0, 1) for i in (0, 1)]
    np.testing.assert_allclose(model.encode(centre)[:2], tables[0, corners].mean(axis=0))
    xyz = jax.random.uniform(jax.random.key(1), (50, 3), minval=-1, maxval=1)
    out = jax.vmap(model)(xyz)
    assert out.shape == (50, 2) and bool(jnp.all(jnp.abs(out) <= 1))
    hashed = jax.vmap(model.encode)(xyz)[:, 2:]  # level 1: every value a table entry's blend
    assert bool(jnp.all((hashed >= 128) & (hashed <= 255)))
    with pytest.raises(ValueError, match="finest"):
        rj.HashGrid(coarsest=8, finest=4, key=jax.random.key(0))
    radar, scene, train, _ = tiny
    result = rj.fit(scene, train, radar=radar, method="rift-n", model="hash-grid", epochs=20,
                    epoch_views=None, progress=False)  # fmt: skip
    assert isinstance(result.field.model, rj.HashGrid) and result.stats["model"] == "hash-grid"


def test_siren_initialisation():
    omega = 30.0
    model = rj.RiftS(width=64, depth=3, omega_0=omega, key=jax.random.key(0))
    first, later = model.hidden[0].weight, model.hidden[1].weight
    assert float(jnp.max(jnp.abs(first))) <= 1 / 3
    bound = np.sqrt(6 / 64) / omega
    assert float(jnp.max(jnp.abs(later))) <= bound
    assert float(jnp.max(jnp.abs(later))) > 0.9 * bound  # uniform over the whole range


def test_model_bad_input():
    with pytest.raises(ValueError, match="width"):
        rj.RiftN(width=0, key=jax.random.key(0))
    with pytest.raises(ValueError, match="omega_0"):
        rj.RiftS(omega_0=-1.0, key=jax.random.key(0))
    with pytest.raises(ValueError, match="model"):
        rj.Field(lambda x: x, extent=1.0)
    with pytest.raises(ValueError, match="gain"):
        rj.Field(rj.RiftN(key=jax.random.key(0)), extent=1.0, gain=0.0)
    with pytest.raises(ValueError, match="factor"):
        rj.Field(rj.RiftN(key=jax.random.key(0)), extent=1.0).scaled(-2.0)


# -- losses -------------------------------------------------------------------------------


def test_losses_hand_values():
    target = jnp.asarray([1 + 0j, -2j])
    pred = jnp.asarray([1 + 0j, 2j])  # same magnitudes; the second phase is off by π
    # paper: magnitudes agree; angles 0 vs 0 and −π/2 vs π/2 → mean |Δ∠| = π/2
    assert float(rj.losses.paper_loss(pred, target)) == pytest.approx(1000 * np.pi / 2, rel=1e-6)
    assert float(rj.losses.paper_loss(pred, target, alpha_phase=1.0)) == pytest.approx(np.pi / 2)
    # robust: (0 + |S|·(1 − cos π) = 2·2) / 2 entries / mean|S| = 1.5 → 4/3
    assert float(rj.losses.robust_loss(pred, target)) == pytest.approx(4 / 3, rel=1e-6)
    # mse: |P − S|² = 0, 16 → mean 8 over mean|S|² = 2.5 → 3.2
    assert float(rj.losses.complex_mse(pred, target)) == pytest.approx(3.2, rel=1e-6)
    # a pure magnitude error, 2 against 1 at the same phase
    two, one = jnp.asarray([2 + 0j]), jnp.asarray([1 + 0j])
    assert float(rj.losses.paper_loss(two, one)) == pytest.approx(1.0)
    assert float(rj.losses.robust_loss(two, one)) == pytest.approx(1.0)
    assert float(rj.losses.complex_mse(two, one)) == pytest.approx(1.0)
    # the paper's angle difference is not wrapped: phases ±(π − 0.1) count 2π − 0.2 apart
    a, b = jnp.exp(1j * (np.pi - 0.1)), jnp.exp(-1j * (np.pi - 0.1))
    assert float(rj.losses.paper_loss(a[None], b[None], alpha_phase=1.0)) == pytest.approx(
        2 * np.pi - 0.2, rel=1e-5
    )
    assert float(rj.losses.robust_loss(a[None], b[None])) == pytest.approx(
        1 - np.cos(0.2), rel=1e-3
    )
    for loss in rj.losses.LOSSES.values():
        assert float(loss(target, target)) == pytest.approx(0.0, abs=1e-7)
        with pytest.raises(ValueError, match="same shape"):
            loss(pred, target[:1])
    # a zero prediction (where a phase is undefined): finite value and gradient for the
    # default and the MSE loss
    zero = jnp.zeros(2, jnp.complex64)
    for loss in (rj.losses.robust_loss, rj.losses.complex_mse):
        value, grad = jax.value_and_grad(lambda p, loss=loss: loss(p, target))(zero)
        assert np.isfinite(float(value)) and bool(jnp.all(jnp.isfinite(grad)))


def test_batches_visit_every_viewpoint_in_one_shape():
    rng = np.random.default_rng(0)
    batches = batch_order(rng, 23, 10)
    assert batches.shape == (3, 10)
    assert set(batches.ravel()) == set(range(23))  # all 23, plus 7 repeated to fill up
    assert not np.array_equal(batches, batch_order(rng, 23, 10))  # a fresh order each epoch
    assert batch_order(rng, 5, 5).shape == (1, 5)


def test_an_epoch_visits_at_least_epoch_views_viewpoints():
    """From fewer viewpoints than `epoch_views`, an epoch passes over them several times,
    each view equally often, so that the epoch-counted schedule means about as many steps
    from 10 or 30 views as from 100; from as many or more, one pass, as with None."""
    recipe = rj.solvers.Recipe()
    assert recipe.epoch_views == 100 and rj.solvers.RECIPES["paper"].epoch_views is None
    passes = {n: recipe.passes(n) for n in (10, 30, 99, 100, 1000)}
    assert passes == {10: 10, 30: 4, 99: 2, 100: 1, 1000: 1}
    assert rj.solvers.Recipe(epoch_views=None).passes(10) == 1
    rng = np.random.default_rng(0)
    batches = batch_order(rng, 30, 10, passes=4)
    assert batches.shape == (12, 10)
    assert np.array_equal(np.bincount(batches.ravel()), np.full(30, 4))  # each view 4 times
    assert len(set(map(tuple, np.split(batches.ravel(), 4)))) == 4  # a fresh order per pass
    assert batch_order(rng, 7, 10, passes=3).shape == (3, 10)  # 21 views filled up to 30
    with pytest.raises(ValueError, match="epoch_views"):
        rj.solvers.Recipe(epoch_views=0)


def test_weight_decay_spares_the_gain():
    field = rj.Field(rj.RiftN(width=4, depth=1, key=jax.random.key(0)), extent=1.0)
    params, _ = eqx.partition(field, eqx.is_inexact_array)
    mask = _decay_mask(params)
    assert mask.log_gain is False and mask.phase is False
    assert all(jax.tree.leaves(mask.model))


# -- training through the GRT -------------------------------------------------------------


def _dense_reference(radar, viewpoints, points):
    """The float64 GRT matrix, (n_views·F·M·N, V), from tests/reference.py."""
    blocks = []
    eye = np.eye(len(points))
    for az, pol in zip(viewpoints.azimuth, viewpoints.polar, strict=True):
        tx, rx = reference.antenna_positions(
            radar.distance, radar.spacing, radar.n_tx, radar.n_rx, az, pol
        )
        cols = [reference.forward(points, e, tx, rx, radar.frequencies).ravel() for e in eye]
        blocks.append(np.stack(cols, axis=1))
    return np.concatenate(blocks, axis=0)


@pytest.mark.parametrize("loss_name", ["robust", "paper", "mse"])
def test_gradient_through_the_grt_matches_float64_finite_differences(tiny, loss_name, rng):
    """The float32 gradient (adjoint kernel route) against central differences of an
    independent float64 pipeline: the NumPy reference GRT and the INR in x64."""
    radar, _, train, _ = tiny
    views = train.subset([0, 5, 9])
    points = rj.scenes.cube(0.5, extent=1.0).points()[::4]  # 32 points
    operator = rj.grt_operator(radar, views, points)
    loss = rj.losses.LOSSES[loss_name]
    model = rj.RiftN(width=8, depth=2, key=jax.random.key(3))
    field = rj.Field(model, extent=1.0, gain=30.0 * np.exp(0.3j))
    signal = jnp.asarray(random_complex(rng, *operator.out_structure().shape))

    @eqx.filter_jit
    def ours(params):
        rho = eqx.combine(params, static).render(points)
        return loss(as_complex(realified(operator.fn)(as_pair(rho))), signal)

    params, static = eqx.partition(field, eqx.is_inexact_array)
    grads = eqx.filter_grad(ours)(params)
    matrix = _dense_reference(radar, views, np.asarray(points, np.float64))
    with jax.enable_x64(True):
        params64 = jax.tree.map(lambda a: jnp.asarray(a, jnp.float64), params)
        points64 = jnp.asarray(points, jnp.float64)
        signal64 = jnp.asarray(signal, jnp.complex128).ravel()

        @jax.jit  # one program: op by op, each of its ~100 operations compiled alone
        def theirs(params):
            rho = jax.vmap(eqx.combine(params, static))(points64)
            return loss(jnp.asarray(matrix) @ rho, signal64)

        leaves, treedef = jax.tree.flatten(params64)
        for _ in range(3):
            direction = treedef.unflatten([jnp.asarray(rng.normal(size=a.shape)) for a in leaves])
            plus = theirs(jax.tree.map(lambda p, d: p + 1e-6 * d, params64, direction))
            minus = theirs(jax.tree.map(lambda p, d: p - 1e-6 * d, params64, direction))
            finite_difference = float((plus - minus) / 2e-6)
            ad = sum(
                float(jnp.vdot(jnp.asarray(g, jnp.float64), d))
                for g, d in zip(jax.tree.leaves(grads), jax.tree.leaves(direction), strict=True)
            )
            assert ad == pytest.approx(finite_difference, rel=2e-3, abs=1e-6)


@pytest.mark.slow  # op-by-op dispatch compiles every primitive (~30 s)
def test_jit_step_equals_eager_step(tiny):
    _, scene, train, _ = tiny
    radar = rj.Radar(n_frequencies=4, n_tx=2, n_rx=3)  # op-by-op dispatch is slow: keep it small
    operator = rj.grt_operator(radar, train, scene.points())
    signal = rj.synthesize(scene, train, radar).signal
    field = rj.Field(rj.RiftN(width=8, depth=2, key=jax.random.key(0)), extent=1.0, gain=5.0)
    params, static = eqx.partition(field, eqx.is_inexact_array)
    recipe = rj.solvers.Recipe(batch_views=2, learning_rate=1e-2)
    optimizer, state = optimizer_for(recipe, 8, params)
    points = StepPoints(operator.fn, jnp.asarray(scene.points(), jnp.float32))
    args = (params, state, static, optimizer, recipe.loss_fn, points)
    rest = (jnp.asarray(signal), jnp.arange(2))
    jitted = _step(*args, *rest)
    eager = _step.__wrapped__(*args, *rest)  # op by op, no outer jit
    for a, b in zip(jax.tree.leaves(jitted), jax.tree.leaves(eager), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=2e-4, atol=1e-6)


def test_rift_overfits_a_tiny_scene(tiny):
    """On its own grid the scene is explainable: the loss falls by orders of magnitude and
    the scene comes back."""
    radar, scene, train, test = tiny
    options = dict(radar=radar, method="rift-n", granularity=0.5, progress=False)
    # every epoch, each one pass over the 30 views (3 steps)
    result = rj.fit(scene, train, epochs=300, patience=None, epoch_views=None, **options)
    loss = result.history.loss
    assert len(loss) == 300 and result.stopped == rj.solvers.Stop(rj.solvers.Outcome.BUDGET, 300)
    assert loss.min() < 1e-2 * loss[0]
    metrics = result.evaluate(scene, test)
    assert metrics["m_ssim"] > 0.9 and metrics["t_iou"] == 1.0
    assert result.stats["best_loss"] == pytest.approx(loss.min())
    # the field is continuous: it renders on any grid, and `scene` is its rendering
    assert result.render(0.25).shape == (9, 9, 9)
    np.testing.assert_allclose(result.render(0.5).reflectivity, result.scene.reflectivity, 1e-4)


@pytest.mark.slow  # RIFT(S), with steps of its own; no candidate of `fit`'s default
def test_rift_s_end_to_end_and_seeded(tiny):
    radar, scene, train, test = tiny
    options = dict(radar=radar, method="rift-s", epochs=3, progress=False)
    first = rj.fit(scene, train, seed=1, **options)
    again = rj.fit(scene, train, seed=1, **options)
    other = rj.fit(scene, train, seed=2, **options)
    np.testing.assert_array_equal(first.scene.reflectivity, again.scene.reflectivity)
    # 30 views: 4 passes (`epoch_views`) of 3 steps of 10
    assert first.stats["passes_per_epoch"] == 4 and first.stats["steps_per_epoch"] == 12
    assert not np.allclose(first.scene.reflectivity, other.scene.reflectivity)
    assert first.scene.shape == (3, 3, 3) and first.field is not None
    prediction = first.predict(test)
    assert prediction.signal.shape == (len(test), *radar.signal_shape)
    assert all(np.isfinite(v) for v in first.evaluate(scene, test).values())
    # resume: a run started from the first one's field (and barely moved) keeps its scene
    resumed = rj.fit(scene, train, seed=1, init=first.field, learning_rate=1e-9, **options)
    np.testing.assert_allclose(
        resumed.scene.reflectivity, first.scene.reflectivity, rtol=1e-3, atol=1e-4
    )


def test_paper_recipe_runs_with_a_fixed_gain(tiny):
    radar, scene, train, _ = tiny
    result = rj.fit(
        scene, train, radar=radar, method="rift-n", recipe="paper", epochs=2, progress=False
    )
    assert result.stats["recipe"]["loss"] == "paper" and result.stats["steps_per_epoch"] == 1
    assert result.stats["recipe"]["learning_rate"] == 1e-2
    # the gain stays 1 on the normalised data: in the scene's units it is the data's scale
    scale = rj.synthesize(scene, train, radar).scale
    assert complex(result.field.gain) == pytest.approx(scale, rel=1e-5)


@pytest.mark.slow  # an option, off by default
def test_a_least_squares_start_begins_at_its_image(tiny):
    """``init="fista"``: FISTA runs on the same operator and data, and the fresh INR is
    fitted to its image before training; with a tiny learning rate the result is that
    image. A wrong name, or a holdout the start would see, is refused."""
    radar, scene, train, _ = tiny
    common = dict(radar=radar, method="rift-n", granularity=0.5, support=None, progress=False)
    fista = rj.fit(scene, train, method="fista", radar=radar, granularity=0.5, support=None,
                   progress=False)  # fmt: skip
    started = rj.fit(scene, train, init="fista", epochs=2, learning_rate=1e-9, **common)
    warm = started.stats["warm_start"]
    assert warm["method"] == "fista" and warm["image_error"] < 0.1  # 0.06 measured
    assert warm["residual"] == pytest.approx(fista.history.residual.min(), rel=1e-4)
    image, ours = np.asarray(fista.scene.reflectivity), np.asarray(started.scene.reflectivity)
    assert np.linalg.norm(ours - image) < 0.1 * np.linalg.norm(image)
    assert started.stats["collapse"] is None  # a start need not descend: no "flat loss"
    with pytest.raises(ValueError, match="`init` must be a Field, one of"):
        rj.fit(scene, train, init="kaczmarz", epochs=2, **common)
    with pytest.raises(ValueError, match="holdout"):
        rj.fit(scene, train, init="lsmr", holdout=2, epochs=2, **common)


@pytest.mark.slow  # an option, off by default
def test_the_sparsity_prior_is_scale_free_and_joins_the_loss(tiny):
    """`concentration` is ‖ρ‖₁/(√k‖ρ‖₂) over live points of a field on k: 1 flat, 1/√k
    for one point, whatever the scale; ``sparsity`` adds it to the loss, and 0 leaves
    training as it was."""
    from rift_jax._solvers.inr.training import concentration

    flat = jnp.full(16, 3.0 - 2.0j)
    assert float(concentration(flat, None, 16)) == pytest.approx(1.0)
    one = jnp.zeros(16, jnp.complex64).at[3].set(5.0)
    assert float(concentration(one, None, 16)) == pytest.approx(0.25)
    assert float(concentration(10 * one, None, 16)) == pytest.approx(0.25)
    live = jnp.arange(16) < 4  # padding (not live) is left out, whatever it holds
    assert float(concentration(flat.at[5:].set(100.0), live, 4)) == pytest.approx(1.0)
    # an active set of 4 of 16 candidates: the field as if 0 on the other 12
    assert float(concentration(flat[:4], None, 16)) == pytest.approx(0.5)
    radar, scene, train, _ = tiny
    common = dict(radar=radar, method="rift-n", granularity=0.5, epochs=2, progress=False)
    plain = rj.fit(scene, train, **common)
    zero = rj.fit(scene, train, sparsity=0.0, **common)
    np.testing.assert_array_equal(plain.history.loss, zero.history.loss)
    prior = rj.fit(scene, train, sparsity=0.5, **common)
    assert prior.history.loss[0] > plain.history.loss[0]  # same start, a term more
    with pytest.raises(ValueError, match="sparsity"):
        rj.solvers.Recipe(sparsity=-0.1)


def test_bad_input(tiny):
    radar, scene, train, _ = tiny
    fit = dict(radar=radar, progress=False)
    cases = [
        (dict(method="rift-n", model="mlp"), "model"),
        (dict(method="rift-n", loss="l2"), "loss"),
        (dict(method="rift-n", recipe="fast"), "recipe"),
        (dict(method="rift-n", epochs=0), "epochs"),
        (dict(method="rift-n", learning_rate=0.0), "learning_rate"),
        (dict(method="rift-n", learning_rate=-1e-3), "learning_rate"),
        (dict(method="rift-n", batch_views=0), "batch_views"),
        (dict(method="rift-n", epoch=3), "epoch"),
        (dict(method="rift-s", init="field"), "init"),
        (dict(method="rift-s", init=rj.Field(rj.RiftN(key=jax.random.key(0)), 1.0)), "init"),
    ]
    for options, match in cases:
        with pytest.raises(ValueError, match=match):
            rj.fit(scene, train, **fit, **options)
    signal = rj.synthesize(scene, train, radar).signal
    with pytest.raises(ValueError, match="viewpoints"):
        rj.fit(
            signal[:-1], train, method="rift-n", extent=1.0, granularity=0.5, **fit
        )  # one signal short of the viewpoints
    with pytest.raises(ValueError, match="viewpoints"):
        rj.fit(
            rj.synthesize(scene, train[:4], radar),
            train,
            method="rift-n",
            extent=1.0,
            granularity=0.5,
            **fit,
        )
    with pytest.raises(ValueError, match="continuous"):
        rj.fit(scene, train, method="kaczmarz", iterations=1, **fit).render(0.25)


def test_patience_stops_a_converged_run_and_keeps_the_best(tiny):
    """With `patience`, a run whose loss has stopped improving ends early (`Outcome.CONVERGED`) at
    exactly the epoch a reference rule gives, keeps its best parameters, and equals the same
    run without it up to there. (A learning rate at which neither run collapses: a retry
    would restart the history at another seed.) It is on by default, but not in the paper's
    recipe."""
    assert rj.solvers.Recipe().patience == 10 and rj.solvers.RECIPES["paper"].patience is None
    radar, scene, train, _ = tiny
    common = dict(radar=radar, method="rift-n", granularity=0.5, progress=False)
    # the budget well past where it stops: on this exactly explainable problem the loss falls
    # by ≥ 1 % every few epochs for long (to epoch 92 with jax 0.10.2 on one CPU, before 60 on
    # others: training is chaotic at float32 rounding), and a budget that runs out first
    # ends it as BUDGET, not CONVERGED
    common |= dict(epochs=200, learning_rate=2.5e-2, epoch_views=None)
    full = rj.fit(scene, train, patience=None, **common)
    stopped = rj.fit(scene, train, patience=3, min_improvement=1e-2, **common)
    assert full.stats["remedies"] == stopped.stats["remedies"] == []

    def expected_stop(loss, patience=3, min_improvement=1e-2):
        reference, improved = np.inf, 0
        for epoch, value in enumerate(loss, start=1):
            if value < (1 - min_improvement) * reference:
                reference, improved = value, epoch
            if epoch - improved >= patience:
                return epoch
        return len(loss)

    run = stopped.stats["epochs_run"]
    assert stopped.stopped == rj.solvers.Stop(rj.solvers.Outcome.CONVERGED, run)
    assert run == expected_stop(full.history.loss) < 200
    np.testing.assert_array_equal(stopped.history.loss, full.history.loss[:run])
    loss = stopped.history.loss
    assert stopped.stats["best_epoch"] == int(np.argmin(loss)) + 1
    assert stopped.stats["best_loss"] == pytest.approx(loss.min())
    assert full.stopped == rj.solvers.Stop(rj.solvers.Outcome.BUDGET, 200)
    assert full.stats["epochs_run"] == 200
    with pytest.raises(ValueError, match="patience"):
        rj.solvers.Recipe(patience=0)


# -- active set and coarse to fine ---------------------------------------------------------


def test_an_active_set_of_every_point_changes_nothing(small_cube):
    """`prune` so low that every point stays active: the run is the unpruned one, exactly
    (the active set's GRT is the whole one, gathered)."""
    radar, scene, train, _ = small_cube
    common = dict(radar=radar, method="rift-n", granularity=0.5, epochs=12, progress=False)
    # every grid point, with and without an active set
    common |= dict(support=None, epoch_views=None)
    plain = rj.fit(scene, train, prune=None, **common)
    pruned = rj.fit(scene, train, prune=1e-12, recheck_every=5, **common)
    assert pruned.stats["active_points"] == plain.stats["active_points"] == 729
    np.testing.assert_array_equal(pruned.history.loss, plain.history.loss)
    np.testing.assert_array_equal(pruned.scene.reflectivity, plain.scene.reflectivity)


def test_a_padded_active_set_trains_as_the_set_itself(small_cube):
    """An active set is padded (ρ = 0 on copies of its first point) to a size that changes
    rarely, so that re-chosen sets of about the same size share one compiled step. The
    padded step's loss, gradient and update are the set's own, within float32 (without
    clipping, Adam's first moment after one step is 0.1 x the gradient itself)."""
    radar, scene, train, _ = small_cube
    operator = rj.grt_operator(radar, train, scene.points())
    candidates = Candidates(operator.fn, scene.points().astype(np.float64))
    active = np.sort(np.random.default_rng(0).choice(729, 50, replace=False))
    padded = candidates.restricted(active)
    assert padded.n_points == 56 and int(padded.fn.live.sum()) == 50
    assert candidates.restricted(active[:40], padded).n_points == 56  # fits, 2/3 full
    assert candidates.restricted(active[:30], padded).n_points == 32  # under 2/3: shrinks
    assert candidates.restricted(np.arange(720), padded).n_points == 729  # at most all
    # the work a smaller size would save, against a compilation's (COMPILE_WORK)
    assert candidates.restricted(active[:30], padded, point_cost=1.0).n_points == 56  # keeps
    assert candidates.restricted(active[:30], padded, point_cost=1e12).n_points == 32
    plain = eqx.tree_at(
        lambda p: (p.points, p.live),
        operator.fn,
        (jax.tree.map(lambda a: a[active], operator.fn.points), operator.fn.live[active]),
    )
    plain = StepPoints(plain, jnp.asarray(scene.points()[active], jnp.float32))
    field = rj.Field(rj.RiftN(width=16, depth=2, key=jax.random.key(0)), extent=2.0, gain=3.0)
    params, static = eqx.partition(field, eqx.is_inexact_array)
    recipe = rj.solvers.Recipe(learning_rate=1e-2, clip_norm=None)
    optimizer, state = optimizer_for(recipe, 3, params)
    signal = jnp.asarray(rj.synthesize(scene, train, radar).signal)
    common = (params, state, static, optimizer, rj.losses.robust_loss)
    ours, theirs = (_step(*common, p, signal, jnp.arange(10)) for p in (padded, plain))
    for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(theirs), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-7)
    mu = ours[1].inner_state[0].mu  # AdamW's first moment: 0.1 x the gradient
    assert any(np.any(np.asarray(m) != 0) for m in jax.tree.leaves(mu))


def test_pruning_trains_the_scene_on_fewer_points(small_cube, caplog):
    """On exact data, the active set shrinks to the cube and its neighbours, the result is
    zero elsewhere (that is what was trained), and it scores as the unpruned run does, both
    given every epoch (with the default `patience` the unpruned run scored 0.80). On a
    problem this small a smaller set would save less work than a compilation costs
    (`COMPILE_WORK`), so every set keeps the candidates' size and the pruned run compiles no
    step of its own."""
    radar, scene, train, test = small_cube
    common = dict(radar=radar, method="rift-n", granularity=0.5, epochs=160, progress=False)
    common |= dict(patience=None, support=None, epoch_views=None)
    plain = rj.fit(scene, train, prune=None, **common)
    pruned = None

    def prune():
        nonlocal pruned
        pruned = rj.fit(scene, train, prune=0.05, recheck_every=20, **common)
        return pruned.scene.reflectivity

    assert not [m for m in compilations(caplog, prune) if "jit(_step)" in m]
    assert pruned.stats["step_sizes"] == plain.stats["step_sizes"] == [729]
    active = pruned.stats["active_points"]
    assert 27 < active < 300  # the 27 voxels of the cube, and some of their neighbours
    assert np.count_nonzero(np.asarray(pruned.scene.reflectivity)) <= active
    a, b = plain.evaluate(scene, test), pruned.evaluate(scene, test)
    # both recover the cube, the pruned run no worse (jax 0.10.2: unpruned 0.89, pruned 0.99;
    # earlier versions: both above 0.9)
    assert a["m_ssim"] > 0.85 and b["m_ssim"] > a["m_ssim"] - 0.05
    with pytest.raises(ValueError, match="prune"):
        rj.solvers.Recipe(prune=1.0)
    with pytest.raises(ValueError, match="recheck_every"):
        rj.solvers.Recipe(recheck_every=0)


@pytest.mark.slow  # an option (`train_granularity`), off by default
def test_coarse_to_fine_explains_what_the_coarse_grid_cannot():
    """docs/rift.md's coarse-to-fine example, as written: data made on a 0.5 m grid, inverse
    grid 1 m. Trained on the inverse grid alone the field cannot explain them; its last
    epochs on the 0.5 m points can. `scene` stays on the inverse grid, and `predict`
    synthesises from `trained`."""
    run = run_docs_block("rift.md", 1)
    radar, scene, train, test = run["radar"], run["scene"], run["train"], run["test"]
    coarse, fine, common = run["coarse"], run["fine"], run["options"]
    assert coarse.trained is None and fine.trained.shape == (9, 9, 9)
    assert fine.scene.shape == coarse.scene.shape == (5, 5, 5)
    assert fine.stats["fine_from_epoch"] == 6 and fine.stats["active_points"] < 729
    # the fine stage's last epochs wander with float32 rounding: its residual ended at 0.013,
    # 0.021 and 0.063 (p-RMSE 0.036-0.088 rad) on 4, 2 and 1 devices; the coarse one stays
    # above 0.5 (and 1 rad)
    assert fine.evaluate(scene, test)["p_rmse"] < 0.2 < 1.0 < coarse.evaluate(scene, test)["p_rmse"]
    assert fine.residual < 0.1 < 0.5 < coarse.residual
    # fit's checks read what was trained, on its points: the fine stage explains the data
    assert fine.stats["data_residual"] < 0.1 < 0.5 < coarse.stats["data_residual"]
    # its sharp field scores a low cos(|ρ|, |Aᴴy|) (0.55), which warns only where the
    # data are not explained (test_fit.py: test_failed_fit_warnings_name_the_cause)
    expected = rj.synthesize(fine.trained, test, radar).signal
    np.testing.assert_array_equal(fine.predict(test).signal, expected)
    with pytest.raises(ValueError, match="train_granularity"):
        rj.fit(scene, train, train_granularity=-0.5, **common)
    with pytest.raises(ValueError, match="fine_epochs"):
        rj.fit(scene, train, train_granularity=0.5, fine_epochs=80, **common)
    with pytest.raises(ValueError, match="takes no option"):
        rj.fit(scene, train, method="points", granularity=1.0, train_granularity=0.5)


@pytest.mark.slow  # an option (`train_granularity`), off by default
def test_coarse_to_fine_on_a_support_after_patience_and_a_coarse_divergence(small_cube):
    """Patience ends the coarse stage early and the fine one gets its own epochs; on a
    support, only fine points inside it are trained. A loss that turns NaN once the
    prediction's energy moves off the data's (it starts on it: the gain is initialised so)
    stops at epoch 2, before the fine stage, and keeps epoch 1's coarse field and no fine
    one."""
    radar, scene, train, _ = small_cube
    support = np.zeros((5, 5, 5), bool)
    support[1:4, 1:4, 1:4] = True  # the cube's voxels on the 1 m grid and a margin
    common = dict(radar=radar, method="rift-n", granularity=1.0, epoch_views=None, progress=False)
    result = rj.fit(
        scene, train, support=support, train_granularity=0.5, epochs=400, fine_epochs=20,
        patience=3, learning_rate=1e-1, **common,
    )  # fmt: skip
    switch = result.stats["fine_from_epoch"]
    assert switch < 381 and result.stats["epochs_run"] <= switch - 1 + 20
    inside = mask_at(support, result.scene, result.trained.points()).reshape(9, 9, 9)
    trained = np.asarray(result.trained.reflectivity) != 0
    assert trained.any() and not np.any(trained & ~inside)

    def fragile(pred, target):  # NaN once the prediction's energy leaves the data's
        drift = jnp.abs(jnp.sum(jnp.abs(pred) ** 2) / jnp.sum(jnp.abs(target) ** 2) - 1)
        return rj.losses.robust_loss(pred, target) + jnp.where(drift > 1e-2, jnp.nan, 0.0)

    diverged = r"at epoch 2, the loss was nan in step 1 of 1"
    with pytest.raises(rj.solvers.Diverged, match=diverged) as error:
        rj.fit(
            scene, train, train_granularity=0.5, epochs=10, loss=fragile, batch_views=None,
            learning_rate=0.1, **common,
        )  # fmt: skip
    assert isinstance(error.value, ValueError)
    result = error.value.result
    assert result.trained is None and "fine_from_epoch" not in result.stats
    assert result.stats["best_epoch"] == 1 and len(result.history.loss) == 1
    assert result.stopped == rj.solvers.Stop(rj.solvers.Outcome.DIVERGED, 2)
    assert result.field is not None
    # the kept parameters are those whose loss was measured finite (epoch 1's, before its
    # update), not the ones that then gave NaN
    data = rj.synthesize(scene, train, radar)
    pred = rj.synthesize(result.scene, train, radar)
    kept = fragile(jnp.asarray(pred.signal * pred.scale / data.scale), jnp.asarray(data.signal))
    assert np.isfinite(float(kept))


@pytest.mark.slow  # what compiles, not what it computes
def test_fields_of_any_extent_train_with_one_compiled_step(tiny, caplog):
    """The step trains the field on coordinates already divided by its extent (the extent
    is a static field of `Field`, so it would key the compilation): fits of other extents
    share one compiled step. The division is the one `Field` makes, bit for bit, so the
    returned field predicts what training measured (here the held-out residual, at an
    extent that is not a power of two)."""
    radar, scene, train, _ = tiny
    operator = rj.grt_operator(radar, train, scene.points())
    signal = jnp.asarray(rj.synthesize(scene, train, radar).signal)
    common = dict(epochs=3, holdout=4, patience=None, progress=False)
    rj.solvers.rift(operator, signal, extent=1.0, **common)
    assert_compilations_are_logged(caplog)
    solution = None

    def other_extent():
        nonlocal solution
        solution = rj.solvers.rift(operator, signal, extent=1.5, **common)
        return solution.rho

    assert not [m for m in compilations(caplog, other_extent) if "jit(_step)" in m]
    field = solution.field
    assert field.extent == 1.5
    held = np.asarray(solution.stats["holdout_views"])
    pred = np.asarray(operator.fn(field.render(jnp.asarray(scene.points(), jnp.float32))))
    target = np.asarray(signal)[held]
    recomputed = np.linalg.norm(pred[held] - target) / np.linalg.norm(target)
    assert recomputed == pytest.approx(solution.stats["best_loss"], rel=1e-5)
    # the coordinates the step renders at are those `Field` divides, to the bit (at points
    # off the grid: x / 1.5 and x · float32(1 / 1.5) differ in the last bit for a third of
    # them, and agree at every point of `tiny`'s grid)
    points = np.random.default_rng(0).uniform(-1.5, 1.5, (scene.points().shape[0], 3))
    coords = Candidates(operator.fn, points, 1.5).coords
    np.testing.assert_array_equal(
        np.asarray(on_extent(field, 1.0).render(coords)), np.asarray(field.render(points))
    )


@pytest.mark.slow  # an option, off by default
def test_holdout_views_are_never_trained_on_and_choose_the_best(small_cube):
    """With ``holdout``, training is the run on the other views exactly; the held-out
    residual is recorded per epoch and picks the best epoch and the stop."""
    radar, scene, train, _ = small_cube
    common = dict(radar=radar, method="rift-n", granularity=0.5, epochs=12, progress=False)
    common |= dict(epoch_views=None)
    held = rj.fit(scene, train, holdout=4, patience=None, **common)  # every epoch, both
    views = held.stats["holdout_views"]
    assert views == [0, 10, 19, 29]
    others = train[np.setdiff1d(np.arange(len(train)), views)]
    data = rj.synthesize(scene, train, radar)  # the same normalisation as `held`'s
    alone = rj.fit(
        rj.RadarData(data.signal[np.setdiff1d(np.arange(30), views)], data.scale, others, radar),
        others, extent=2.0, patience=None, **common,
    )  # fmt: skip
    np.testing.assert_array_equal(held.history.loss, alone.history.loss)
    residual = held.stats["holdout_residual"]
    assert len(residual) == 12 and residual[-1] < residual[0]
    assert held.stats["best_epoch"] == int(np.argmin(residual)) + 1
    assert held.stats["best_loss"] == pytest.approx(min(residual))
    stopped = rj.fit(scene, train, holdout=4, patience=1, min_improvement=0.5, **common)
    assert stopped.stopped.outcome is rj.solvers.Outcome.CONVERGED
    assert stopped.stats["epochs_run"] < 12
    with pytest.raises(ValueError, match="holdout"):
        rj.fit(scene, train, holdout=30, **common)
    with pytest.raises(ValueError, match="holdout"):
        rj.solvers.Recipe(holdout=-1)
