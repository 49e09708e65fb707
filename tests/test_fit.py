"""`rift_jax.fit` end to end: the Scene path, the bring-your-own-data path, FitResult."""

import dataclasses
import functools
import inspect
import re
import warnings

import numpy as np
import pytest

import rift_jax as rj
from rift_jax import _holdout, _selection
from rift_jax._fit import _at_points
from rift_jax._geometry import spread
from rift_jax._holdout import holdout_residual
from rift_jax._solvers.methods import METHODS
from rift_jax._support import mask_at


@pytest.fixture(scope="module")
def matched(small_cube):
    """Reconstruction on the scene's own grid: the data are explained exactly."""
    radar, scene, train, _ = small_cube
    options = dict(iterations=300, check_every=100, tol=0.0)  # cond(A) ≈ 50
    return rj.fit(
        scene, train, radar=radar, method="lsmr", granularity=0.5, progress=False, **options
    )


def test_matched_grid_recovers_the_scene(small_cube, matched):
    _, scene, _, test = small_cube
    metrics = matched.evaluate(scene, test)
    assert set(metrics) == {"m_ssim", "m_cos", "t_iou", "p_rmse", "residual"}
    assert metrics["m_ssim"] > 0.99 and metrics["m_cos"] > 0.999 and metrics["t_iou"] == 1.0
    assert metrics["p_rmse"] < 0.05 and metrics["residual"] < 1e-3
    # reflectivity comes back in the scene's units (ρ = 1), not the normalised data's
    assert np.abs(matched.scene.reflectivity).max() == pytest.approx(1.0, rel=1e-2)


def test_fit_result(small_cube, matched):
    radar, scene, train, test = small_cube
    assert matched.method == "lsmr" and matched.radar == radar and matched.viewpoints is train
    assert matched.scene.granularity == 0.5 and matched.scene.extent == 2.0
    assert matched.seconds > 0 and len(matched.history) == 3
    prediction = matched.predict(test)
    assert prediction.signal.shape == (len(test), 8, 4, 4)
    assert np.abs(prediction.signal).max() == pytest.approx(1.0)


def test_default_inverse_grid_is_twice_as_coarse(small_cube):
    radar, scene, train, test = small_cube
    result = rj.fit(scene, train, radar=radar, method="kaczmarz", iterations=2, progress=False)
    assert result.scene.granularity == 1.0 and result.scene.shape == (5, 5, 5)
    metrics = result.evaluate(scene, test)
    assert all(np.isfinite(v) for v in metrics.values())
    assert -1 <= metrics["m_ssim"] <= 1 and 0 <= metrics["t_iou"] <= 1
    assert 0 <= metrics["p_rmse"] <= np.pi


def test_signal_paths_agree(small_cube, matched):
    """RadarData and a raw (unnormalised) array give the same reconstruction."""
    radar, scene, train, _ = small_cube
    data = rj.synthesize(scene, train, radar)
    kwargs = dict(method="lsmr", extent=2.0, granularity=0.5, progress=False)
    kwargs |= dict(iterations=300, check_every=100, tol=0.0)
    from_data = rj.fit(data, train, **kwargs)
    from_array = rj.fit(np.asarray(data.signal) * 7.0, train, radar=radar, **kwargs)
    np.testing.assert_allclose(from_data.scene.reflectivity, matched.scene.reflectivity)
    expected = 7.0 * np.asarray(from_data.scene.reflectivity) / data.scale
    # float32 rounding of the rescaled data, amplified by 300 LSMR steps: 1e-3 of the peak
    atol = 1e-3 * np.abs(expected).max()
    np.testing.assert_allclose(from_array.scene.reflectivity, expected, rtol=0, atol=atol)


def test_the_command_line_fits_a_saved_file_as_fit_does(small_cube, matched, tmp_path, capsys):
    """``rift-jax fit DATA ...`` (`rift_jax._cli`): the result it saves is `matched`'s, made
    by `fit` in Python with the same options; ``info`` describes both files; bad input
    names what is wrong."""
    from rift_jax._cli import main

    radar, scene, train, _ = small_cube
    data = rj.save(tmp_path / "data.npz", rj.synthesize(scene, train, radar))
    grid = ["--extent", "2", "--granularity", "0.5", "--method", "lsmr", "--no-progress"]
    options = ["--option", "iterations=300", "--option", "check_every=100", "--option", "tol=0"]
    assert main(["fit", str(data), *grid, *options]) == 0
    said = capsys.readouterr().out
    assert "lsmr: budget at iteration 300" in said and "data_fit.h5" in said
    result = rj.load(tmp_path / "data_fit.h5")
    assert result.method == "lsmr" and result.options["check_every"] == 100
    np.testing.assert_allclose(result.scene.reflectivity, matched.scene.reflectivity)
    assert main(["info", str(data)]) == 0 and main(["info", str(tmp_path / "data_fit.h5")]) == 0
    said = capsys.readouterr().out
    assert "RadarData" in said and "signal (30, 8, 4, 4)" in said
    assert "FitResult" in said and "9³ points at 0.5 m over ±2.0 m, 30 views" in said
    with pytest.raises(SystemExit, match="`--option` must be NAME=VALUE"):
        main(["fit", str(data), *grid, "--option", "300"])
    with pytest.raises(SystemExit, match=r"takes no option\(s\) \[.epochs.\]"):
        main(["fit", str(data), *grid, "--option", "epochs=3"])
    with pytest.raises(SystemExit, match="holds a Scene, not measured signals"):
        main(["fit", str(rj.save(tmp_path / "scene.npz", scene)), *grid])
    with pytest.raises(SystemExit, match="`extent` is not a method option"):
        main(["fit", str(data), *grid, "--option", "extent=3"])
    with pytest.raises(SystemExit, match="`--out` must be a .npz, .h5 or .hdf5 file"):
        main(["fit", str(data), *grid, "--out", str(tmp_path / "result.npy")])  # before fitting
    with pytest.raises(SystemExit, match="no file at `path`"):
        main(["fit", str(tmp_path / "missing.npz"), *grid])
    # `experiment` hands what follows the study's name to the study's own command line
    with pytest.raises(SystemExit) as ended:
        main(["experiment", "weak_target", "--help"])
    assert ended.value.code == 0 and "Weak-target detection" in capsys.readouterr().out


def test_a_signal_without_phase_warns(small_cube):
    """Magnitudes (a real dtype) or complex samples with no imaginary part: a FitWarning
    before anything runs (the empty support then stops the fit, so nothing compiles)."""
    radar, scene, train, _ = small_cube
    signal = np.asarray(rj.synthesize(scene, train, radar).signal)
    stop = dict(support=np.zeros((5,) * 3, bool), extent=2.0, granularity=1.0, radar=radar)
    for phaseless in (np.abs(signal), np.abs(signal).astype(np.complex64)):
        with pytest.warns(rj.FitWarning, match="real-valued: it carries no phase"):
            with pytest.raises(ValueError, match="no points"):
                rj.fit(phaseless, train, **stop)
    with warnings.catch_warnings():
        warnings.simplefilter("error", rj.FitWarning)
        with pytest.raises(ValueError, match="no points"):
            rj.fit(signal, train, **stop)


def test_zero_signal_warns(small_cube):
    radar, _, train, _ = small_cube
    zeros = np.zeros((len(train), *radar.signal_shape), np.complex64)
    with pytest.warns(UserWarning, match="all zero"):
        result = rj.fit(zeros, train, radar=radar, extent=2.0, granularity=1.0, progress=False)
    assert not np.any(result.scene.reflectivity) and result.support is None  # none to see
    assert result.stopped.outcome is rj.solvers.Outcome.ZERO_SIGNAL
    predicted = result.predict(train)  # ρ = 0 predicts nothing (`synthesize` would refuse)
    assert predicted.signal.shape == zeros.shape and not np.any(predicted.signal)


def test_each_method_declares_the_options_its_solver_takes():
    """`fit` checks options against each method's declaration, not its solver's signature:
    the two must agree (plus `train_granularity`, fit's own, for every grid method; for
    RIFT the Recipe's fields too, less what fit passes itself)."""
    recipe = {field.name for field in dataclasses.fields(rj.solvers.Recipe)}
    for name, method in METHODS.items():
        solver = method.solve
        fixed = set(solver.keywords) if isinstance(solver, functools.partial) else set()
        parameters = inspect.signature(solver).parameters
        keywords = {p for p, v in parameters.items() if v.kind is v.KEYWORD_ONLY}
        expected = keywords - {"progress", "monitor", "seed"}
        if not method.scatterers:
            expected |= {"train_granularity"}
        if method.inr:
            expected = (expected | fixed | recipe) - {
                "extent",
                "fine_points",
            }
        assert method.options == expected, name
        assert method.seeded == ("seed" in parameters), name
        assert method.inr == ("fine_points" in parameters), name


def test_bad_input(small_cube):
    radar, scene, train, _ = small_cube
    signal = np.full((len(train), *radar.signal_shape), 1 + 1j, np.complex64)
    grid = dict(extent=2.0, granularity=1.0, radar=radar)
    with pytest.raises(ValueError, match="unknown `method` 'newton'"):
        rj.fit(scene, train, method="newton")
    with pytest.raises(ValueError, match=r"takes no option\(s\) \['relaxation'\]"):
        rj.fit(scene, train, method="lsmr", relaxation=1.0)
    bad = signal.copy()
    bad[1, 2, 0, 0] = np.inf
    with pytest.raises(ValueError, match="must be finite"):
        rj.fit(bad, train, **grid)
    with pytest.raises(ValueError, match=r"must have shape \(30, 8, 4, 4\)"):
        rj.fit(signal[:, :4], train, **grid)
    with pytest.raises(ValueError, match="pass the grid"):
        rj.fit(signal, train, radar=radar)
    with pytest.raises(ValueError, match="`granularity`"):  # a grid without points
        rj.fit(signal, train, extent=2.0, granularity=5.0, radar=radar)
    with pytest.raises(ValueError, match="`viewpoints` must be"):
        rj.fit(scene, [0.1, 0.2])
    with pytest.raises(ValueError, match="`snr_db` applies to a Scene"):
        rj.fit(signal, train, snr_db=10.0, **grid)


def test_warns_when_the_inverse_grid_does_not_nest():
    """A 20³ scene over ±2 m (points at half-integer multiples of 4/19 m) and its default 2×
    inverse grid share no point: fit says so, naming both grids; 21³ nests and is quiet."""
    radar = rj.Radar(n_frequencies=4, n_tx=2, n_rx=2)
    views = rj.Viewpoints.grid(3, 2)
    even = rj.Scene.from_array(np.ones((20, 20, 20), np.complex64), 2.0)
    # fit warns while preparing the data, before it solves: an empty support then stops it
    # with a ValueError, so that no solver is compiled for this check (~10 s of the suite)
    common = dict(radar=radar, method="lsmr", progress=False)
    with pytest.warns(rj.GridWarning) as warned:
        with pytest.raises(ValueError, match="no points"):
            rj.fit(even, views, support=np.zeros((10,) * 3, bool), **common)
    said = [str(w.message) for w in warned]
    assert any(re.search(r"shares 0% of its points.*20 points per axis", m) for m in said)
    # 2·4/19 m does not divide ±2 m either: its 10 points reach ±1.89 m
    assert any("reaches only ±1.89474 m (10 points per axis)" in m for m in said)
    odd = rj.Scene.from_array(np.ones((21, 21, 21), np.complex64), 2.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", rj.GridWarning)
        with pytest.raises(ValueError, match="no points"):
            rj.fit(odd, views, support=np.zeros((11,) * 3, bool), **common)
    # of c = 2..8 (centred grids: c odd nests only with an even number of points): c = 5
    assert rj._scenes.nesting_granularities(2.0, 4 / 19) == pytest.approx([5 * 4 / 19])


@pytest.mark.filterwarnings("ignore::rift_jax.FitWarning")  # tiny budgets: RIFT fits little
@pytest.mark.parametrize(
    "method, options",
    [
        ("kaczmarz", {"iterations": 4}),
        ("fista", {"iterations": 4, "sparsity": 0.05}),  # one solve (the λ path's: below)
        ("rift-n", {"epochs": 4}),
    ],
)
def test_monitor_sees_each_iteration_and_changes_nothing(tiny, method, options):
    """`monitor` is called once per iteration with the best reconstruction so far as a
    Scene on the inverse grid (for least squares the last one is the result), its time is
    left out of the run's clock, and the result is bit-identical to a run without it."""
    import time

    radar, scene, train, _ = tiny
    common = dict(radar=radar, method=method, granularity=0.5, progress=False, **options)
    seen = []

    def monitor(iteration, seconds, current):
        seen.append((iteration, seconds, current()))
        time.sleep(0.5)  # a slow look: not the run's time

    plain = rj.fit(scene, train, **common)  # compiles: the watched run's times are its own
    watched = rj.fit(scene, train, monitor=monitor, **common)
    np.testing.assert_array_equal(watched.scene.reflectivity, plain.scene.reflectivity)
    runs = options.get("iterations", options.get("epochs"))  # (FISTA's history has one more:
    assert [k for k, _, _ in seen] == list(range(1, runs + 1))  # its last iterate, checked after)
    seconds = np.array([t for _, t, _ in seen])  # fit's clock, which began before the solver's
    assert np.all(seconds >= watched.history.seconds[: len(seen)])
    assert np.all(np.diff(seconds) < 0.5) and seconds[-1] <= watched.seconds
    assert np.all(np.diff(watched.history.seconds) < 0.5)
    # counted, the looks would add 0.5 s each (2 s); the checks after the solver take
    # ~0.1 s, and 0.5 s on a loaded machine (a fresh clone beside two other jobs)
    assert watched.seconds < watched.history.seconds[-1] + 0.25 * runs
    assert all(s.shape == watched.scene.shape for _, _, s in seen)
    if method == "kaczmarz":  # the best sweep so far is the one returned (FISTA may still
        # return its last iterate, whose residual is known only after the loop)
        np.testing.assert_array_equal(seen[-1][2].reflectivity, watched.scene.reflectivity)
    with pytest.raises(ValueError, match="`monitor` must be callable"):
        rj.fit(scene, train, monitor=1, **common)


@pytest.mark.filterwarnings("ignore::rift_jax.FitWarning")  # tiny budgets: RIFT fits little
@pytest.mark.parametrize(
    "method, options",
    [
        ("kaczmarz", {"iterations": 6, "tol": 0}),
        ("fista", {"iterations": 6, "tol": 0, "sparsity": 0.05}),
        ("rift-n", {"epochs": 6}),
    ],
)
def test_a_monitor_or_time_limit_ends_the_run_with_the_best_so_far(tiny, method, options):
    """A monitor that returns True ends the run after that iteration (`Outcome.STOPPED`),
    and the result is what its `current()` showed: the run up to there, unchanged.
    `time_limit` ends it after the iteration in which fit's clock passes the limit, and a
    limit never reached changes nothing."""
    radar, scene, train, _ = tiny
    common = dict(radar=radar, method=method, granularity=0.5, progress=False, **options)
    seen = []

    def stop_at_three(iteration, seconds, current):
        seen.append((seconds, current()))
        return iteration == 3

    stopped = rj.fit(scene, train, monitor=stop_at_three, **common)
    assert stopped.stopped == rj.solvers.Stop(rj.solvers.Outcome.STOPPED, 3)
    assert len(seen) == 3
    if method != "fista":  # (FISTA's history adds its last iterate, checked after the loop)
        assert len(stopped.history) == 3
        # (RIFT's: one field rendered by two compiled functions, equal to float32 rounding)
        np.testing.assert_allclose(
            seen[-1][1].reflectivity, stopped.scene.reflectivity, rtol=1e-6, atol=1e-6
        )
    whole = rj.fit(scene, train, **common)
    assert whole.stopped.outcome is rj.solvers.Outcome.BUDGET
    if method == "kaczmarz":  # stopping changes nothing before it: its three sweeps are these
        np.testing.assert_array_equal(stopped.history.residual, whole.history.residual[:3])

    # the clock passes a limit of a nanosecond in the first iteration, and never a day's
    limited = rj.fit(scene, train, time_limit=1e-9, **common)
    assert limited.stopped == rj.solvers.Stop(rj.solvers.Outcome.STOPPED, 1)
    unlimited = rj.fit(scene, train, time_limit=86400, **common)
    np.testing.assert_array_equal(unlimited.scene.reflectivity, whole.scene.reflectivity)
    for bad in (0, -1.0, float("inf"), "60", True):
        with pytest.raises(ValueError, match="`time_limit` must be a positive finite number"):
            rj.fit(scene, train, time_limit=bad, **common)


def test_a_time_limit_ends_fistas_lambda_path_and_the_solve_goes_on_from_it(small_cube):
    """FISTA's λ path is watched as its solve is: a limit passed in the path's first solve
    ends the path there (its record says so), and the final solve, stopped after one
    step, starts from that λ's image, not from zero (measured: residuals 0.988 at the start
    and 0.979 after the step, against 1 and 0.986 from zero)."""
    radar, scene, train, _ = small_cube
    options = dict(radar=radar, method="fista", progress=False)
    limited = rj.fit(scene, train, time_limit=1e-9, **options)
    path = limited.stats["sparsity_path"]
    assert path["stopped"] and list(path["scores"]) == ["0.5"]
    assert limited.stats["sparsity"] == 0.5
    assert limited.stopped == rj.solvers.Stop(rj.solvers.Outcome.STOPPED, 1)
    assert path["scores"]["0.5"]["iterations"] == 1
    one_step = rj.fit(scene, train, sparsity=0.5, iterations=1, tol=0, **options)
    assert one_step.history.residual[0] == 1 and limited.history.residual[0] < 0.995
    assert limited.history.residual.min() < one_step.history.residual.min()


def test_least_squares_solves_for_the_points_of_a_finer_grid(small_cube):
    """`train_granularity` puts least squares on the points RIFT's coarse to fine trains
    last (the finer grid's, in the support), so the two compare on the same points: the
    solve is exactly the fine grid's on the support carried there, `scene` holds its values
    at the inverse grid's points (nested: every other fine point), and `predict`
    synthesises from `trained`."""
    radar, scene, train, test = small_cube  # data on a 0.5 m grid; inverse grid 1 m
    options = dict(radar=radar, method="fista", iterations=5, sparsity=0.05, progress=False)
    seen = []  # what a monitor sees: the best so far on the inverse grid, as `scene`
    result = rj.fit(
        scene, train, train_granularity=0.5, monitor=lambda *a: seen.append(a[2]()), **options
    )
    assert result.scene.shape == (5, 5, 5) and result.trained.shape == (9, 9, 9)
    assert len(seen) == 5 and seen[-1].shape == (5, 5, 5)  # one per iteration
    fine = rj.Scene.empty(scene.extent, 0.5)
    carried = mask_at(result.support, rj.Scene.empty(scene.extent, 1.0), fine.points())
    direct_seen = []
    direct = rj.fit(
        scene, train, granularity=0.5, support=carried.reshape(fine.shape),
        monitor=lambda *a: direct_seen.append(a[2]()), **options,
    )  # fmt: skip
    np.testing.assert_array_equal(result.trained.reflectivity, direct.scene.reflectivity)
    for monitored, on_fine in zip(seen, direct_seen, strict=True):  # sampled as `scene`
        np.testing.assert_array_equal(monitored.reflectivity, on_fine.reflectivity[::2, ::2, ::2])
    assert result.stats["data_residual"] == direct.stats["data_residual"]
    every_other = result.trained.reflectivity[::2, ::2, ::2]
    np.testing.assert_array_equal(result.scene.reflectivity, every_other)
    expected = rj.synthesize(result.trained, test, radar).signal
    np.testing.assert_array_equal(result.predict(test).signal, expected)
    whole = rj.fit(scene, train, support=None, train_granularity=0.5, **options)
    assert whole.support is None and "support_points" not in whole.stats  # as on one grid
    with pytest.raises(ValueError, match="`x0` is a start on the inverse grid"):
        rj.fit(scene, train, train_granularity=0.5, x0=np.zeros(125), **options)


def test_a_finer_grids_values_at_the_inverse_grids_points():
    """Each inverse grid point takes its nearest fine point's value: that very point where
    the grids nest, within half a fine spacing per axis where they do not."""
    fine = rj.Scene.empty(2.0, 0.5)
    values = np.arange(fine.reflectivity.size)
    nested = _at_points(values, fine, rj.Scene.empty(2.0, 1.0).points())
    np.testing.assert_array_equal(nested, values.reshape(fine.shape)[::2, ::2, ::2].ravel())
    fine, coarse = rj.Scene.empty(2.4, 0.3), rj.Scene.empty(2.4, 0.8).points()
    nearest = fine.points()[_at_points(np.arange(fine.reflectivity.size), fine, coarse)]
    assert np.abs(nearest - coarse).max() == pytest.approx(0.1)  # 0.8 m reads 0.9 m


# -- defaults and the checks after a fit ---------------------------------------------------


def test_every_method_defaults_to_the_estimated_support(small_cube):
    """``support="auto"``, exactly the mask `estimate_support` gives; `support=None` is the
    whole grid."""
    radar, scene, train, _ = small_cube
    options = dict(radar=radar, granularity=0.5, method="fista", iterations=5, progress=False)
    result = rj.fit(scene, train, **options)
    data = rj.synthesize(scene, train, radar)
    grid = rj.Scene.empty(scene.extent, 0.5)
    expected = rj.estimate_support(data.signal, train, grid, radar=radar)
    np.testing.assert_array_equal(result.support, expected)
    assert result.n_points == expected.sum()  # here all 729: this radar's sidelobes are wide
    whole = rj.fit(scene, train, support=None, **options)
    assert whole.support is None and whole.n_points == expected.size
    for checked in (result, whole):  # the checks run with or without a support
        assert 0 <= checked.stats["data_residual"] < 1 and 0 < checked.stats["coherence"] <= 1
    assert "support_leak" in result.stats and "support_leak" not in whole.stats


def test_check_measures_residual_and_coherence_by_hand(small_cube):
    """`check_fit`'s numbers against NumPy on the same views: ‖y − Aρ‖/‖y‖, and cos(|ρ|, |Aᴴy|),
    1 for ρ = Aᴴy itself and lower for a flat ρ (a smooth blob)."""
    from rift_jax._checks import check_fit

    radar, scene, train, _ = small_cube
    data = rj.synthesize(scene, train, radar)
    grid = rj.Scene.empty(scene.extent, 2 * scene.granularity)
    operator = rj.grt_operator(radar, train, grid.points())
    signal = np.asarray(data.signal)
    back = np.asarray(operator.fn.adjoint(signal))
    matched = check_fit(operator, signal, back, None, grid.points(), train)
    assert matched["coherence"] == pytest.approx(1.0, abs=1e-5)
    residual = signal - np.asarray(operator.fn(back))
    assert matched["data_residual"] == pytest.approx(
        np.linalg.norm(residual) / np.linalg.norm(signal), rel=1e-4
    )
    flat = check_fit(operator, signal, np.ones_like(back), None, grid.points(), train)
    expected = np.abs(back).sum() / (np.sqrt(back.size) * np.linalg.norm(back))
    assert flat["coherence"] == pytest.approx(expected, rel=1e-4) and expected < 0.9
    # a pruned field (0 off its active set) is read over its own points: Aᴴy's sidelobes
    # off the set do not count against it, as they would over every point
    kept = np.abs(back) >= np.quantile(np.abs(back), 0.9)
    pruned = check_fit(operator, signal, np.where(kept, back, 0), None, grid.points(), train)
    assert pruned["coherence"] == pytest.approx(1.0, abs=1e-5)
    everywhere = np.linalg.norm(back[kept]) / np.linalg.norm(back)  # cos over every point
    assert everywhere < 0.9


def test_failed_fit_warnings_name_the_cause():
    """Residual ≥ 1 names the support when it leaked, RIFT's training, or the grid; a
    RIFT field unlike the backprojection names the smooth-blob collapse; a good fit is
    silent."""
    from rift_jax._checks import warn_if_failed

    cases = [
        ("lsmr", {"data_residual": 1.2, "coherence": 0.9, "support_leak": 0.8}, True, "support"),
        ("lsmr", {"data_residual": 1.0, "coherence": 0.9}, False, "finer `granularity`"),
        ("rift-n", {"data_residual": 1.3, "coherence": 0.9, "support_leak": 0.1}, True, "INR"),
        ("rift-s", {"data_residual": 0.5, "coherence": 0.6}, False, "smooth-blob"),
        # ρ = 0: FISTA's λ from the known noise (the leak then reads the whole signal)
        (
            "fista",
            {"data_residual": 1.0, "coherence": 0.0, "noise_lambda": 0.3, "support_leak": 0.9},
            True,
            "above their noise",
        ),  # fmt: skip
    ]
    for method, stats, on_support, cause in cases:
        with pytest.warns(rj.FitWarning, match=cause):
            warn_if_failed(method, stats, on_support)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_if_failed("fista", {"data_residual": 0.9, "coherence": 0.5}, False)  # not RIFT
        warn_if_failed("rift-n", {"data_residual": 0.9, "coherence": 0.85}, False)
        # a good field trained with complex MSE (0.68-0.80 on the stress grid)
        mse = {"data_residual": 0.9, "coherence": 0.68, "recipe": {"loss": "mse"}}
        warn_if_failed("rift-n", mse, False)
        # a field that explains the data is no collapse, however sharp against Aᴴy
        warn_if_failed("rift-n", {"data_residual": 0.1, "coherence": 0.55}, False)
        # at 0 dB a perfect fit leaves 0.71: the residual beyond the noise's is what counts
        warn_if_failed("rift-n", {"data_residual": 0.72, "coherence": 0.55}, False, 0.707)
    # the robust loss's failed fields scored 0.74-0.79: warned at that loss, not at MSE's
    for loss, coherence, floor in (("robust", 0.75, 0.8), ("mse", 0.6, 0.65)):
        stats = {"data_residual": 0.9, "coherence": coherence, "recipe": {"loss": loss}}
        with pytest.warns(rj.FitWarning, match=rf"= {coherence:.2f} < {floor}\): the smooth"):
            warn_if_failed("rift-s", stats, False)
    with pytest.warns(rj.FitWarning, match="smooth-blob"):  # a collapse at 0 dB
        warn_if_failed("rift-n", {"data_residual": 0.98, "coherence": 0.55}, False, 0.707)


# -- method="auto": the candidate that predicts held-out viewpoints best ----------------------


def test_holdout_residual_is_the_best_gain_residual():
    """√(1 − c²) against the residual at the least-squares complex gain, by lstsq in float64:
    scale-free, 0 for a perfect prediction, 1 for none."""
    rng = np.random.default_rng(0)
    y = rng.normal(size=(3, 4, 2, 2)) + 1j * rng.normal(size=(3, 4, 2, 2))
    p = y + 0.7 * (rng.normal(size=y.shape) + 1j * rng.normal(size=y.shape))
    gain = np.linalg.lstsq(p.reshape(-1, 1), y.ravel(), rcond=None)[0]
    expected = np.linalg.norm(y.ravel() - p.ravel() * gain) / np.linalg.norm(y)
    assert holdout_residual(p, y) == pytest.approx(expected, rel=1e-9)
    assert holdout_residual((2 - 3j) * p, y) == pytest.approx(expected, rel=1e-9)
    assert holdout_residual(-5j * y, y) == pytest.approx(0.0, abs=1e-7)
    assert holdout_residual(np.zeros_like(y), y) == pytest.approx(1.0, rel=1e-12)
    assert holdout_residual(np.full_like(y, np.nan), y) == pytest.approx(1.0, rel=1e-12)
    assert holdout_residual(y, np.zeros_like(y)) == pytest.approx(1.0)  # zero held-out data


def test_auto_keeps_the_first_candidate_unless_another_is_clearly_better():
    """The one-standard-error rule: a candidate listed later takes the lead only if its
    held-out residual² is lower by more than `MARGIN` standard errors of the paired
    per-view differences; a lower residual within that noise keeps the first (the two
    at −10 dB that differed by 0.0002), and a clear win on every view does not."""
    rng = np.random.default_rng(0)
    base = np.full(20, 0.0496) + rng.normal(0, 1e-3, 20)  # 20 held-out views, residual ≈ 0.996

    def score(errors, failure=None):
        errors = np.asarray(errors)
        return dict(holdout_residual=float(np.sqrt(errors.sum())),
                    holdout_errors=errors.tolist(), failure=failure)  # fmt: skip

    # lower on average by t standard errors of the sum of the 20 paired differences
    z = rng.normal(size=20)
    z, deviation = (z - z.mean()) / z.std(ddof=1), 2e-4

    def lower_by(t):
        return base - (t * deviation / np.sqrt(20) + deviation * z)

    for t, ranked in ((0.9, ["fista", "rift-n"]), (1.1, ["rift-n", "fista"])):
        assert _holdout.paired_t(score(lower_by(t)), score(base)) == pytest.approx(t)
        assert score(lower_by(t))["holdout_residual"] < score(base)["holdout_residual"]
        assert _holdout.rank({"fista": score(base), "rift-n": score(lower_by(t))}) == ranked
    noisy = lower_by(0.9)  # lower, but within the noise
    clear = base - 5e-4  # lower on every view
    assert _holdout.rank({"fista": score(base), "rift-n": score(clear)}) == ["rift-n", "fista"]
    # the lead passes on in the candidates' order; the rest follow by residual, failures last
    scores = {"a": score(base), "b": score(base - 1e-3, "collapsed"), "c": score(noisy),
              "d": score(clear)}  # fmt: skip
    assert _holdout.rank(scores) == ["d", "c", "a", "b"]
    # a per-view tie keeps the first; the same gain on every view is infinitely clear
    assert _holdout.rank({"x": score(base), "y": score(base)}) == ["x", "y"]
    assert _holdout.paired_t(score(base), score(base)) == 0.0
    assert _holdout.paired_t(score(clear), score(base)) == np.inf
    # the errors sum to the residual²
    rho = rng.normal(size=(4, 3, 2)) + 1j * rng.normal(size=(4, 3, 2))
    y = rho + 0.3 * (rng.normal(size=rho.shape) + 1j * rng.normal(size=rho.shape))
    errors = _holdout.holdout_errors(2j * rho, y)
    assert errors.shape == (4,) and np.sum(errors) == pytest.approx(holdout_residual(rho, y) ** 2)


AUTO_CANDIDATES = {  # one damped sweep, and least squares that explains the data's own grid
    "kaczmarz": {"iterations": 1, "relaxation": 0.01},
    "lsmr": {"iterations": 40, "tol": 0.0},
}


def test_auto_fits_the_candidate_that_predicts_held_out_views_best(small_cube):
    """Each candidate is fitted on the training views less a fifth, evenly spread, on one
    support; its score is the held-out residual of its prediction (recomputed here from a
    fit of its own); the clearly lower wins, though listed second; the result is then that
    method's fit on every view, bit for bit, with the selection's time added. On the data's
    own 0.5 m grid, which explains them: on the 1 m grid both candidates leave ~0.95,
    each lower on half the held-out views, and the first keeps its place."""
    radar, scene, train, _ = small_cube
    result = rj.fit(
        scene, train, radar=radar, method="auto", candidates=AUTO_CANDIDATES, granularity=0.5,
        progress=False,
    )  # fmt: skip
    selection = result.stats["selection"]
    held = selection["holdout_views"]
    assert held == spread(len(train), 6).tolist()
    kept = np.setdiff1d(np.arange(len(train)), held)
    signal = np.asarray(rj.synthesize(scene, train, radar).signal)
    for method, options in AUTO_CANDIDATES.items():
        alone = rj.fit(
            signal[kept], train.subset(kept), radar=radar, method=method, extent=2.0,
            granularity=0.5, support=result.support, progress=False, **options,
        )  # fmt: skip
        predicted = alone.predict(train.subset(held)).signal
        expected = holdout_residual(predicted, signal[held])
        # float32 rounding: the split's data went through fit's normalisation and back
        assert selection["scores"][method]["holdout_residual"] == pytest.approx(expected, 1e-5)
    scores = {m: s["holdout_residual"] for m, s in selection["scores"].items()}
    assert scores["lsmr"] < scores["kaczmarz"] and selection["chosen"] == result.method == "lsmr"
    direct = rj.fit(scene, train, radar=radar, method="lsmr", granularity=0.5,
                    support=result.support, progress=False, **AUTO_CANDIDATES["lsmr"])  # fmt: skip
    np.testing.assert_array_equal(result.scene.reflectivity, direct.scene.reflectivity)
    expected_support = rj.estimate_support(signal, train, rj.Scene.empty(2.0, 0.5), radar=radar)
    np.testing.assert_array_equal(result.support, expected_support)
    assert result.seconds > selection["seconds"] > 0 and "support_seconds" in result.stats


# a RIFT run that cannot move (a learning rate of 1e-12) from its start: a collapse
COLLAPSING = {"epochs": 3, "learning_rate": 1e-12, "retries": 0, "patience": None}


def test_auto_from_too_few_views_runs_its_first_candidate(small_cube):
    """4 views: holding out 2 would leave 2 to fit on, under `MIN_TRAINING`; nothing is
    scored, and the first candidate runs alone."""
    radar, scene, train, _ = small_cube
    few = train[:4]
    result = rj.fit(
        scene, few, radar=radar, method="auto", candidates=AUTO_CANDIDATES, progress=False
    )
    assert result.method == "kaczmarz" and result.stats["selection"]["scores"] == {}
    assert result.stats["selection"]["holdout_views"] == []


def test_auto_passes_over_a_candidate_that_collapsed(small_cube, monkeypatch):
    """A RIFT candidate that collapsed ranks after one that did not, even with the lower
    held-out residual (given it here); a final fit that collapses gives way to the next
    candidate (its warning not raised; `rejected` names the collapse); only when every one
    collapsed is the warning raised."""
    radar, scene, train, _ = small_cube
    candidates = {"rift-n": COLLAPSING, "lsmr": AUTO_CANDIDATES["lsmr"]}
    options = dict(radar=radar, method="auto", candidates=candidates, progress=False)
    # in the candidates' order: the collapsed RIFT scores best, on every held-out view
    residuals = iter([0.1, 0.5])
    monkeypatch.setattr(
        _holdout, "holdout_errors", lambda _, y: np.full(len(y), next(residuals) ** 2 / len(y))
    )
    scored = rj.fit(scene, train, **options)
    selection = scored.stats["selection"]
    assert selection["scores"]["rift-n"]["holdout_residual"] == 0.1
    assert selection["scores"]["rift-n"]["failure"] is not None
    assert selection["scores"]["lsmr"]["failure"] is None and scored.method == "lsmr"
    assert selection["rejected"] == {}  # ranked after LSMR: its final fit never ran
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing raised: the collapse is only recorded
        unscored = rj.fit(scene, train[:4], **options)  # too few views: in the given order
    assert unscored.method == "lsmr"
    assert unscored.stats["selection"]["rejected"]["rift-n"] is not None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        alone = rj.fit(scene, train[:4], **options | {"candidates": {"rift-n": COLLAPSING}})
    assert alone.method == "rift-n" and alone.stats["collapse"] is not None
    assert alone.stats["selection"]["rejected"] == {}  # returned, collapse and all
    assert rj.solvers.CollapseWarning in {w.category for w in caught}
    assert all(w.filename == __file__ for w in caught)  # at the line that called fit


def test_auto_on_noisy_data_is_the_chosen_methods_own_fit(small_cube):
    """With ``snr_db`` and a seed, the final fit draws the very noise the candidates were
    scored on: the result is the chosen method's fit on the same noisy data, bit for bit."""
    radar, scene, train, _ = small_cube
    noisy = dict(radar=radar, snr_db=0.0, seed=3, progress=False)
    result = rj.fit(scene, train, method="auto", candidates=AUTO_CANDIDATES, **noisy)
    chosen = result.method
    direct = rj.fit(scene, train, method=chosen, support=result.support,
                    **noisy, **AUTO_CANDIDATES[chosen])  # fmt: skip
    np.testing.assert_array_equal(result.scene.reflectivity, direct.scene.reflectivity)
    assert result.residual == direct.residual


def test_auto_tells_its_candidates_the_noise_fit_would_know(small_cube, monkeypatch):
    """The candidates fit arrays (four fifths of the views), which say no noise level: a
    method that uses one (RIFT, FISTA) gets the σ that ``snr_db`` implies, in the signal's units,
    as `noise` (RIFT's and FISTA's way to it are tested in test_stability.py); a method
    that does not is given none, and a candidate's own `noise` wins."""
    from rift_jax import _selection

    radar, scene, train, _ = small_cube
    given = []

    def scored(method, options, *args):  # a tie: the first candidate, LSMR, is fitted
        given.append((method, dict(options)))
        return dict(holdout_residual=0.5, holdout_errors=[0.125, 0.125], seconds=0.0,
                    stopped="budget", failure=None, warnings=[])  # fmt: skip

    monkeypatch.setattr(_selection, "_score", scored)
    candidates = {"lsmr": AUTO_CANDIDATES["lsmr"], "rift-n": {"epochs": 1}}
    noisy = dict(radar=radar, method="auto", snr_db=0.0, seed=3, progress=False)
    assert rj.fit(scene, train, candidates=candidates, **noisy).method == "lsmr"
    data = rj.synthesize(scene, train, radar, snr_db=0.0, seed=3)
    power = np.mean(np.abs(np.asarray(data.signal) * data.scale) ** 2)
    assert given[0] == ("lsmr", AUTO_CANDIDATES["lsmr"])
    assert given[1][0] == "rift-n" and given[1][1]["epochs"] == 1
    assert given[1][1]["noise"] == pytest.approx(np.sqrt(power / 2), rel=1e-5)  # 0 dB
    given.clear()
    rj.fit(scene, train, candidates={"lsmr": {}, "rift-n": {"noise": 0.0}}, **noisy)
    assert given[1] == ("rift-n", {"noise": 0.0})


def test_auto_refuses_what_it_cannot_honour(small_cube):
    radar, scene, train, _ = small_cube
    auto = dict(radar=radar, method="auto")
    with pytest.raises(ValueError, match=r"takes no solver option\(s\) \['iterations'\]"):
        rj.fit(scene, train, iterations=5, **auto)
    with pytest.raises(ValueError, match="no `monitor` or `time_limit`"):
        rj.fit(scene, train, time_limit=5.0, **auto)
    for bad in ("fista", ["fista", "fista"], ["fista", "points"], [], {"fista": 3}, [1]):
        with pytest.raises(ValueError, match="`candidates"):
            rj.fit(scene, train, candidates=bad, **auto)
    with pytest.raises(ValueError, match=r"method 'lsmr' takes no option\(s\) \['relaxation'\]"):
        rj.fit(scene, train, candidates={"lsmr": {"relaxation": 1.0}}, **auto)


def test_the_default_method_is_fista_with_its_lambda_chosen_on_held_out_views(small_cube):
    """`fit(scene, viewpoints)` is FISTA at its defaults (λ chosen on held-out views), and
    its result is that of the λ it chose, bit for bit; ``method="auto"`` still chooses
    between FISTA and RIFT(N) when asked."""
    radar, scene, train, _ = small_cube
    assert inspect.signature(rj.fit).parameters["method"].default == "fista"
    result = rj.fit(scene, train, radar=radar, progress=False)
    assert result.method == "fista" and "sparsity_path" in result.stats
    assert "selection" not in result.stats  # no choice between methods
    chosen = result.stats["sparsity"]
    direct = rj.fit(scene, train, radar=radar, method="fista", sparsity=chosen,
                    support=result.support, progress=False)  # fmt: skip
    np.testing.assert_array_equal(result.scene.reflectivity, direct.scene.reflectivity)
    assert "sparsity_path" not in direct.stats
    auto = rj.fit(scene, train, radar=radar, method="auto", progress=False)
    selection = auto.stats["selection"]
    assert selection["candidates"] == ["fista", "rift-n"]
    assert auto.method == selection["chosen"] == _holdout.rank(selection["scores"])[0]


def test_auto_says_each_warning_once_at_the_callers_line(small_cube, monkeypatch):
    """Each fit inside "auto" meets the same input: a grid that does not nest warns once,
    not once per fit, and at the line that called `fit`; a filter that makes it an error
    stops the call before any fit, as it stops a single method's `fit`."""
    radar, scene, train, _ = small_cube
    options = dict(radar=radar, method="auto", granularity=0.8, candidates=AUTO_CANDIDATES,
                   progress=False)  # fmt: skip
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rj.fit(scene, train, **options)
    grid = [str(w.message) for w in caught if issubclass(w.category, rj.GridWarning)]
    assert grid and len(grid) == len(set(grid))  # the non-nesting grid's, each once
    assert all(w.filename == __file__ for w in caught)
    monkeypatch.setattr(_selection, "fit", lambda *_, **__: pytest.fail("a fit ran"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", rj.GridWarning)
        with pytest.raises(rj.GridWarning, match="nest"):
            rj.fit(scene, train, **options)


def test_auto_keeps_its_warnings_and_its_errors_when_a_fit_raises(small_cube, monkeypatch):
    """A phaseless signal on an empty support: the first candidate's fit raises, and the
    warning is still said (once). With warnings as errors, the input's warning stops the
    call before any fit; one that a fit raises before its own error comes out in that
    error's notes."""
    radar, scene, train, _ = small_cube
    magnitudes = np.abs(np.asarray(rj.synthesize(scene, train, radar).signal))
    stop = dict(support=np.zeros((5,) * 3, bool), extent=2.0, granularity=1.0, radar=radar)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(ValueError, match="no points"):
            rj.fit(magnitudes, train, **stop)
    phaseless = [w for w in caught if "carries no phase" in str(w.message)]
    assert len(phaseless) == 1 and phaseless[0].filename == __file__
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(rj.FitWarning, match="carries no phase"):
            rj.fit(magnitudes, train, **stop)

    def warns_then_raises(*_, **__):
        warnings.warn("a stand-in warning from inside a fit", rj.GridWarning, stacklevel=1)
        raise ValueError("a stand-in error")

    monkeypatch.setattr(_selection, "fit", warns_then_raises)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="stand-in error") as info:
            rj.fit(scene, train, radar=radar, method="auto", progress=False)
    assert any("stand-in warning" in note for note in info.value.__notes__)


def test_auto_gives_way_when_a_final_fit_diverges(small_cube, monkeypatch):
    """A final fit that diverges gives way to the next candidate, as a collapse does; if
    it was the only one, its `Diverged` is raised with the selection in ``.result``. (The
    divergence is a stand-in: the winner's real fit on every view, raised as diverged.)"""
    radar, scene, train, _ = small_cube
    real = _selection.fit

    def diverging(data, viewpoints, *, method, **options):
        result = real(data, viewpoints, method=method, **options)
        if method == "lsmr" and len(viewpoints) == len(train):  # the final fit only
            error = rj.solvers.Diverged("lsmr: a stand-in divergence", None)
            error.result = result
            raise error
        return result

    monkeypatch.setattr(_selection, "fit", diverging)
    first_lsmr = {"lsmr": AUTO_CANDIDATES["lsmr"], "kaczmarz": AUTO_CANDIDATES["kaczmarz"]}
    options = dict(radar=radar, method="auto", progress=False)
    result = rj.fit(scene, train, candidates=first_lsmr, **options)
    selection = result.stats["selection"]
    assert (
        selection["scores"]["lsmr"]["holdout_residual"]
        < (selection["scores"]["kaczmarz"]["holdout_residual"])
    )  # LSMR won the split ...
    assert result.method == "kaczmarz"  # ... and gave way when its final fit diverged
    assert "stand-in divergence" in selection["rejected"]["lsmr"]
    with pytest.raises(rj.solvers.Diverged) as info:
        rj.fit(scene, train, candidates={"lsmr": AUTO_CANDIDATES["lsmr"]}, **options)
    assert info.value.result.stats["selection"]["chosen"] == "lsmr"


def test_auto_ranks_a_candidate_that_diverged_on_the_split_last(small_cube, monkeypatch):
    """A candidate whose fit on the split diverged is scored on its best iterate but ranks
    after every one that did not, even with the lower held-out residual."""
    radar, scene, train, _ = small_cube
    real = _selection.fit

    def diverging(data, viewpoints, *, method, **options):
        result = real(data, viewpoints, method=method, **options)
        if method == "lsmr" and len(viewpoints) < len(train):  # the split's fit only
            error = rj.solvers.Diverged("lsmr: a stand-in divergence", None)
            stopped = rj.solvers.Stop(rj.solvers.Outcome.DIVERGED, 1)
            error.result = dataclasses.replace(result, stopped=stopped)
            raise error
        return result

    monkeypatch.setattr(_selection, "fit", diverging)
    first_lsmr = {"lsmr": AUTO_CANDIDATES["lsmr"], "kaczmarz": AUTO_CANDIDATES["kaczmarz"]}
    result = rj.fit(scene, train, radar=radar, method="auto", candidates=first_lsmr,
                    progress=False)  # fmt: skip
    scores = result.stats["selection"]["scores"]
    assert scores["lsmr"]["holdout_residual"] < scores["kaczmarz"]["holdout_residual"]
    assert scores["lsmr"]["failure"].startswith("diverged")
    assert result.method == "kaczmarz" and result.stats["selection"]["rejected"] == {}
