"""Where the suite's time goes: per test, the seconds JAX spends tracing, lowering and
compiling, by program. Most of the suite's time is compilation (measured: ~70 %), so this is
the profile to read before adding a slow test or cutting one.

    PYTHONPATH=tests .venv/bin/python -m pytest -q -p compile_profile   # writes .compile_profile/
    .venv/bin/python tests/compile_profile.py [.compile_profile] [--top 30]

Each pytest process (each xdist worker) writes ``<folder>/<worker>.json``; the script merges
them and prints the slowest tests with their compile time and most expensive programs, then
the programs that cost most over the whole suite, with how often they compiled. Tests
that start subprocesses show their wall time only. Cheap: listeners on JAX's own monitoring
events (`jax.monitoring`), which JAX records whether or not anyone listens.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import time
from pathlib import Path

FOLDER = Path(os.environ.get("COMPILE_PROFILE_DIR", ".compile_profile"))
STAGES = {  # JAX's duration events, by the name this profile gives them
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "compile",
}

_current: list = []  # [test id, its start time] while a test runs
_controller: list = []  # [True] in xdist's controller: it runs no test, workers report to it
_seconds: dict = collections.defaultdict(lambda: collections.defaultdict(float))
_counts: dict = collections.defaultdict(lambda: collections.defaultdict(int))


def _listen(event: str, duration: float, **kwargs) -> None:
    if _current and event in STAGES:
        key = f"{STAGES[event]}|{kwargs.get('fun_name', '?')}"
        _seconds[_current[0]][key] += duration
        _counts[_current[0]][key] += 1


def pytest_configure(config):
    from jax import monitoring

    if "PYTEST_XDIST_WORKER" not in os.environ:  # the first process: a new run, new files
        for old in FOLDER.glob("*.json"):
            old.unlink()
        if config.getoption("dist", "no") != "no":  # it sees the workers' tests, not their time
            _controller.append(True)
    monitoring.register_event_duration_secs_listener(_listen)


def pytest_runtest_logstart(nodeid, location):
    if not _controller:
        _current[:] = [nodeid, time.perf_counter()]


def pytest_runtest_logfinish(nodeid, location):
    if _current and _current[0] == nodeid:
        _seconds[nodeid]["wall|"] += time.perf_counter() - _current[1]
        _current.clear()


def pytest_sessionfinish(session):
    if _controller:
        return
    FOLDER.mkdir(parents=True, exist_ok=True)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    merged = {
        test: {key: [seconds, _counts[test][key]] for key, seconds in by_key.items()}
        for test, by_key in _seconds.items()
    }
    (FOLDER / f"{worker}.json").write_text(json.dumps(merged))


def report(folder: Path, top: int) -> str:
    tests: dict = {}
    for file in sorted(folder.glob("*.json")):
        tests |= json.loads(file.read_text())
    rows, totals = [], collections.Counter()
    suite_seconds, suite_compiled, suite_tests = (
        collections.Counter(),
        collections.Counter(),
        collections.Counter(),
    )
    for test, by_key in tests.items():
        stage, programs, compiled = (
            collections.Counter(),
            collections.Counter(),
            collections.Counter(),
        )
        for key, (seconds, count) in by_key.items():
            kind, name = key.split("|", 1)
            stage[kind] += seconds
            if kind != "wall":  # one name per program: JAX says "f" tracing, "jit(f)" after
                name = name[4:-1] if name.startswith("jit(") else name
                programs[name] += seconds
                compiled[name] += count if kind == "compile" else 0
        totals.update(stage)
        suite_seconds.update(programs)
        suite_compiled.update(compiled)
        suite_tests.update(name for name in compiled if compiled[name])
        rows.append((stage["wall"], stage, programs, compiled, test))
    rows.sort(key=lambda row: -row[0])
    jax_time = totals["trace"] + totals["lower"] + totals["compile"]
    lines = [
        f"{len(rows)} tests, {totals['wall']:.0f} s in all (per-test wall time, summed); JAX "
        f"traced {totals['trace']:.0f} s, lowered {totals['lower']:.0f} s, compiled "
        f"{totals['compile']:.0f} s ({jax_time / max(totals['wall'], 1e-9):.0%})",
        "",
        "| wall s | trace + lower + compile s | test | costliest programs (s, compilations) |",
        "|---|---|---|---|",
    ]
    for wall, stage, programs, compiled, test in rows[:top]:
        costly = ", ".join(
            f"{name} {s:.1f} ×{compiled[name]}" for name, s in programs.most_common(3)
        )
        spent = stage["trace"] + stage["lower"] + stage["compile"]
        lines.append(f"| {wall:.1f} | {spent:.1f} | {test} | {costly} |")
    # the same program compiled for many shapes or settings is what sharing them would save
    lines += [
        "",
        "| trace + lower + compile s | program | compilations | tests compiling it |",
        "|---|---|---|---|",
    ]
    for name, seconds in suite_seconds.most_common(top):
        lines.append(f"| {seconds:.1f} | {name} | {suite_compiled[name]} | {suite_tests[name]} |")
    return "\n".join(lines)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="Print the suite's compile profile.")
    parser.add_argument("folder", type=Path, nargs="?", default=FOLDER)
    parser.add_argument("--top", type=int, default=30)
    args = parser.parse_args()
    print(report(args.folder, args.top))
