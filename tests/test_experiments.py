"""The paper's experiments at their quick scale: every file is written, every number is
finite and in range, resuming repeats nothing; and the weak-target resolvability measure on
hand-made volumes."""

from __future__ import annotations

import dataclasses
import json
import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import compilations

import rift_jax as rj
from experiments import (
    complex_scenes,
    mismatch,
    replay,
    rift_ideas,
    runner,
    simple_scenes,
    stability,
    weak_target,
)
from experiments.runner import write_atomic

FILES = ("results.json", "results.md", "reconstructions.npz")
MIPS = ("reconstructions_xy.png", "reconstructions_xz.png", "training.png")
EXPERIMENTS = {
    "weak_target": (weak_target, ("weak_target.png", "profiles.png", "training.png")),
    "simple_scenes": (simple_scenes, MIPS),
    "complex_scenes": (complex_scenes, MIPS),
    "stability": (stability, ("stability.png",)),
    "mismatch": (mismatch, ("mismatch.png",)),
}


@pytest.fixture(scope="module", params=list(EXPERIMENTS))
def quick_run(request, tmp_path_factory):
    name = request.param
    module, figures = EXPERIMENTS[name]
    out = tmp_path_factory.mktemp(name)
    results = module.cli(["--scale", "quick", "--out", str(out), "--no-progress"])
    return name, module, out, results, figures


@pytest.mark.slow
def test_quick_scale_writes_every_file(quick_run):
    name, module, out, results, figures = quick_run
    for file in FILES + figures:
        assert (out / file).stat().st_size > 0, file
    shown = re.findall(r"^!\[[^\]]*\]\(([^)]+)\)$", (out / "results.md").read_text(), re.M)
    assert tuple(shown) == figures  # results.md shows its figures, each once, in order
    assert not list(out.glob(".*.tmp")), "a temporary file was left behind"
    saved = json.loads((out / "results.json").read_text())
    assert saved["experiment"] == name and saved["scale"] == "quick"
    assert saved["config"] == json.loads(json.dumps(dataclasses.asdict(module.SCALES["quick"])))
    assert {"rift_jax", "jax", "numpy", "python"} <= set(saved["versions"])
    assert len(saved["rows"]) == len(results["rows"]) > 0
    with np.load(out / "reconstructions.npz") as volumes:
        for row in saved["rows"]:
            volume = volumes[f"{row['scene']}/{row['run']}"]
            assert np.all(np.isfinite(volume)) and np.abs(volume).max() > 0
            assert volume.shape == volumes[f"truth/{row['scene']}"].shape


@pytest.mark.slow
def test_quick_scale_numbers_are_finite_and_in_range(quick_run):
    name, _, out, results, _ = quick_run
    for row in results["rows"]:
        assert -1 <= row["m_ssim"] <= 1
        assert 0 <= row["m_cos"] <= 1 + 1e-6
        assert 0 <= row["t_iou"] <= 1
        assert 0 <= row["p_rmse"] <= math.pi
        assert 0 <= row["residual"] < 10
        if row["method"] != "points":  # fit's check on a grid, kept to re-judge its warning
            assert 0 < row["coherence"] <= 1 + 1e-6
        assert row["wall_seconds"] > 0 and row["iterations"] >= 1
    text = (out / "results.md").read_text()
    assert all(row["run"] in text for row in results["rows"])
    if name == "weak_target":
        for row in results["rows"]:
            assert 0 <= row["weak_peak"] <= 1 and 0 <= row["strong_peak"] <= 1
            assert row["resolved"] == (row["weak_detected"] and row["dip"] >= 0.25)
            assert f"{row['scene']}**, {row['run']}: " in text
    elif name == "stability":
        check_stability_counts(out)
        check_shared_supports(results)
    elif name == "mismatch":
        check_mismatch_cells(results)
    else:
        scene = results["rows"][0]["scene"]
        assert f"| {scene} | RIFT(N)-10 beats LS-10 | " in text


def check_shared_supports(results):
    """``support="auto"`` is estimated once per dataset: in each cell (same scene, views and
    noise, and the noise's seed) one run estimates it, the others reuse it and run on as
    many points, and every run's ``fit_seconds`` counts the estimate."""
    cells = {}
    for row in results["rows"]:
        snr_db = row["options"].get("snr_db")
        cell = (row["scene"], row["n_train"], snr_db, row["seed"] if snr_db is not None else None)
        cells.setdefault(cell, []).append(row)
    assert len(cells) < len(results["rows"])  # some data are shared
    for rows in cells.values():
        assert [row["support_reused"] for row in rows].count(False) == 1
        assert len({row["points"] for row in rows}) == 1
        assert all(row["fit_seconds"] > row["support_seconds"] > 0 for row in rows)


@pytest.mark.slow  # as the experiments' other end-to-end checks
def test_shared_support_is_the_one_fit_estimates(small_cube):
    """The runner's shared estimate is `fit`'s own ``support="auto"`` on the same data:
    noisy signals, synthesised with the run's noise and seed."""
    radar, scene, train, _ = small_cube
    shared = runner.SharedSupports(radar)
    options = {"snr_db": 0.0}
    estimate = shared.get("cube", scene, train, 0.5, 3, options)
    again = shared.get("cube", scene, train, 0.5, 3, options)
    assert not estimate.reused and again.reused and again.mask is estimate.mask
    result = rj.fit(
        scene, train, radar=radar, method="lsmr", granularity=0.5, iterations=1, seed=3,
        snr_db=0.0, progress=False,
    )  # fmt: skip
    np.testing.assert_array_equal(estimate.mask, result.support)
    other_noise = shared.get("cube", scene, train, 0.5, 4, options)
    assert not other_noise.reused


def test_shared_support_makes_the_estimate_it_is_given(small_cube, monkeypatch):
    """The shared estimate takes the study's `estimate_support` options (the weak target's
    paper scale: 500 views, threshold 0.2, 1.5 floors); without any, it is `fit`'s own."""
    radar, scene, train, _ = small_cube
    asked = []

    def estimate(signal, viewpoints, grid, *, radar, **options):
        assert radar is small_cube[0]
        asked.append(options)
        return np.ones(grid.shape, bool)

    monkeypatch.setattr(rj, "estimate_support", estimate)
    options = {"max_views": 12, "threshold": 0.3, "floor_factor": 2.0}
    for given in (options, None):
        runner.SharedSupports(radar, given).get("cube", scene, train, 0.5, 0, {})
    assert asked == [options, {}]


def test_weak_target_hands_its_support_settings_to_the_estimate(tmp_path, monkeypatch):
    """The paper scale's estimate reads every training view, above the study's detection
    threshold and 1.5 floors; the study's settings reach the shared estimate through
    `execute` (stopped there: nothing is fitted) and its results page; a traced study,
    which makes no shared estimate, refuses them."""
    paper = weak_target.SCALES["paper"]
    assert paper.budget.support == "auto" and paper.support_estimate() == {
        "max_views": paper.n_train, "threshold": paper.threshold, "floor_factor": 1.5,
    }  # fmt: skip
    assert weak_target.SCALES["default"].support_estimate() == {}  # fit's own estimate
    assert paper.budget.describe(support=paper.support_estimate()).endswith(
        "from at most 500 views, threshold 0.2 of the backprojection's peak, at least 1.5 "
        "times the backprojection's median voxel)"
    )

    class Made(Exception):
        pass

    def shared(radar, options=None):
        raise Made(options)

    monkeypatch.setattr(runner, "SharedSupports", shared)
    quick = dataclasses.replace(weak_target.SCALES["quick"], support_views=7, support_floor=2.0)
    with pytest.raises(Made) as made:
        weak_target.main(quick, out=tmp_path, progress=False)
    assert made.value.args == ({"max_views": 7, "floor_factor": 2.0},)
    with pytest.raises(ValueError, match="`support` options need the shared estimate"):
        runner.execute(
            "weak_target", "quick", quick, {}, [], pool=None, radar=None, inverse=0.5,
            n_test=1, seed=0, out=tmp_path, report=None, trace={}, support={"max_views": 7},
        )  # fmt: skip


@pytest.mark.slow
def test_resume_repeats_nothing_and_checks_the_config(quick_run, monkeypatch):
    _, module, out, results, _ = quick_run

    def refuse(*args, **kwargs):
        raise AssertionError("a finished run was repeated")

    monkeypatch.setattr(runner, "fit_and_evaluate", refuse)
    again = module.cli(["--scale", "quick", "--out", str(out), "--resume", "--no-progress"])
    assert again["rows"] == json.loads(json.dumps(results["rows"]))
    with pytest.raises(SystemExit, match="another config or seed"):
        module.cli(["--scale", "quick", "--out", str(out), "--resume", "--seed", "1"])


def _legacy(row: dict) -> dict:
    """``row`` as files from before typed outcomes (95641d3) and per-row seeds held it (and
    before RIFT's `patience` defaulted to 10: a run of every epoch named none)."""
    stop = rj.solvers.Stop.from_json(row["stopped"])
    if row["method"].startswith("rift") and row["options"]["patience"] is None:
        row = row | {"options": {k: v for k, v in row["options"].items() if k != "patience"}}
    words = {
        "budget": "epochs" if row["method"].startswith("rift") else "iterations",
        "converged": "tolerance",
        "diverged": f"diverged at epoch {stop.at}",
        "zero signal": "zero signal",
    }[stop.outcome.value]
    kept = {k: v for k, v in row.items() if k not in ("seed", "remedies", "collapse")}
    return kept | {"stopped": words, "diverged": None}


def _had_old_form(row: dict, seed: int) -> bool:
    stop = rj.solvers.Stop.from_json(row["stopped"])
    steps = 1  # per history entry; LSMR's stopped counts its steps, one entry per check
    if row["method"] == "lsmr":
        steps = min(row["options"].get("check_every", 10), row["options"]["iterations"])
    ended = stop.outcome.value in ("diverged", "zero signal")
    ended = ended or stop.at == steps * row["iterations"]
    return row["seed"] == seed and ended


@pytest.mark.slow
def test_resume_keeps_runs_from_before_the_experiment_gained_settings(
    quick_run, monkeypatch, tmp_path
):
    """A file from an older version resumes: settings it lacks, at their defaults, are what
    it did; its rows in the old form are read; only the missing run is done. A kept run
    this config no longer asks for, or asks for otherwise, refuses."""
    _, module, out, results, _ = quick_run
    saved = json.loads((out / "results.json").read_text())
    cfg = module.SCALES["quick"]
    at_default = [f.name for f in dataclasses.fields(cfg) if getattr(cfg, f.name) == f.default]
    for key in at_default:  # as if added to the experiment since
        del saved["config"][key]
    # rows made with the file's seed, as older versions wrote them: read back as they are
    # now, but for what older rows did not hold. (Older versions ended a run at its last
    # history entry; a row where they differ, after RIFT's collapse retry, has no old form.)
    rows = [_legacy(r) if _had_old_form(r, saved["seed"]) else r for r in saved["rows"]]
    assert any(old is not row for old, row in zip(rows, saved["rows"], strict=True))
    for old, row in zip(rows, saved["rows"], strict=True):
        expected = {k: v for k, v in row.items() if old is row or k not in ("remedies", "collapse")}
        assert runner._upgrade(old, saved["seed"]) == expected
    missing = saved["rows"][-1]
    saved["rows"] = rows[:-1]
    older = tmp_path / "older"
    older.mkdir()
    (older / "reconstructions.npz").write_bytes((out / "reconstructions.npz").read_bytes())

    def resume_with(changed: dict):
        (older / "results.json").write_text(json.dumps(changed))
        module.cli(["--scale", "quick", "--out", str(older), "--resume", "--no-progress"])

    class Asked(Exception):
        pass

    asked = []

    def record(scene, train, test, *, method, options, **kwargs):
        # support="auto" reaches fit as the mask estimated once for the run's data
        if isinstance(options.get("support"), np.ndarray):
            options = options | {"support": "auto"}
        asked.append((method, len(train), json.loads(json.dumps(options))))
        raise Asked  # stop before the run: its fit is not the point

    monkeypatch.setattr(runner, "fit_and_evaluate", record)
    with pytest.raises(Asked):
        resume_with(saved)
    assert asked[0] == (missing["method"], missing["n_train"], missing["options"])

    first = saved["rows"][0]
    with pytest.raises(SystemExit, match="made with other settings"):
        resume_with(saved | {"rows": [first | {"n_train": first["n_train"] + 1}]})
    with pytest.raises(SystemExit, match="not one this config asks for"):
        resume_with(saved | {"rows": [first | {"run": "LS-99999"}]})
    with pytest.raises(SystemExit, match="no longer a setting"):
        resume_with(saved | {"config": saved["config"] | {"retired": 1}})


def test_the_experiments_choose_rifts_active_set_as_fit_does():
    """Every experiment's RIFT that trains an active set chooses it first no sooner than
    `fit`'s default does (after `recheck_every` epochs on every point): chosen after 2
    epochs, the weak target's set dropped the weaker bar at 3:1 and 4:1 before the field
    had learned it (docs/experiments.md). Not the quick scales: the tests' few epochs
    choose it sooner, so that they run it."""
    default = rj.solvers.Recipe().recheck_every
    studies = (weak_target, simple_scenes, complex_scenes)
    budgets = [s.SCALES[k].budget for s in studies for k in s.SCALES if k != "quick"]
    pruned = [b for b in budgets if b.rift_prune is not None]
    assert weak_target.SCALES["default"].budget in pruned and len(pruned) >= 3
    assert all(b.rift(500)["recheck_every"] >= default for b in pruned)


def test_the_experiments_name_rifts_patience():
    """`fit` stops RIFT once converged (patience 10), prunes (0.05) and estimates a support
    by default; the experiments say what they do (every step, or the paper scale's 10; the
    whole grid or the support; the loss), so their committed results stay what the code
    makes, and rows from before name none: they ran every epoch, on every point, with the
    robust loss."""
    assert runner.rift_options(100, 200)["patience"] is None
    assert runner.rift_options(100, 200)["loss"] == rj.solvers.Recipe().loss
    plain = runner.Budget(1, 4)
    assert plain.rift(100)["patience"] is None and plain.rift(100)["prune"] is None
    assert plain.ls()["support"] is None and plain.fista()["support"] is None
    paper = runner.Budget(1, 4, **runner.PAPER_STOPPING).rift(100)
    assert paper["patience"] == 10 and paper["prune"] == 0.05 and paper["support"] == "auto"
    stop = rj.solvers.Stop(rj.solvers.Outcome.BUDGET, 3).to_json()
    row = {"scene": "s", "run": "RIFT(N)-1", "method": "rift-n", "iterations": 3}
    named = {"epochs": 3, "patience": 10, "prune": 0.05, "loss": "mse", "support": "auto"}
    row |= {"stopped": stop, "seed": 0, "options": named}
    assert runner._upgrade(row, seed=0) == row
    older = row | {"options": {"epochs": 3}}
    expected = {"epochs": 3, "patience": None, "prune": None, "loss": "robust", "support": None}
    assert runner._upgrade(older, seed=0)["options"] == expected
    paper = older | {"options": {"epochs": 3, "recipe": "paper"}}
    assert runner._upgrade(paper, seed=0)["options"]["loss"] == "paper"
    lsmr = row | {"method": "lsmr", "options": {"iterations": 30, "support": "auto"}}
    lsmr |= {"stopped": rj.solvers.Stop(rj.solvers.Outcome.BUDGET, 30).to_json()}
    assert runner._upgrade(lsmr, seed=0) == lsmr  # 3 checks of 10 steps
    older_lsmr = lsmr | {"options": {"iterations": 30}}
    assert runner._upgrade(older_lsmr, seed=0)["options"] == {"iterations": 30, "support": None}
    # before 2d75a99 LSMR's `stopped` counted checks: 3 then, 30 steps now (4 after a divergence)
    for outcome, then, now in (("budget", 3, 30), ("diverged", 4, 40), ("zero signal", 0, 0)):
        counted = lsmr | {"stopped": {"outcome": outcome, "at": then}}
        assert runner._upgrade(counted, seed=0)["stopped"] == {"outcome": outcome, "at": now}


def test_resume_refuses_a_changed_setting_unless_it_only_shapes_the_runs():
    @dataclasses.dataclass(frozen=True)
    class Inner:
        a: int = 1

    @dataclasses.dataclass(frozen=True)
    class Config:
        extent: float
        runs: tuple[int, ...] = ()
        inner: Inner = Inner()
        flag: bool = False
        needed: int = dataclasses.field(default_factory=lambda: 3)

    cfg = Config(2.0, runs=(10, 20), flag=False)
    saved = json.loads(json.dumps(dataclasses.asdict(cfg)))
    changed = runner._changed_setting
    assert changed(cfg, saved, ()) is None
    assert changed(cfg, saved | {"runs": [10]}, ("runs",)) is None  # a run added
    assert "runs" in changed(cfg, saved | {"runs": [10]}, ())
    assert "extent: 1.0, now 2.0" in changed(cfg, saved | {"extent": 1.0}, ("runs",))
    assert "inner" in changed(cfg, saved | {"inner": {"a": 2}}, ())
    for key in ("flag", "inner", "needed"):  # added since, at their defaults: as before
        assert changed(cfg, {k: v for k, v in saved.items() if k != key}, ()) is None
    older = {k: v for k, v in saved.items() if k != "flag"}
    assert "flag: new" in changed(dataclasses.replace(cfg, flag=True), older, ())
    assert "extent: new, and without a default" in changed(cfg, {}, ())
    assert "gone: no longer a setting" in changed(cfg, saved | {"gone": 0}, ())


def test_the_environment_line_names_every_commit_a_resumed_file_ran():
    versions = {"cpu_count": 2, "devices": ["cpu:0"], "rift_jax": "0", "jax": "0", "python": "3"}
    results = {"seed": 0, "rows": [{}], "wall_seconds": 60.0, "versions": versions}
    assert "commit" not in runner.environment_line(results)  # not from a git checkout
    results["versions"] = versions | {"git_commit": "a" * 40}
    assert runner.environment_line(results).endswith(" Code at commit aaaaaaa.")
    results["resumed_with"] = [{"git_commit": "a" * 40}, {"git_commit": "b" * 40}]
    line = runner.environment_line(results)
    assert line.endswith(" Code at commit aaaaaaa, resumed at bbbbbbb.")
    assert "1 runs in 1.0 min (fit + evaluation) on 2 CPU cores (cpu:0);" in line
    results["versions"] |= {"matmul_rate_gmacs": 12.34}  # recorded since: the day's speed
    line = runner.environment_line(results)
    assert "on 2 CPU cores (cpu:0), its complex64 matmul at 12.3 G/s;" in line


def test_the_environment_line_names_the_accelerator_and_an_unfinished_study():
    """A GPU run says which GPU, and where it was resumed; a study stopped early says how
    many of its runs it holds."""
    versions = {"cpu_count": 16, "devices": ["cuda:0"], "device_kind": "NVIDIA H100 80GB HBM3"}
    versions |= {"rift_jax": "0", "jax": "0", "python": "3"}
    results = {"seed": 0, "rows": [{}] * 8, "wall_seconds": 60.0, "versions": versions}
    line = runner.environment_line(results | {"planned_runs": 12})
    assert "8 of 12 runs (unfinished) in 1.0 min" in line
    assert "on 1 × NVIDIA H100 80GB HBM3 (cuda:0) and 16 CPU cores;" in line
    assert "8 runs in" in runner.environment_line(results | {"planned_runs": 8})
    cpu = {"cpu_count": 2, "devices": ["cpu:0", "cpu:1"], "device_kind": "cpu"}
    resumed = results | {"resumed_with": [versions, cpu]}  # finished on a CPU
    assert "CPU cores, resumed on 2 CPU cores (cpu:0, cpu:1);" in runner.environment_line(resumed)


def _study_folder(folder, rows, seed=0, first=0, kind="NVIDIA H200", **row):
    """A study's --out folder holding ``rows`` (scene, run) of 30 s each (and ``row``'s
    fields), run on a GPU of ``kind``, with a volume for each run (the k-th all
    ``first + k``)."""
    versions = {"cpu_count": 16, "devices": ["cuda:0"], "device_kind": kind}
    versions |= {"rift_jax": "0", "jax": "0", "python": "3"}
    results = {"experiment": "stability", "scale": "default", "config": {"extent": 4.8}}
    results |= {"seed": seed, "wall_seconds": 30.0 * len(rows), "versions": versions}
    results |= {"rows": [{"scene": s, "run": r, "wall_seconds": 30.0} | row for s, r in rows]}
    results |= {"histories": {f"{s}/{r}": {"loss": [1.0]} for s, r in rows}, "failures": 0}
    results |= {"notes": {"matmul": kind}, "part": [1, 2]}
    runner.write_json(folder / "results.json", results)
    volumes = {f"{s}/{r}": np.full(3, first + k, np.complex64) for k, (s, r) in enumerate(rows)}
    runner.write_npz(folder / "reconstructions.npz", volumes | {"truth/cube": np.ones(3)})


def test_merge_joins_the_parts_of_a_study_and_refuses_two_studies(tmp_path):
    from experiments import merge

    _study_folder(tmp_path / "a", [("cube", "FISTA 10"), ("cube", "LSMR 10")])
    # b resumed from a copy of a's first run (kept once), on another GPU; its own run
    # reused a support estimate of 5 s that an earlier run of b made
    _study_folder(tmp_path / "b", [("cube", "FISTA 10")])
    b = json.loads((tmp_path / "b" / "results.json").read_text())
    b["rows"].append({"scene": "sphere", "run": "FISTA 10", "wall_seconds": 30.0,
                      "support_reused": True, "support_seconds": 5.0})  # fmt: skip
    b["histories"]["sphere/FISTA 10"] = {"loss": [1.0]}
    b["resumed_with"] = [b["versions"] | {"device_kind": "NVIDIA H100"}]
    runner.write_json(tmp_path / "b" / "results.json", b)
    runner.write_npz(tmp_path / "b" / "reconstructions.npz", {
        "cube/FISTA 10": np.zeros(3, np.complex64), "sphere/FISTA 10": np.ones(3, np.complex64),
        "truth/cube": np.ones(3),
    })  # fmt: skip
    merged = merge.merge(tmp_path / "all", [tmp_path / "a", tmp_path / "b"])
    saved = json.loads((tmp_path / "all" / "results.json").read_text())
    assert saved == json.loads(json.dumps(merged))
    runs = [(r["scene"], r["run"]) for r in saved["rows"]]
    assert runs == [("cube", "FISTA 10"), ("cube", "LSMR 10"), ("sphere", "FISTA 10")]
    assert set(saved["histories"]) == {f"{s}/{r}" for s, r in runs}
    assert saved["wall_seconds"] == 85.0  # 3 runs of 30 s, less the reused estimate
    assert [p["runs"] for p in saved["parts"]] == [2, 2]
    assert "failures" not in saved and "part" not in saved  # the resumed study's own
    assert saved["parts"][1]["notes"] == [{"matmul": "NVIDIA H200"}]
    with np.load(tmp_path / "all" / "reconstructions.npz") as volumes:
        assert set(volumes.files) == {f"{s}/{r}" for s, r in runs} | {"truth/cube"}
        np.testing.assert_array_equal(volumes["sphere/FISTA 10"], np.ones(3))  # b's own
    line = runner.environment_line(saved)
    assert "3 runs (in 2 parts run side by side; the time is their sum) in 1.4 min" in line
    assert "NVIDIA H200 (cuda:0) and 16 CPU cores, resumed on 1 × NVIDIA H100" in line

    _study_folder(tmp_path / "again", [("cube", "LSMR 10")], first=1)  # the same volume...
    _study_folder(tmp_path / "rerun", [("cube", "LSMR 10")], first=1, fit_seconds=2.0)
    _study_folder(tmp_path / "seed1", [("cube", "RIFT(N) 10")], seed=1)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "results.json").write_text("{}")
    for out, parts, message in (
        ("joined", ["a", "rerun"], "cube/LSMR 10 was measured in two parts"),  # ... timed anew
        ("joined", ["a", "seed1"], r"another study \(seed 1"),
        ("joined", ["a", "missing"], "has no results.json"),
        ("joined", ["a", "a"], "named twice"),
        ("a", ["a", "b"], "`out` .* is one of the parts"),
        ("full", ["a", "b"], "already holds a study"),
    ):
        with pytest.raises(ValueError, match=message):
            merge.merge(tmp_path / out, [tmp_path / p for p in parts])
    assert not (tmp_path / "joined").exists()  # refused before anything was written
    assert len(merge.merge(tmp_path / "joined", [tmp_path / "a", tmp_path / "again"])["rows"]) == 2


def test_merge_puts_replayed_runs_in_place_of_the_grids(tmp_path):
    """``--replace``: a replay's runs take the place of the study's runs of the same scene
    and label (row, reconstruction and history; their comparison with the grid dropped, the
    time counted anew). A replay covers some of the grid's scenes; one of another study,
    of no run, of a run already replaced, or at other options stops the merge."""
    from experiments import merge

    same = dict(method="fista", options={"support": "auto"})
    _study_folder(tmp_path / "grid", [("cube", "FISTA 10"), ("cube", "LSMR 10")], **same)
    grid = json.loads((tmp_path / "grid" / "results.json").read_text())
    grid["config"] |= {"scenes": ["cube", "sphere"]}
    runner.write_json(tmp_path / "grid" / "results.json", grid)

    def replay(name, rows, config=None, **row):
        folder = tmp_path / name
        row = same | {"wall_seconds": 10.0, "grid": 0.1, "failed": ""} | row
        _study_folder(folder, rows, first=7, **row)
        results = json.loads((folder / "results.json").read_text())
        config = config or {"extent": 4.8, "scenes": ["cube"]}  # the scenes it replayed
        results |= {"experiment": "replay", "config": config}
        results["config"] |= {"replay_method": "fista", "replay_options": {}}
        runner.write_json(folder / "results.json", results)
        return folder

    fista = replay("fista", [("cube", "FISTA 10")])
    merged = merge.merge(tmp_path / "today", [tmp_path / "grid"], [fista])
    rows = {r["run"]: r for r in merged["rows"]}
    assert list(rows) == ["FISTA 10", "LSMR 10"]  # in the grid's order
    assert rows["FISTA 10"]["wall_seconds"] == 10.0 and "grid" not in rows["FISTA 10"]
    assert "failed" not in rows["FISTA 10"]  # the report judges anew
    assert merged["wall_seconds"] == 40.0  # 30 s replaced by 10 s
    assert merged["parts"][-1]["replaced"] == 1
    assert "2 runs (1 of them replayed later, in 1 replays)" in runner.environment_line(merged)
    with np.load(tmp_path / "today" / "reconstructions.npz") as volumes:
        np.testing.assert_array_equal(volumes["cube/FISTA 10"], np.full(3, 7))
        np.testing.assert_array_equal(volumes["cube/LSMR 10"], np.full(3, 1))
    other = replay("other", [("cube", "FISTA 10")], config={"extent": 2.4})
    pier = {"extent": 4.8, "scenes": ["pier"]}  # a scene the grid did not run
    elsewhere = replay("elsewhere", [("cube", "FISTA 10")], config=pier)
    nowhere = replay("nowhere", [("sphere", "FISTA 10")])
    tuned = replay("tuned", [("cube", "FISTA 10")], options={"support": "auto", "sparsity": 0.1})
    for out, replays, message in (
        ("a", [other], "is no replay of the parts' study"),
        ("b", [elsewhere], "is no replay of the parts' study"),
        ("c", [nowhere], "sphere/FISTA 10 replaces no run of the parts"),
        ("d", [fista, replay("again", [("cube", "FISTA 10")])], "a run already replaced"),
        ("e", [tuned], "only a replay at the study's own options"),
    ):
        with pytest.raises(ValueError, match=message):
            merge.merge(tmp_path / out, [tmp_path / "grid"], replays)


def test_resume_reads_the_free_text_outcomes_of_older_files():
    """Rows from before typed outcomes said why a run ended in words (95641d3)."""
    Stop, Outcome = rj.solvers.Stop, rj.solvers.Outcome
    base = {"scene": "s", "run": "LS-1", "iterations": 7, "diverged": None}
    for legacy, expected in (
        ("iterations", Stop(Outcome.BUDGET, 7)),
        ("epochs", Stop(Outcome.BUDGET, 7)),
        ("tolerance", Stop(Outcome.CONVERGED, 7)),
        ("diverged at epoch 3", Stop(Outcome.DIVERGED, 3)),
        ("zero signal", Stop(Outcome.ZERO_SIGNAL, 0)),
    ):
        row = runner._upgrade(base | {"stopped": legacy}, seed=5)
        assert row == {"scene": "s", "run": "LS-1", "iterations": 7, "seed": 5} | {
            "stopped": expected.to_json()
        }, legacy
    typed = base | {"stopped": Stop(Outcome.CONVERGED, 2).to_json(), "seed": 1}
    assert runner._upgrade(typed, seed=5) == typed  # its own seed kept
    with pytest.raises(SystemExit, match="cannot read"):
        runner._upgrade(base | {"stopped": "gave up"}, seed=0)


def test_draw_shares_the_test_views_and_nests_the_training_views():
    pool = rj.Viewpoints.grid(10, 10)
    train_a, test_a = runner.draw(pool, 20, 10, seed=3)
    train_b, test_b = runner.draw(pool, 50, 10, seed=3)

    def key(views):
        return set(
            zip(np.asarray(views.azimuth).tolist(), np.asarray(views.polar).tolist(), strict=True)
        )

    assert key(test_a) == key(test_b)
    assert key(train_a) < key(train_b)
    assert not key(train_b) & key(test_b)
    with pytest.raises(ValueError, match="exceed the 100"):
        runner.draw(pool, 95, 10, seed=0)


def test_rift_options_give_every_run_the_same_steps_and_three_halvings():
    from rift_jax._solvers.inr.optimizer import halving_steps, schedule
    from rift_jax._solvers.inr.recipe import Recipe

    for n, steps in ((100, 200), (1000, 200), (500, 300), (1000, 10000), (40, 150), (10, 200)):
        options = runner.rift_options(n, steps=steps)
        per_epoch = -(-n * Recipe(**options).passes(n) // options["batch_views"])
        total = options["epochs"] * per_epoch
        assert total == pytest.approx(steps, rel=0.2)
        rate = schedule(1.0, halving_steps(Recipe(**options), per_epoch))
        rates = sorted({float(rate(step)) for step in range(total)})
        assert rates == [0.125, 0.25, 0.5, 1.0], (n, steps, rates)
    # from fewer views than an epoch's, one pass per epoch: a small budget is its own count
    assert runner.rift_options(10, steps=6)["epochs"] == 6
    assert runner.rift_options(10, steps=6)["epoch_views"] is None
    assert "epoch_views" not in runner.rift_options(100, steps=6)  # as before it existed


def _bars(strong: float, weak: float, gap_fill: float, weak_fill: float = 0.0):
    """A 13³ volume on ±1.44 m with the weak-target bars at the inverse grid's points."""
    scene = rj.scenes.weak_target(0.5, 0.12, extent=1.44)
    bars = weak_target.footprints(scene)
    axis = rj.Scene.empty(1.44, 0.24).axis()
    volume = np.zeros((13, 13, 13), np.complex64)
    y = np.abs(axis) <= 1.2
    z = np.abs(axis) <= 0.24
    for (lo, hi), value in ((bars[0][:2], strong), (bars[1][:2], weak), ((-0.5, 0.5), gap_fill)):
        x = (axis >= lo - 1e-6) & (axis <= hi + 1e-6)
        volume[np.ix_(x, y, z)] = value
    volume[np.ix_(axis > 0, ~y, z)] = weak_fill  # clutter off the bars' footprint is ignored
    return volume, axis, bars


def test_resolvability_on_hand_made_volumes():
    # Two bars with an empty gap: resolved at any detectable contrast.
    volume, axis, bars = _bars(1.0, 0.3, 0.0, weak_fill=0.9)
    r = weak_target.resolvability(volume, axis, *bars)
    assert r["strong_peak"] == pytest.approx(1.0) and r["weak_peak"] == pytest.approx(0.3)
    assert r["gap_mean"] == 0 and r["dip"] == pytest.approx(1.0)
    assert 0.72 <= r["weak_side_peak_x"] <= 1.2  # the weak bar's cells
    assert r["weak_detected"] and r["resolved"]
    assert len(r["profile"]) == axis.size
    # The gap filled to 90% of the weak bar: detected but not resolved (dip 10% < 25%).
    r = weak_target.resolvability(*_bars(1.0, 0.5, 0.45)[0:1], axis, *bars)
    assert r["dip"] == pytest.approx(0.1, abs=1e-6) and r["weak_detected"]
    assert not r["resolved"]
    # A weak side brighter beyond the bar than on it: the peak's place says so.
    spill, *_ = _bars(1.0, 0.3, 0.0)
    spill[np.ix_(axis > 1.3, np.abs(axis) <= 1.2, np.abs(axis) <= 0.24)] = 0.5
    assert weak_target.resolvability(spill, axis, *bars)["weak_side_peak_x"] == pytest.approx(1.44)
    # Detection is relative to the stronger bar's peak in the same profile.
    r = weak_target.resolvability(*_bars(0.5, 0.15, 0.0)[0:1], axis, *bars)
    assert r["weak_detected"] and r["weak_peak"] / r["strong_peak"] == pytest.approx(0.3)
    # The weak bar below the threshold: not detected, hence not resolved, dip or no dip.
    r = weak_target.resolvability(*_bars(1.0, 0.1, 0.0)[0:1], axis, *bars, threshold=0.2)
    assert not r["weak_detected"] and not r["resolved"]
    assert "below the detection threshold" in weak_target.verdict(r, weak_target.SCALES["default"])


def test_write_atomic_leaves_the_old_file_when_writing_fails(tmp_path):
    path = write_atomic(tmp_path / "a.json", "old")

    with pytest.raises(TypeError):  # fails inside the write, after the temp file exists
        write_atomic(path, object())
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def check_stability_counts(out):
    """results.json carries the stability study's failures as an integer, and results.md
    says the same."""
    saved = json.loads((out / "results.json").read_text())
    assert isinstance(saved["failures"], int)
    assert saved["failures"] == sum(bool(r["failed"]) for r in saved["rows"])
    text = (out / "results.md").read_text()
    counted = sum(r["method"] != stability.BASELINE for r in saved["rows"])
    assert f"Failures: {saved['failures']} of {counted} counted runs" in text


def test_stability_judges_a_run_against_its_cell():
    """A non-finite metric, an m-SSIM under half its cell's median, or under 0.5 where the
    cell's best is ≥ 0.9, fails a run; never the baseline's (reported, not counted)."""
    row = {"scene": "s", "options": {}, "m_cos": 0.5, "t_iou": 0.5, "p_rmse": 1.0, "residual": 1}
    row |= {"n_train": 10, "seed": 0}
    rows = [row | {"m_ssim": v, "method": "m"} for v in (0.8, 0.7, 0.3, 0.9)]
    rows.append(row | {"m_ssim": 0.8, "method": "m", "residual": float("nan")})
    rows.append(row | {"m_ssim": 0.1, "method": stability.BASELINE})  # in the median only
    rows.append(row | {"m_ssim": 0.1, "method": "m", "n_train": 30})  # a cell of its own
    verdicts = [r["failed"] for r in stability.judge(rows)]
    assert verdicts[:2] == [None, None] and verdicts[3] is None
    assert "half the cell's median 0.750" in verdicts[2] and verdicts[4] == "non-finite metric"
    assert verdicts[5] is None and verdicts[6] is None  # the baseline; alone in its cell
    strong = [row | {"m_ssim": v, "method": "m"} for v in (0.95, 0.45, 0.6)]
    assert [r["failed"] for r in stability.judge(strong)][1].endswith("best is 0.950")


def test_stability_runs_every_method_at_its_defaults_on_shared_data():
    """The stress grid's named defaults are still `fit`'s and `Recipe`'s; every cell runs
    every method with the same seed, and every seed runs at every level of every factor."""
    import inspect

    assert inspect.signature(rj.fit).parameters["support"].default == "auto"
    assert stability.DEFAULTS == {"support": "auto"}
    recipe = rj.solvers.Recipe()
    assert stability.RIFT_DEFAULTS == {
        "loss": recipe.loss,
        "prune": recipe.prune,
        "patience": recipe.patience,
        "epoch_views": recipe.epoch_views,
    }
    cfg = stability.SCALES["default"]
    asked = stability.runs(cfg)
    cells = {}
    for run in asked:
        cell = (run.scene, run.n_train, run.options.get("snr_db"))
        cells.setdefault(cell, set()).add((run.method, run.seed))
    assert len(cells) == len(cfg.scenes) * len(cfg.views) * len(cfg.snrs)
    for methods_seeds in cells.values():
        seeds = {seed for _, seed in methods_seeds}
        assert len(seeds) == cfg.seeds_per_cell
        assert methods_seeds == {(m, s) for m in cfg.methods for s in seeds}
    for level in ("scene", "n_train", "snr"):
        index = {"scene": 0, "n_train": 1, "snr": 2}[level]
        by_level = {}
        for cell, methods_seeds in cells.items():
            by_level.setdefault(cell[index], set()).update(s for _, s in methods_seeds)
        assert all(seen == set(cfg.seeds) for seen in by_level.values()), level


def test_stability_win_rates_count_shared_runs_only():
    base = {"scene": "s", "options": {}, "seed": 0}
    rows = [
        base | {"n_train": 10, "method": "a", "m_ssim": 0.5},
        base | {"n_train": 10, "method": "b", "m_ssim": 0.4},
        base | {"n_train": 30, "method": "a", "m_ssim": 0.5},
        base | {"n_train": 30, "method": "b", "m_ssim": 0.6},
        base | {"n_train": 100, "method": "a", "m_ssim": 0.9},  # b did not run: no comparison
    ]
    for row in rows:
        row["noise"] = "noise-free"
    assert stability.win_rates(rows, ("a", "b"))[("all", "a", "b")] == (1, 2)
    by_views = stability.win_rates(rows, ("a", "b"), "n_train")
    assert by_views[(10, "a", "b")] == (1, 1) and by_views[(30, "b", "a")] == (1, 1)
    assert (100, "a", "b") not in by_views


def check_mismatch_cells(results):
    """The mismatch study ran every truth x grid x noise x method once, each truth on its own
    grid: the point truth's image is its spread, of the same total reflectivity."""
    cfg = mismatch.SCALES["quick"]
    cells = mismatch._cells(results["rows"])
    expected = {
        (t, g, mismatch.noise_name(s), mismatch.LABELS[m])
        for t in cfg.truths
        for g in cfg.resolutions
        for s in cfg.snrs
        for m in cfg.methods
    }
    assert set(cells) == expected
    points = mismatch.point_scatterers(cfg.n_scatterers, cfg.extent, results["seed"])
    spread = np.asarray(points.resample(cfg.resolutions[0]).reflectivity)
    total = complex(np.sum(np.asarray(points.reflectivity)))
    assert complex(np.sum(spread)) == pytest.approx(total, rel=1e-5)


def test_release_compiled_programs_drops_them_near_the_mapping_limit(caplog):
    """A long study drops JAX's compiled programs once its memory mappings near the
    kernel's limit (LLVM then fails to compile): past the share it clears, and a program
    compiles again; below it nothing is dropped."""
    twice = jax.jit(lambda x: 2 * x + 1)
    twice(jnp.ones(3))
    assert not runner.release_compiled_programs(share=1e9)
    assert compilations(caplog, lambda: twice(jnp.ones(3))) == []
    assert runner.release_compiled_programs(share=0.0)
    assert compilations(caplog, lambda: twice(jnp.ones(3)))


def test_rift_ideas_run_on_their_stress_grid_cells_data():
    """Every idea runs beside the RIFT(N) run of its stress-grid cell, on the same data
    (scene, views, noise, seed) with one option more, and its label names its variant."""
    cfg = rift_ideas.SCALES["default"]
    runs = rift_ideas.runs(cfg)
    grid = {(r.scene, r.label): r for r in stability.runs(stability.SCALES["default"])}
    assert len(runs) == 10 * 2 * len(rift_ideas.VARIANTS)  # scenes × (10, 30 views)
    for run in runs:
        variant = rift_ideas.variant({"run": run.label})
        assert variant in rift_ideas.VARIANTS
        assert run.n_train in (10, 30) and run.options["snr_db"] == rift_ideas.SNR
        base = run.label.replace(variant, "FISTA" if variant == "FISTA" else "RIFT(N)", 1)
        plain = grid[run.scene, base]  # the stress grid's own run of that cell
        assert (plain.n_train, plain.seed) == (run.n_train, run.seed)
        extra = rift_ideas.IDEAS.get(variant, {})
        assert run.options == plain.options | extra


def test_replay_repeats_the_grids_own_runs_with_the_options_added():
    """A replayed cell runs the stress grid's own run of the method there (scene, views,
    noise, seed) with the options added; a cell the grid lacks, or a method it does not
    run, is refused by name."""
    cfg = stability.SCALES["default"]
    cells = [replay.parse_cell("cube:30:none"), replay.parse_cell("parking_lot:100:-10")]
    assert cells == [("cube", 30, None), ("parking_lot", 100, -10.0)]
    asked = replay.runs(cfg, "rift-n", cells, {"loss": "mse"})
    grid = {(r.scene, r.label): r for r in stability.runs(cfg)}
    assert len(asked) == 2
    for run in asked:
        plain = grid[run.scene, run.label]
        assert plain.method == "rift-n" and (plain.n_train, plain.seed) == (run.n_train, run.seed)
        assert run.options == plain.options | {"loss": "mse"}
    with pytest.raises(ValueError, match="has no cell cube:20:none"):
        replay.runs(cfg, "rift-n", [("cube", 20, None)], {})
    with pytest.raises(ValueError, match="`--method` must be one of"):
        replay.runs(cfg, "rift-x", cells, {})
    with pytest.raises(ValueError, match="SCENE:VIEWS:NOISE"):
        replay.parse_cell("cube:30")
    several = dataclasses.replace(cfg, seeds_per_cell=None)  # every seed of a cell
    assert {run.seed for run in replay.runs(several, "fista", cells[:1], {})} == {0, 1, 2}


def test_replay_runs_fits_default_where_the_grid_ran_fista():
    """``--method auto``, which the grid does not run, runs in each cell on FISTA's run's
    data (views, seed, noise) with `fit`'s defaults (and, at the quick scale, each
    candidate with the scale's budget), labelled as its own method."""
    for scale in ("default", "quick"):
        cfg = stability.SCALES[scale]
        cell = (cfg.scenes[0], cfg.views[-1], 0.0)
        (run,) = replay.runs(cfg, "auto", [cell], {})
        (fista,) = [r for r in stability.runs(cfg) if r.method == "fista"
                    and (r.scene, r.n_train, r.options.get("snr_db")) == cell]  # fmt: skip
        assert run.method == "auto" and run.label == fista.label.replace("FISTA", "Auto")
        assert (run.n_train, run.seed) == (fista.n_train, fista.seed)
        expected = stability.DEFAULTS | {"snr_db": 0.0}
        if scale == "quick":  # the scale's small budgets, per candidate, FISTA first
            budgets = dict(cfg.budgets)
            expected |= {"candidates": {m: dict(budgets[m]) for m in ("fista", "rift-n")}}
        assert run.options == expected
        if scale == "quick":  # in fit's order: the first keeps its place unless beaten clearly
            assert list(run.options["candidates"]) == ["fista", "rift-n"]


def test_replay_says_what_auto_chose_and_on_what_evidence():
    """An auto replay's row says the method chosen (and any whose final fit gave way), each
    candidate's held-out residual, and how clearly the later ones beat the first."""
    scores = {"fista": {"holdout_residual": 0.99602},
              "rift-n": {"holdout_residual": 0.99599, "paired_t": 0.41}}  # fmt: skip
    row = {"selection": {"chosen": "fista", "rejected": {"rift-n": "collapsed"}, "scores": scores}}
    assert replay._chose(row) == "FISTA, not RIFT(N)"
    assert replay._held_out(row) == "FISTA 0.99602 / RIFT(N) 0.99599 (t +0.4)"
    assert replay._held_out({"selection": {"scores": {}}}) == "– (unscored)"


def test_replay_names_the_cells_best_other_method():
    """``best``: the best of the grid's counted methods in the cell on the same seed
    (Kaczmarz, the baseline, and the replayed method's own runs left out)."""
    base = {"options": {}, "residual": 0.9, "m_cos": 0.5, "t_iou": 0.5, "p_rmse": 1.0,
            "noise": "noise-free", "scene": "cube", "n_train": 30}  # fmt: skip
    grid = [base | {"seed": seed, "method": m, "m_ssim": v} for seed, m, v in (
        (1, "rift-n", 0.8), (1, "fista", 0.6), (1, "kaczmarz", 0.95), (2, "fista", 0.99),
    )]  # fmt: skip
    (row,) = replay.compare([base | {"seed": 1, "method": "auto", "m_ssim": 0.7}], grid, "auto")
    assert (row["best"], row["best_method"], row["grid"]) == (0.8, "rift-n", None)


def test_replay_judges_a_replayed_run_with_the_grids_other_methods():
    """The replay stands beside the grid's own run and FISTA's on the same seed, and fails
    by the grid's rule against the other methods of its cell, its own method's grid runs
    left out (it stands in for them)."""
    base = {"options": {}, "residual": 0.9, "m_cos": 0.5, "t_iou": 0.5, "p_rmse": 1.0,
            "noise": "noise-free"}  # fmt: skip
    grid = [
        base | {"scene": "cube", "n_train": n, "seed": seed, "method": m, "m_ssim": v}
        for n in (30, 100)
        for seed, m, v in (
            (1, "rift-n", 0.95),
            (2, "rift-n", 0.99),
            (1, "fista", 0.6),
            (1, "lsmr", 0.5),
            (1, "kaczmarz", 0.4),
        )  # fmt: skip
    ]
    good = base | {"scene": "cube", "n_train": 30, "seed": 1, "method": "rift-n", "m_ssim": 0.7}
    bad = good | {"n_train": 100, "m_ssim": 0.3}
    judged = replay.compare([good, bad], grid, "rift-n")
    assert [(r["grid"], r["fista"]) for r in judged] == [(0.95, 0.6)] * 2  # seed 1's runs
    assert judged[0]["failed"] == ""  # judged, and passed
    # 0.3 is above half the median of (0.6, 0.5, 0.4, 0.3) but below 0.5 where the best is
    # 0.6: it passes; with the grid's own 0.95 and 0.99 in the cell it would fail
    assert judged[1]["failed"] == ""
    worse = replay.compare([bad | {"m_ssim": 0.2}], grid, "rift-n")[0]
    assert "half the cell's median" in worse["failed"]
    assert replay.compare([good], [], "rift-n")[0]["failed"] is None  # no grid: not judged


def test_replay_refuses_bad_arguments_by_name(tmp_path, capsys):
    """Options that choose the cell's data, a grid of another scale or seed, and options
    that are not a JSON object are refused before any run, naming the argument."""
    cfg = stability.SCALES["quick"]
    with pytest.raises(ValueError, match="may not set"):
        replay.runs(cfg, "fista", [("random-0", 6, None)], {"snr_db": 3.0})
    grid = tmp_path / "grid"
    grid.mkdir()
    config = json.loads(json.dumps(dataclasses.asdict(cfg)))
    saved = {"experiment": "stability", "seed": 0, "config": config, "rows": []}
    (grid / "results.json").write_text(json.dumps(saved))
    assert replay.load_grid(grid, cfg) == []
    with pytest.raises(ValueError, match="another config than this scale's"):
        replay.load_grid(grid, stability.SCALES["default"])
    (grid / "results.json").write_text(json.dumps(saved | {"seed": 1}))
    with pytest.raises(ValueError, match="with seed 0"):
        replay.load_grid(grid, cfg)
    cells = ["--cells", "random-0:6:none", "--out", str(tmp_path / "out")]
    for argv, named in (
        (["--options", "[1]"], "argument --options"),
        (["--options", '{"seed": 3}'], "may not set"),
        (["--scale", "quick", "--grid", str(grid)], "`--grid`"),
    ):
        with pytest.raises(SystemExit):
            replay.cli(["--scale", "quick", *argv, *cells])
        assert named in capsys.readouterr().err
    assert not (tmp_path / "out" / "results.json").exists()


@pytest.mark.slow
def test_replay_writes_its_report_beside_the_grid(tmp_path):
    """End to end at the quick scale: one FISTA run replayed with a smaller budget, its
    report beside a grid's rows for the cell."""
    cfg = stability.SCALES["quick"]
    run = replay.runs(cfg, "fista", [("random-0", 6, None)], {})[0]
    grid = tmp_path / "grid"
    grid.mkdir()
    row = {"scene": "random-0", "n_train": 6, "options": {}, "seed": run.seed,
           "residual": 0.9, "m_cos": 0.5, "t_iou": 0.5, "p_rmse": 1.0, "method": "fista",
           "m_ssim": 0.123}  # fmt: skip
    rows = [row, row | {"method": "rift-n"}]
    config = json.loads(json.dumps(dataclasses.asdict(cfg)))
    saved = {"experiment": "stability", "seed": 0, "config": config, "rows": rows}
    (grid / "results.json").write_text(json.dumps(saved))
    out = tmp_path / "out"
    argv = ["--scale", "quick", "--method", "fista", "--options", '{"iterations": 3}',
            "--cells", "random-0:6:none", "--grid", str(grid), "--out", str(out),
            "--no-progress"]  # fmt: skip
    results = replay.cli(argv)
    (done,) = results["rows"]
    assert done["options"] == run.options | {"iterations": 3} and done["seed"] == run.seed
    assert np.isfinite(done["m_ssim"])
    text = (out / "results.md").read_text()
    assert "| random-0 | 6 | noise-free |" in text and "| 0.123 | 0.123 |" in text
    assert (out / "results.json").exists() and json.loads((out / "results.json").read_text())[
        "rows"
    ][0]["fista"] == pytest.approx(0.123)  # the verdicts are in results.json too


def test_replay_says_which_loss_each_side_trained_with():
    """A grid's RIFT rows from before complex MSE name no loss: they ran the robust loss,
    and a report that sets MSE replays beside them says so."""
    old = {"method": "rift-n", "options": {"prune": 0.05}}
    new = {"method": "rift-n", "options": {"loss": "mse"}}
    grid = [old, {"method": "fista", "options": {}}]
    said = replay._losses([new], grid, "rift-n")
    assert said == " Loss: the replays' mse, the grid's runs' robust."
    assert replay._losses([new], grid, "fista") == ""
