"""benchmarks.time_to_quality at its quick scale: traces, tables, figure and resume."""

from __future__ import annotations

import json
import types

import numpy as np
import pytest

import rift_jax as rj
from benchmarks import time_to_quality
from experiments import runner


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("time_to_quality")
    results = time_to_quality.cli(["--scale", "quick", "--out", str(out), "--no-progress"])
    return out, results


@pytest.mark.slow
def test_every_method_is_traced_against_its_own_clock(quick):
    out, results = quick
    cfg = time_to_quality.SCALES["quick"]
    expected = [(r.scene, r.label, r.method) for r in time_to_quality.runs(cfg)]
    assert [(r["scene"], r["run"], r["method"]) for r in results["rows"]] == expected
    assert {r["method"] for r in results["rows"]} == set(cfg.methods)  # `fit`'s names
    for row in results["rows"]:
        trace = row["trace"]
        seconds = [r["seconds"] for r in trace]
        assert np.all(np.diff(seconds) >= 0), row["run"]
        # the last sample is the result itself: the same m-SSIM as its evaluation
        assert trace[-1]["m_ssim"] == pytest.approx(row["m_ssim"], abs=1e-9)
        assert trace[-1]["seconds"] == pytest.approx(row["fit_seconds"])
        assert all(-1 <= r["m_ssim"] <= 1 and 0 <= r["p_rmse"] <= np.pi for r in trace)
        assert all(r["residual"] is None or 0 <= r["residual"] for r in trace)
        assert trace[-1]["residual"] is not None  # (None: a sample of FISTA's λ path)
        assert trace[0]["seconds"] < trace[-1]["seconds"], row["run"]  # sampled while running
    assert results["versions"]["matmul_rate_gmacs"] > 0
    saved = json.loads((out / "results.json").read_text())
    assert saved["rows"] == json.loads(json.dumps(results["rows"]))
    text = (out / "results.md").read_text()
    assert "## cube, 10 training views" in text and "to m-SSIM 0.9" in text
    assert "rift-n auto fine" in text and "its complex64 matmul at" in text
    assert (out / "time_to_quality.png").stat().st_size > 10_000
    assert text.endswith("## Figures\n\n![time to quality](time_to_quality.png)\n")  # shown


@pytest.mark.slow  # it reads the same quick run
def test_a_finished_benchmark_resumes_without_repeating_a_run(quick, monkeypatch):
    out, results = quick

    def refuse(*args, **kwargs):
        raise AssertionError("a finished run was repeated")

    monkeypatch.setattr(runner, "fit_and_evaluate", refuse)
    again = time_to_quality.cli(
        ["--scale", "quick", "--out", str(out), "--resume", "--no-progress"]
    )
    assert again["rows"] == json.loads(json.dumps(results["rows"]))


def test_reading_a_trace():
    trace = [
        {"seconds": 1.0, "m_ssim": 0.3},
        {"seconds": 4.0, "m_ssim": 0.85},
        {"seconds": 90.0, "m_ssim": 0.6},  # quality can fall: the residual is what fell
    ]
    assert time_to_quality.time_to(trace, 0.5) == 4.0
    assert time_to_quality.time_to(trace, 0.9) is None
    assert time_to_quality.quality_at(trace, 0.5) is None
    assert time_to_quality.quality_at(trace, 60.0) == 0.85
    assert time_to_quality.quality_at(trace, 900.0) == 0.6  # what stopping then gives


def test_a_trace_samples_on_its_time_ladder():
    """Samples at the first iteration whose clock passes 0.25 s, then 0.375 s, 0.5625 s, ...
    (one sample however many ladder steps an iteration jumps), and renders the current
    reconstruction only then."""
    truth = rj.scenes.cube(0.5, extent=1.0, edge=1.0)
    views = rj.Viewpoints.grid(2, 2, polar_range=(0.4, 1.2))
    trace = runner.Trace(truth, views, rj.Radar(n_frequencies=4, n_tx=2, n_rx=2), 0.5)
    rendered = []

    def current():
        rendered.append(True)
        return truth

    for iteration, seconds in enumerate([0.1, 0.3, 0.35, 0.5, 1.0, 1.1], start=1):
        trace(iteration, seconds, current)
    assert [r["iteration"] for r in trace.records] == [2, 4, 5] and len(rendered) == 3
    assert all(r["m_ssim"] == pytest.approx(1.0) and r["p_rmse"] < 1e-3 for r in trace.records)
    # LSMR's monitor counts its steps, its history one entry per check (every 10 steps):
    # each sample reads the residual of the check it was taken at, the last closes at step 40
    trace.records = [{"iteration": k} for k in (10, 20, 30)]
    history = rj.solvers.History(np.array([0.8, 0.6, 0.5, 0.4]), np.arange(1.0, 5.0))
    lsmr = types.SimpleNamespace(
        history=history, stats={"check_every": 10}, seconds=4.0, scene=truth
    )
    records = trace.finish(lsmr)
    assert [r["iteration"] for r in records] == [10, 20, 30, 40]
    assert [r["residual"] for r in records] == pytest.approx([0.8, 0.6, 0.5, 0.4])


def test_the_compile_profile_attributes_compilation_to_the_running_test(
    tmp_path, monkeypatch, request
):
    """tests/compile_profile.py (the pytest plugin behind the suite's time budget): a program
    compiled while a test runs is charged to that test, and the report ranks tests by time."""
    import collections

    import compile_profile as profile
    import jax
    import jax.numpy as jnp
    from jax import monitoring

    fresh = collections.defaultdict  # the plugin's own tables are the suite's, if it is on
    monkeypatch.setattr(profile, "_seconds", fresh(lambda: fresh(float)))
    monkeypatch.setattr(profile, "_counts", fresh(lambda: fresh(int)))
    monkeypatch.setattr(profile, "_current", [])
    listening = request.config.pluginmanager.hasplugin("compile_profile")  # (-p): it listens
    if not listening:
        monitoring.register_event_duration_secs_listener(profile._listen)
    try:
        profile.pytest_runtest_logstart("t::fast", None)
        c = float(np.random.default_rng().uniform())  # a new program: no cache can hold it
        jax.jit(lambda x: jnp.sin(x) * c + 1.25)(jnp.arange(7.0)).block_until_ready()
        profile.pytest_runtest_logfinish("t::fast", None)
    finally:
        if not listening:
            monitoring.unregister_event_duration_listener(profile._listen)
    charged = profile._seconds["t::fast"]
    assert (
        charged["compile|jit(<lambda>)"] > 0
        and charged["wall|"] >= charged["compile|jit(<lambda>)"]
    )
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw7")
    monkeypatch.setattr(profile, "FOLDER", tmp_path)
    profile.pytest_sessionfinish(None)
    (tmp_path / "gw8.json").write_text(json.dumps({"t::slow": {"wall|": [100.0, 1]}}))
    text = profile.report(tmp_path, top=5)
    assert text.startswith("2 tests,") and text.index("t::slow") < text.index("t::fast")
    assert "<lambda> " in text.split("t::fast")[1]  # among its costliest programs, compiled once
    assert "×1" in text.split("t::fast")[1]


def test_a_sub_radar_sees_what_the_full_radar_sees_on_its_antennas_and_frequencies():
    """`benchmarks.support --screen` measures sub-radars as exact subsets of the full one:
    their signals are the full radar's at the kept elements and frequencies."""
    from benchmarks.support import sub_radar

    radar = rj.Radar(n_frequencies=7, n_tx=7, n_rx=4)
    points = rj.grid_points(1.0, 0.5)
    rho = np.random.default_rng(0).normal(size=len(points)).astype(np.complex64)
    views = rj.Viewpoints.grid(2, 2)
    sub, rows = sub_radar(radar, 3, 3)
    assert (sub.n_tx, sub.n_rx, sub.n_frequencies) == (2, 1, 3)
    full = np.asarray(rj.grt_operator(radar, views, points).mv(rho))
    part = np.asarray(rj.grt_operator(sub, views, points).mv(rho))
    np.testing.assert_allclose(
        part, full[(slice(None), *rows)], rtol=0, atol=1e-5 * abs(full).max()
    )
    for strides in ((2, 3), (3, 4)):
        with pytest.raises(ValueError, match="no exact sub-radar"):
            sub_radar(radar, *strides)
