"""Shared fixtures and helpers, and the suite's compilation cache.

The suite's time is mostly XLA compiling: at e79f5e7, JAX traced, lowered and compiled for
~1,180 of the ~1,610 s that the tests took one after another (2,051 programs; a RIFT step
~4 s each, an LSMR segment ~4 s, the operator ~1.3 s). Every new shape, radar, model size
or schedule compiles its programs again, so a new test costs least on the problems already
here: `small_cube` and `tiny` (below), with the budgets their tests use.
`tests/compile_profile.py` shows where the time goes, test by test.
"""

import logging
import os
import re
import shutil
import tempfile
from pathlib import Path

import jax
import numpy as np
import pytest

import rift_jax as rj

# Most of the suite's time is XLA compiling, and its processes (the xdist workers, and the
# subprocesses some tests start) compile many of the same programs: they share them through
# JAX's disk cache, in a fresh folder per test run (made by the first process, which the
# others inherit it from, and which removes it at the end), so nothing is kept between runs;
# or in the folder `RIFT_JAX_TEST_CACHE` names, which is then left to its owner (.ci/run
# shares one between its two commands).
_OWNER = "RIFT_JAX_TEST_CACHE" not in os.environ
if _OWNER:
    os.environ["RIFT_JAX_TEST_CACHE"] = tempfile.mkdtemp(prefix="rift_jax_tests_")
_CACHE = os.environ["RIFT_JAX_TEST_CACHE"]
os.environ["JAX_COMPILATION_CACHE_DIR"] = _CACHE  # for the subprocesses tests start
# Not on a GPU: there, with the workers sharing it, test_points' programs stopped on
# CUDA_ERROR_ILLEGAL_ADDRESS (twice, on an H200), and with it off every test passed
# (docs/benchmarks.md, GPU). Turned off, not only left unset: a worker that inherits
# JAX_COMPILATION_CACHE_DIR reads it when it imports JAX. The subprocesses tests start run
# on the CPU and share it still.
if jax.default_backend() == "cpu":
    jax.config.update("jax_compilation_cache_dir", _CACHE)
else:
    jax.config.update("jax_enable_compilation_cache", False)
# every program, not only those over a second: the many small ones (a model's
# initialisation, eager array operations) are the same in every process
os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)


def pytest_sessionfinish(session):
    if _OWNER:
        shutil.rmtree(_CACHE, ignore_errors=True)


def pytest_terminal_summary(terminalreporter):
    """The machine's own speed beside the suite's time, measured once the workers are done.
    The same 2-core machine is not equally fast every day: the whole suite (slow tests
    included) took 743-777 s in earlier sessions (whose benchmarks record 10-18 G/s),
    1,391 s on a day of 6.2-7.3 G/s and 1,306 s at 11.5 G/s (2476b56)."""
    from benchmarks._timing import complex_matmul_rate

    rate = complex_matmul_rate()
    terminalreporter.write_line(f"this machine's complex64 matmul (1024³): {rate:.1f} G/s")


# The files that take longest, by their summed test time in `tests/compile_profile.py`
# (default run at 573748a: test_inr 327 s, test_support 247, test_grt 95, test_precision
# 95, test_stability 87, test_io 84, test_operator 75 of the two workers' 1,318; the slow
# run's test_experiments, test_devices and test_examples held 345, 167 and 167 s of 1,012
# at 2476b56). xdist hands out whole files (`--dist loadfile`) in collection
# order (`--no-loadscope-reorder`; its default order is by test count, which put the many
# quick bad-input checks first): the longest first, so that the last files handed out are
# short and the two workers finish together. The order serves both runs: the default one
# (test_inr and test_support lead) and `-m slow` (test_experiments, test_devices and
# test_examples lead).
_LONGEST_FIRST = (
    "test_inr.py",
    "test_experiments.py",
    "test_support.py",
    "test_devices.py",
    "test_examples.py",
    "test_grt.py",
    "test_stability.py",
    "test_precision.py",
    "test_io.py",
    "test_operator.py",
)


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(_LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable within a file


def default_then_slow(default, slow) -> list:
    """Parameters for `pytest.mark.parametrize`: those in ``default`` run in the default
    run, the rest of ``slow`` only with ``-m slow`` (other methods' checks that compile
    programs of their own; CI runs them as its second command)."""
    return [*default, *(pytest.param(v, marks=pytest.mark.slow) for v in slow if v not in default)]


@pytest.fixture
def rng():
    return np.random.default_rng(0)


@pytest.fixture
def x64():
    """Run the test body with 64-bit types enabled (restored afterwards)."""
    with jax.enable_x64(True):
        yield


def relative_error(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def random_points(rng, n, half_width):
    """Random points in the scene cube, rounded to float32 (the values the kernel sees)."""
    return rng.uniform(-half_width, half_width, (n, 3)).astype(np.float32)


def random_complex(rng, *shape, dtype=np.complex64):
    return (rng.normal(size=shape) + 1j * rng.normal(size=shape)).astype(dtype)


@pytest.fixture
def small_radar():
    """A radar with the paper's band and spacing but fewer channels: fast to compile."""
    return rj.Radar(n_frequencies=12, n_tx=4, n_rx=5)


@pytest.fixture(scope="module")
def small_cube():
    """(radar, scene, train, test): a 1 m cube on a 0.5 m grid over ±2 m, a small radar and
    30 + 6 viewpoints. Fits in seconds; on its own grid the data are explained exactly."""
    radar = rj.Radar(n_frequencies=8, n_tx=4, n_rx=4)
    scene = rj.scenes.cube(0.5, extent=2.0, edge=1.0)
    train, test = rj.Viewpoints.grid(8, 6, polar_range=(0.2, 1.4)).split(30, 6)
    return radar, scene, train, test


@pytest.fixture(scope="module")
def tiny(small_cube):
    """(radar, scene, train, test): a 1 m cube on its own 0.5 m grid over ±1 m (the data
    are explainable exactly), seen by `small_cube`'s radar and viewpoints. Its 125 points
    are as many as `small_cube`'s inverse grid holds, so that fits of both share compiled
    programs."""
    radar, _, train, test = small_cube
    return radar, rj.scenes.cube(0.5, extent=1.0, edge=1.0), train, test


def docs_blocks(page: str) -> list[str]:
    """The ```python blocks of ``docs/<page>``, in order."""
    text = (Path(__file__).resolve().parent.parent / "docs" / page).read_text()
    return re.findall(r"```python\n(.*?)```", text, re.S)


def run_docs_block(page: str, index: int) -> dict:
    """Run block ``index`` of ``docs/<page>`` as written; returns its namespace."""
    namespace: dict = {}
    exec(compile(docs_blocks(page)[index], f"{page}[{index}]", "exec"), namespace)
    return namespace


def compilations(caplog, call) -> list[str]:
    """The "Compiling ..." messages JAX logs while ``call()`` runs (to its results)."""
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="jax"), jax.log_compiles():
        jax.block_until_ready(call())
    return [r.getMessage() for r in caplog.records if r.getMessage().startswith("Compiling")]


def assert_compilations_are_logged(caplog) -> None:
    """Fails unless a new program shows in `compilations`' log: a test that then finds no
    compilation of its program knows that none happened, not that none was recorded."""
    fresh = compilations(caplog, lambda: jax.jit(lambda v: v * 3.0)(np.ones(11, np.float32)))
    assert fresh, "a new program does not show in the log"
