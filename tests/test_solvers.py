"""Every solver against float64 least squares on a tiny problem, plus their contracts."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import (
    assert_compilations_are_logged,
    compilations,
    random_complex,
    relative_error,
)

import rift_jax as rj
from rift_jax import solvers
from rift_jax._solvers._common import as_complex, as_pair, realified
from rift_jax._solvers._solution import Patience, Record, iterate

RUNS = {
    "kaczmarz": (solvers.kaczmarz, {"iterations": 150, "tol": 0.0}, 5e-3),
    "lsmr": (solvers.lsmr, {"iterations": 60, "tol": 0.0}, 1e-4),
    "gauss-newton": (solvers.gauss_newton, {"iterations": 3, "inner": 20, "tol": 0.0}, 1e-4),
    "fista": (solvers.fista, {"iterations": 150, "sparsity": 0.0, "tol": 0.0}, 1e-3),
}


@pytest.fixture(scope="module")
def problem(tiny):
    """30 viewpoints x 128 samples of a 125-voxel random scene: overdetermined and
    well-conditioned, so least squares recovers ρ; the reference is float64 NumPy lstsq.
    `tiny`'s radar, viewpoints and grid, so that the solvers' programs are those its fits
    compile."""
    radar, scene, viewpoints, _ = tiny
    operator = rj.grt_operator(radar, viewpoints, scene.points())
    rho = random_complex(np.random.default_rng(1), operator.fn.n_points)
    signal = np.asarray(operator.mv(jnp.asarray(rho)))
    matrix = np.asarray(operator.as_matrix(), np.complex128)
    reference = np.linalg.lstsq(matrix, signal.ravel().astype(np.complex128), rcond=None)[0]
    return operator, signal, reference


@pytest.fixture(scope="module")
def solutions(problem):
    operator, signal, _ = problem
    return {name: f(operator, signal, progress=False, **kw) for name, (f, kw, _) in RUNS.items()}


@pytest.mark.parametrize("name", RUNS)
def test_agrees_with_float64_lstsq(problem, solutions, name):
    _, _, reference = problem
    assert relative_error(solutions[name].rho, reference) < RUNS[name][2]


@pytest.mark.parametrize("name", RUNS)
def test_history(solutions, name):
    solution = solutions[name]
    history = solution.history
    assert solution.stopped.outcome is rj.solvers.Outcome.BUDGET
    assert len(history) == history.seconds.shape[0] > 1
    assert np.all(np.diff(history.seconds) > 0)
    assert history.residual[-1] < 1e-2 * history.residual[0]
    assert solution.rho.dtype == jnp.complex64


def test_history_lengths(solutions):
    assert len(solutions["kaczmarz"].history) == 150  # sweeps
    assert len(solutions["lsmr"].history) == 6  # checks, every 10 LSMR steps
    assert solutions["lsmr"].stopped.at == 60  # `stopped` counts LSMR steps, not checks
    assert len(solutions["gauss-newton"].history) == 3


def test_lsmr_checked_at_another_interval_compiles_nothing(problem, solutions, caplog):
    """LSMR's segment length is traced: a run checked every 3 steps reuses the program of
    the runs checked every 10, and each segment runs the 3 steps it asks for (its first
    residual is SciPy's float64 LSMR's after 3 steps, not after 2 or 4)."""
    from scipy.sparse.linalg import lsmr as scipy_lsmr

    operator, signal, _ = problem
    run = {}

    def lsmr():
        run["solution"] = solvers.lsmr(
            operator, signal, iterations=6, check_every=3, tol=0.0, progress=False
        )
        return run["solution"].rho

    assert_compilations_are_logged(caplog)
    assert not [m for m in compilations(caplog, lsmr) if m.startswith("Compiling jit(_segment)")]
    first = run["solution"].history.residual[0]
    matrix = np.asarray(operator.as_matrix(), np.complex128)
    y = np.asarray(signal).ravel().astype(np.complex128)

    def after(steps):
        x = scipy_lsmr(matrix, y, atol=0, btol=0, conlim=0, maxiter=steps)[0]
        return np.linalg.norm(y - matrix @ x) / np.linalg.norm(y)

    assert first == pytest.approx(after(3), rel=1e-3)
    assert abs(first - after(2)) > 1e-2 * first and abs(first - after(4)) > 1e-2 * first


def test_one_loop_one_stopping_rule():
    """`iterate`'s `Patience` measures progress from the last iteration that made enough of
    it (small steps cannot keep resetting the bar); a `Record` may judge the best by its
    own measure; a ``fresh`` record restarts the best and the patience, and ``then`` may go
    on after a stop (RIFT's coarse-to-fine stages)."""

    def run(values, **kwargs):
        def step(k):
            return k + 1, values[k]

        return iterate(step, 0, iterations=len(values), progress=False, desc="t",
                       image=lambda k: k, **kwargs)  # fmt: skip

    # improves at 1, 2 and 3 (by ≥ 1 % of the last improvement's value); 4-6 creep by
    # 0.25 % each: 6 − 3 = 3 iterations without enough progress
    creeping = [1.0, 0.5, 0.4, 0.399, 0.398, 0.397, 0.1]
    best, history, stopped, stats = run(creeping, until=Patience(3, 0.01))
    assert stopped == rj.solvers.Stop(rj.solvers.Outcome.CONVERGED, 6)
    assert len(history) == 6 and stats == {"best": 5} and best == 6
    assert run(creeping, until=None).stopped.outcome is rj.solvers.Outcome.BUDGET
    assert Patience.from_tol(0) is None and Patience.from_tol(1e-3) == Patience(3, 1e-3)
    # a measure of its own picks the best, whatever the residual; a fresh stage restarts
    # both the best (a worse measure wins) and the patience
    records = [Record(1.0, measure=m, at=f"at {k}", fresh=k == 3) for k, m in enumerate(
        [5.0, 4.0, 4.0, 9.0, 9.0, 9.0, 9.0])]  # fmt: skip
    best, history, stopped, stats = run(records, until=Patience(2, 0.0))
    assert best == "at 3" and stats == {"best": 3}  # epoch 4's, worse than 4.0 before it
    assert stopped.at == 6 and history.loss is None
    # `then` is asked when the rule stops, and may give more iterations (here 2, which
    # then run out: the budget ends the run)
    asked = []

    def then(carry, k):
        asked.append(k)
        return carry, 2

    extended = run(creeping * 2, until=Patience(3, 0.01), then=then)
    assert asked == [6] and extended.stopped == rj.solvers.Stop(rj.solvers.Outcome.BUDGET, 8)
    assert len(extended.history) == 8 and extended.best == 7  # 0.1, in the extension


def test_patience_measures_progress_above_the_noise_floor():
    """With a ``floor`` (what a perfect fit leaves: the noise's share of a loss), progress
    is counted on the part above it. Steps of 0.1 % of the loss are ~1.1 % of what lies
    above a floor of 0.909 (data at -10 dB): they go on, where without the floor they
    stop. At or below the floor nothing counts: descent there only fits the noise."""

    def run(values, until):
        def step(k):
            return k + 1, values[k]

        return iterate(step, 0, iterations=len(values), progress=False, desc="t",
                       image=lambda k: k, until=until)  # fmt: skip

    noisy = [1.0 - 0.001 * k for k in range(12)]
    assert run(noisy, Patience(3, 0.01)).stopped.at == 4  # progress only at the first
    budget = rj.solvers.Outcome.BUDGET
    assert run(noisy, Patience(3, 0.01, floor=0.909)).stopped.outcome is budget
    into_the_noise = [1.0, 0.8, 0.6, 0.5, 0.45, 0.4, 0.3, 0.2]
    stopped = run(into_the_noise, Patience(2, 0.01, floor=0.5)).stopped
    # reaching the floor is the last progress (iteration 4); two more end the run
    assert stopped == rj.solvers.Stop(rj.solvers.Outcome.CONVERGED, 6)
    assert Patience(2, 0.01).progressed(0.4, 0.5) and not Patience(2, 0.01).progressed(0.5, 0.5)


def test_tolerance_stops_early(problem):
    operator, signal, _ = problem
    solution = solvers.lsmr(
        operator, signal, iterations=200, check_every=10, tol=0.5, progress=False
    )  # checks every 10 steps, as the `solutions` runs do: the same compiled segment
    assert solution.stopped.outcome is rj.solvers.Outcome.CONVERGED
    assert len(solution.history) < 200 // 10  # one entry per check: stopped before the budget
    assert solution.stopped.at == 10 * len(solution.history)  # in LSMR steps
    seen = []  # the monitor counts LSMR steps too, as `stopped` does
    solvers.lsmr(
        operator,
        signal,
        iterations=30,
        tol=0.0,
        progress=False,
        monitor=lambda k, *_: seen.append(k),
    )
    assert seen == [10, 20, 30]


def test_kaczmarz_seeded(problem):
    operator, signal, _ = problem

    def run(seed):
        return solvers.kaczmarz(operator, signal, iterations=2, seed=seed, progress=False)

    a, b, c = run(0), run(0), run(1)
    np.testing.assert_array_equal(a.rho, b.rho)
    assert not np.array_equal(a.rho, c.rho)


def test_kaczmarz_resumes_from_x0(problem):
    """From ``x0`` the line search starts from that ρ's own residual: the residuals it
    reports are those of its iterates, measured here independently."""
    operator, signal, _ = problem
    first = solvers.kaczmarz(operator, signal, iterations=3, progress=False)
    more = solvers.kaczmarz(operator, signal, iterations=3, x0=first.rho, seed=1, progress=False)
    assert more.history.residual[0] < first.history.residual[-1]
    direct = np.linalg.norm(signal - np.asarray(operator.mv(more.rho))) / np.linalg.norm(signal)
    assert more.history.residual[-1] == pytest.approx(direct, rel=1e-3)


def test_fista_sparsity_and_nonnegativity(problem):
    operator, signal, _ = problem
    sparse = solvers.fista(operator, signal, iterations=30, sparsity=0.5, progress=False)
    dense = solvers.fista(operator, signal, iterations=30, sparsity=0.0, progress=False)
    assert np.sum(np.abs(sparse.rho) > 0) < np.sum(np.abs(dense.rho) > 0)
    positive = solvers.fista(operator, signal, iterations=10, nonnegative=True, progress=False)
    assert np.all(np.imag(positive.rho) == 0) and np.all(np.real(positive.rho) >= 0)
    assert positive.stats["lambda"] > 0


def test_fista_keeps_no_point_that_known_noise_could_have_made(problem):
    """Given the noise's σ, λ is at least max|Aᴴn| for a seeded draw n of that noise (by
    hand, float64 on the operator's matrix), and the draw has E|n|² = σ². On noise whose
    backprojection stays below the draw's (here the draw itself, scaled by 0.9) the result
    is ρ = 0, where FISTA without σ fits the noise; σ = 0 is σ unknown."""
    from rift_jax._solvers.sparse import _noise_draw

    operator, signal, _ = problem
    sigma = float(np.sqrt(np.mean(np.abs(signal) ** 2)))  # 0 dB
    draw = np.asarray(_noise_draw(signal.shape, sigma, seed=0), np.complex128)
    noise = (0.9 * draw).astype(np.complex64)
    known = solvers.fista(operator, noise, noise=sigma, iterations=30, progress=False)
    unknown = solvers.fista(operator, noise, iterations=30, progress=False)
    assert np.all(np.asarray(known.rho) == 0) and np.linalg.norm(unknown.rho) > 0
    assert np.mean(np.abs(draw) ** 2) == pytest.approx(sigma**2, rel=0.05)  # 3,840 samples
    matrix = np.asarray(operator.as_matrix(), np.complex128)
    by_hand = np.abs(matrix.conj().T @ draw.ravel()).max()
    assert known.stats["noise_lambda"] == pytest.approx(by_hand, rel=1e-4)
    # on the scene's own signal: λ is the larger of the two floors, and without σ no floor
    fixed = dict(sparsity=0.05, iterations=5, progress=False)
    with_noise = solvers.fista(operator, signal, noise=sigma, **fixed)
    plain = solvers.fista(operator, signal, **fixed)
    expected = max(with_noise.stats["noise_lambda"], plain.stats["lambda"])
    assert with_noise.stats["lambda"] == pytest.approx(expected, rel=1e-6)
    unknown_zero = solvers.fista(operator, signal, noise=0.0, **fixed)
    np.testing.assert_array_equal(unknown_zero.rho, plain.rho)
    assert "noise_lambda" not in plain.stats | unknown_zero.stats
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="`noise`"):
            solvers.fista(operator, signal, noise=bad, progress=False)


def test_fista_chooses_its_lambda_on_held_out_views(problem):
    """``sparsity="auto"``: the path's record holds the held-out views (a fifth, evenly
    spread) and each λ tried, densest last, each scored by its prediction of them; the
    chosen sparsity predicts them best, and the result is
    exactly that of a fixed ``sparsity`` at it (the final solve starts afresh). On data
    its own grid explains exactly, denser is better all the way down the path."""
    from rift_jax import _holdout
    from rift_jax._solvers.sparse import SPARSITIES, UNSPLIT

    operator, signal, _ = problem
    auto = solvers.fista(operator, signal, iterations=20, progress=False)
    path = auto.stats["sparsity_path"]
    assert path["views"] == _holdout.split(operator.fn.n_views)[1].tolist()
    assert len(path["views"]) == 6
    scores = {float(k): v for k, v in path["scores"].items()}
    assert list(scores) == list(SPARSITIES)  # held-out residual falls all the way
    residuals = [v["holdout_residual"] for v in scores.values()]
    assert residuals == sorted(residuals, reverse=True)
    assert auto.stats["sparsity"] == min(scores, key=lambda k: scores[k]["holdout_residual"])
    assert auto.stats["sparsity"] == SPARSITIES[-1]
    fixed = solvers.fista(operator, signal, iterations=20, sparsity=SPARSITIES[-1], progress=False)
    np.testing.assert_array_equal(auto.rho, fixed.rho)
    assert auto.stats["lambda"] == fixed.stats["lambda"]
    # too few views to hold any out: the fixed fallback, and no path
    few = rj.GRTOperator(operator.fn.subset(np.arange(4)))
    alone = solvers.fista(few, signal[:4], iterations=5, progress=False)
    assert alone.stats["sparsity"] == UNSPLIT and "sparsity_path" not in alone.stats
    with pytest.raises(ValueError, match="`sparsity`"):
        solvers.fista(operator, signal, sparsity="best", progress=False)


def test_fistas_path_stops_two_past_its_best_and_keeps_the_sparser_on_a_tie(problem, monkeypatch):
    """The path ends once two λ in a row predict the held-out views worse than the best so
    far (`_PAST_BEST`), and of equal held-out residuals the sparser λ is chosen. The
    scores are stand-ins, in the path's order (a V, and a tie at its bottom)."""
    from rift_jax import _holdout
    from rift_jax._solvers import sparse

    operator, signal, _ = problem
    real = _holdout.score
    for residuals, tried, chosen in [
        ([0.9, 0.8, 0.7, 0.75, 0.76, 0.5], [0.5, 0.3, 0.2, 0.1, 0.05], 0.2),
        ([0.9, 0.8, 0.8, 0.85, 0.9, 0.5], [0.5, 0.3, 0.2, 0.1, 0.05], 0.3),
    ]:
        given = iter(residuals)

        def scored(predicted, signal, failure=None, given=given):
            return real(predicted, signal, failure) | {"holdout_residual": next(given)}

        monkeypatch.setattr(sparse._holdout, "score", scored)
        result = solvers.fista(operator, signal, iterations=3, progress=False)
        assert [float(s) for s in result.stats["sparsity_path"]["scores"]] == tried
        assert result.stats["sparsity"] == chosen


def test_a_monitor_that_stops_fistas_path_starts_the_final_solve_from_the_best_lambda(
    problem, monkeypatch
):
    """A monitor sees the path's solves (each counting its iterations from 1); one that
    stops the third λ's solve ends the path there, and the final solve starts from the
    image of the best λ so far (the second, by stand-in scores), not from the last one."""
    from rift_jax import _holdout
    from rift_jax._solvers import sparse

    operator, signal, _ = problem
    real_score, real_minimize = _holdout.score, sparse._minimize
    given = iter([0.9, 0.7, 0.8])
    starts, images = [], []

    def scored(predicted, signal, failure=None):
        return real_score(predicted, signal, failure) | {"holdout_residual": next(given)}

    def minimize(fn, signal, x, lam, **options):
        starts.append(np.asarray(x))
        out = real_minimize(fn, signal, x, lam, **options)
        images.append(np.asarray(out[0]))
        return out

    monkeypatch.setattr(sparse._holdout, "score", scored)
    monkeypatch.setattr(sparse, "_minimize", minimize)
    calls = []

    def monitor(iteration, seconds, current):
        calls.append(iteration)
        return len(calls) >= 7  # the third λ's first step, and the final solve's

    result = solvers.fista(operator, signal, iterations=3, tol=0, monitor=monitor, progress=False)
    assert calls == [1, 2, 3, 1, 2, 3, 1, 1]
    path = result.stats["sparsity_path"]
    assert path["stopped"] and [float(s) for s in path["scores"]] == [0.5, 0.3, 0.2]
    assert result.stats["sparsity"] == 0.3
    np.testing.assert_array_equal(starts[-1], images[1])  # the 0.3 image, not the 0.2 one
    assert not np.array_equal(images[1], images[2])
    assert result.stopped == rj.solvers.Stop(rj.solvers.Outcome.STOPPED, 1)


def test_fistas_held_out_lambda_beats_the_fixed_one_on_two_grids(small_cube):
    """Under the two-grid protocol (the small cube's data, reconstructed on fit's grid
    twice as coarse) much of the data is unexplainable, like noise: the fixed λ (0.05 of
    max|Aᴴy|) keeps a haze of points, and λ chosen on held-out views is sparser and far
    closer to the truth (measured: sparsity 0.3, m-COS 0.623 → 0.896, m-SSIM
    0.147 → 0.416)."""
    radar, scene, train, test = small_cube
    options = dict(radar=radar, method="fista", progress=False)
    auto = rj.fit(scene, train, **options)
    fixed = rj.fit(scene, train, sparsity=0.05, **options)
    assert auto.stats["sparsity"] >= 0.2
    ours, theirs = (r.evaluate(scene, test) for r in (auto, fixed))
    assert ours["m_cos"] > theirs["m_cos"] + 0.2 and ours["m_ssim"] > theirs["m_ssim"] + 0.2


def test_fistas_path_tries_the_lambdas_under_the_noise_floor_once(problem):
    """Where the noise's floor on λ is above some of the path's λ, those are one candidate,
    sparsity 0 (λ at the floor, tried last); chosen, the final λ is the whole data's floor.
    Above all of them, no path is solved."""
    from rift_jax._solvers.sparse import _noise_draw

    operator, signal, _ = problem
    sigma = 3 * float(np.sqrt(np.mean(np.abs(signal) ** 2)))  # about −10 dB
    noisy = signal + np.asarray(_noise_draw(signal.shape, sigma, seed=5))
    result = solvers.fista(operator, noisy, noise=sigma, iterations=20, progress=False)
    scores = result.stats["sparsity_path"]["scores"]
    assert list(scores) == ["0.5", "0.0"]  # the floor is above 0.3 of max|Aᴴy| here
    lams = [v["lambda"] for v in scores.values()]
    assert lams == sorted(lams, reverse=True) and len(set(lams)) == len(lams)
    floor = scores["0.0"]["lambda"]
    assert all(v["lambda"] > floor for k, v in scores.items() if k != "0.0")
    assert result.stats["sparsity"] == 0.0  # here the floor predicts the held-out views best
    assert result.stats["lambda"] == result.stats["noise_lambda"]
    # a floor above every λ of the path leaves nothing to choose: no path is solved
    louder = 30 * sigma
    drowned = signal + np.asarray(_noise_draw(signal.shape, louder, seed=5))
    alone = solvers.fista(operator, drowned, noise=louder, iterations=5, progress=False)
    assert alone.stats["sparsity"] == 0.0 and "sparsity_path" not in alone.stats
    assert alone.stats["lambda"] == alone.stats["noise_lambda"]


def test_realified_operator_transposes_to_the_adjoint(problem, rng):
    """The (Re, Im) map optimistix sees transposes (real inner product) to Aᴴ."""
    operator, signal, _ = problem
    apply = realified(operator.fn)
    x = as_pair(jnp.asarray(random_complex(rng, operator.fn.n_points)))
    y = as_pair(jnp.asarray(random_complex(rng, *signal.shape)))
    (back,) = jax.linear_transpose(apply, x)(y)
    np.testing.assert_allclose(
        as_complex(back), operator.fn.adjoint(as_complex(y)), rtol=1e-5, atol=1e-9
    )
    ax = apply(x)
    lhs = np.sum(ax[0] * y[0] + ax[1] * y[1])
    rhs = np.sum(x[0] * back[0] + x[1] * back[1])
    assert abs(lhs - rhs) < 1e-5 * abs(lhs)


@pytest.mark.parametrize("name", RUNS)
def test_zero_signal_gives_zero_with_warning(problem, name):
    operator, signal, _ = problem
    f, kw, _ = RUNS[name]
    with pytest.warns(UserWarning, match="all zero"):
        solution = f(operator, np.zeros_like(signal), progress=False, **kw)
    assert solution.stopped.outcome is rj.solvers.Outcome.ZERO_SIGNAL
    assert not np.any(solution.rho)


@pytest.mark.parametrize("name", RUNS)
def test_bad_signal(problem, name):
    operator, signal, _ = problem
    f = RUNS[name][0]
    bad = signal.copy()
    bad[0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="`signal` must be finite"):
        f(operator, bad, progress=False)
    with pytest.raises(ValueError, match=r"`signal` must have shape \(30, 8, 4, 4\)"):
        f(operator, signal[:-1], progress=False)
    with pytest.raises(ValueError, match="`iterations` must be a positive integer"):
        f(operator, signal, iterations=0, progress=False)
    with pytest.raises(ValueError, match="`operator` must be the GRTOperator"):
        f(operator.transpose(), signal, progress=False)


def test_bad_options(problem):
    operator, signal, _ = problem
    with pytest.raises(ValueError, match="`relaxation` must be in"):
        solvers.kaczmarz(operator, signal, relaxation=2.0)
    with pytest.raises(ValueError, match="`sparsity` must be in"):
        solvers.fista(operator, signal, sparsity=1.0)
    with pytest.raises(ValueError, match="`check_every`"):
        solvers.lsmr(operator, signal, check_every=0)
    with pytest.raises(ValueError, match="`x0` must be"):
        solvers.lsmr(operator, signal, x0=np.zeros(3))


def test_no_warnings_from_jaxopt_import():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        import importlib

        import rift_jax._solvers.sparse as sparse

        importlib.reload(sparse)


@pytest.fixture(scope="module")
def inconsistent(problem):
    """The tiny problem's signal plus as much again that no scene on the grid explains
    (random numbers): no ρ fits it, and a Kaczmarz block step fits mostly noise."""
    operator, signal, _ = problem
    noise = random_complex(np.random.default_rng(7), signal.size).reshape(signal.shape)
    noise *= np.linalg.norm(signal) / np.linalg.norm(noise)
    return operator, (signal + noise).astype(np.complex64)


@pytest.mark.parametrize("name", RUNS)
def test_returns_its_best_iterate_never_worse_than_zero(inconsistent, name):
    """Every least-squares solver returns the iterate with the lowest residual in its
    history, that residual is the returned ρ's own (measured here independently), and it is
    below the zero image's 1."""
    operator, signal = inconsistent
    solve, options, _ = RUNS[name]
    options = options | {"iterations": 12}
    solution = solve(operator, signal, progress=False, **options)
    direct = np.linalg.norm(signal - np.asarray(operator.mv(solution.rho)))
    direct /= np.linalg.norm(signal)
    best = solution.stats["best"]
    assert best is not None
    assert solution.history.residual[best] == pytest.approx(direct, rel=1e-3)
    assert direct == pytest.approx(solution.history.residual.min(), rel=1e-3)
    assert direct < 1.0


def test_kaczmarz_keeps_each_sweep_as_far_as_it_helps(inconsistent):
    """At λ = 1 a sweep over inconsistent data overshoots, and the line search keeps the
    point of its segment with the lowest residual (t < 1, measured here independently
    against points either side); the history only goes down, and the next sweep's λ is
    λ·t, at least half and at most all of this one's."""
    operator, signal = inconsistent

    def residual(rho):
        return np.linalg.norm(signal - np.asarray(operator.mv(rho))) / np.linalg.norm(signal)

    one = solvers.kaczmarz(operator, signal, iterations=1, relaxation=1.0, tol=0, progress=False)
    (t,) = one.stats["steps"]
    end = np.asarray(one.rho) / t  # from ρ = 0, the kept point is t times the sweep's end
    assert 0 < t < 1, "λ = 1 was expected to overshoot on this data"
    at = {s: residual(s * end) for s in (0.9 * t, t, 1.1 * t)}
    assert at[t] < min(at[0.9 * t], at[1.1 * t])
    assert one.history.residual[0] == pytest.approx(at[t], rel=1e-4)

    solution = solvers.kaczmarz(operator, signal, iterations=8, relaxation=1.0, progress=False)
    relaxations, steps = solution.stats["relaxations"], solution.stats["steps"]
    assert len(relaxations) == len(steps) == len(solution.history.residual)
    assert relaxations[0] == 1.0 and steps[0] == t  # the same first sweep
    for k in range(1, len(steps)):
        expected = relaxations[k - 1] * min(max(steps[k - 1], 0.5), 1.0)
        assert relaxations[k] == pytest.approx(expected, rel=1e-6)
    assert relaxations[-1] < 1.0
    assert np.all(np.diff(solution.history.residual) <= 0)
    assert solution.history.residual[-1] == pytest.approx(residual(solution.rho), rel=1e-4)


def test_fista_tracks_its_iterates_residual_exactly(problem):
    """FISTA's recorded residuals, derived from its extrapolated points, are those of its
    iterates: the returned iterate's is the independently measured one, at every budget."""
    operator, signal, _ = problem
    for iterations in (1, 2, 7):
        solution = solvers.fista(
            operator, signal, iterations=iterations, sparsity=0.1, tol=0.0, progress=False
        )
        direct = np.linalg.norm(signal - np.asarray(operator.mv(solution.rho)))
        direct /= np.linalg.norm(signal)
        assert len(solution.history) == iterations + 1  # the start and every iterate
        assert solution.history.residual[solution.stats["best"]] == pytest.approx(direct, rel=1e-4)


def test_least_squares_divergence_is_reported_like_rift(problem, monkeypatch):
    """FISTA given a step 10⁶× too long blows up; like a RIFT run, it raises `Diverged`
    holding the best iterate before the divergence, whose `Stop` names the iteration, and
    `fit` hands the same as a `FitResult`."""
    import rift_jax._solvers.sparse as sparse

    operator, signal, _ = problem
    true_norm = sparse._power_norm
    monkeypatch.setattr(sparse, "_power_norm", lambda *args: 1e-6 * true_norm(*args))
    with pytest.raises(rj.solvers.Diverged, match="diverged") as error:
        solvers.fista(operator, signal, iterations=50, sparsity=0.0, tol=0.0, progress=False)
    solution = error.value.solution
    stop = solution.stopped
    assert stop.outcome is rj.solvers.Outcome.DIVERGED and 1 < stop.at < 50
    assert len(solution.history) == stop.at - 1  # the iterations before it, all finite
    assert np.all(np.isfinite(solution.history.residual))
    assert np.all(np.isfinite(np.asarray(solution.rho)))
    assert rj.solvers.Stop.from_json(stop.to_json()) == stop
    assert str(stop) == f"diverged at iteration {stop.at}"
