"""Time to a first result: `fit` + `evaluate` in a fresh process, compilation included.

    python -m benchmarks.first_fit [--repeats 3] [--methods rift-n,fista,lsmr,kaczmarz,auto]

At small and medium sizes a first fit is mostly XLA compiling its programs (the test suite
is too, and the stress grid's runs), so this is the number that says what a user waits for
the first time, and what each compiled program costs. Workload: the tests' `small_cube` (a
1 m cube synthesised on a 0.5 m grid over ±2 m, a radar of 8 frequencies and 4 × 4
antennas, 30 training and 6 test viewpoints), each method at `fit`'s defaults (the 1 m
inverse grid, ``support="auto"``) with a small budget, then `evaluate` on the test views.
Each repeat is a new Python process with no compilation cache, so nothing is reused; the
median over repeats is printed, with the seconds XLA spent compiling (`jax.monitoring`'s
backend-compile events) and how many programs it compiled, beside the machine's complex64
matmul rate from the same run.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

from ._timing import complex_matmul_rate

BUDGETS = {
    "rift-n": {"epochs": 3, "epoch_views": None},  # 3 steps per epoch on 30 views, as
    "rift-s": {"epochs": 3, "epoch_views": None},  # before epoch_views (comparable rows)
    "fista": {"iterations": 10},
    "lsmr": {"iterations": 10},
    "kaczmarz": {"iterations": 2},
}
# fit's default: both candidates with their budgets above, on four fifths of the views, then
# the winner's fit on all of them
BUDGETS["auto"] = {"candidates": {m: BUDGETS[m] for m in ("fista", "rift-n")}}

# run in the child process: one fit and its evaluation, timed, with XLA's compile events
_CHILD = """
import json, sys, time
import jax.monitoring
compiled = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, seconds, **_: compiled.append(seconds)
    if event.endswith("backend_compile_duration") else None
)
import rift_jax as rj
method, options = sys.argv[1], json.loads(sys.argv[2])
radar = rj.Radar(n_frequencies=8, n_tx=4, n_rx=4)
scene = rj.scenes.cube(0.5, extent=2.0, edge=1.0)
train, test = rj.Viewpoints.grid(8, 6, polar_range=(0.2, 1.4)).split(30, 6)
start = time.perf_counter()
result = rj.fit(scene, train, radar=radar, method=method, progress=False, **options)
metrics = result.evaluate(scene, test)
print(json.dumps({"seconds": time.perf_counter() - start, "compile_seconds": sum(compiled),
                  "programs": len(compiled), "m_ssim": metrics["m_ssim"]}))
"""


def first_fit(method: str) -> dict:
    """One fresh process's fit + evaluate of ``method``; the child's own measurements."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["JAX_ENABLE_COMPILATION_CACHE"] = "false"
    command = [sys.executable, "-W", "ignore", "-c", _CHILD, method, json.dumps(BUDGETS[method])]
    out = subprocess.run(command, env=env, capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"first_fit: the {method} process failed:\n{out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--methods", default="rift-n,fista,lsmr,kaczmarz,auto")
    args = parser.parse_args(argv)
    methods = args.methods.split(",")
    if unknown := sorted(set(methods) - set(BUDGETS)):
        parser.error(f"--methods: unknown {unknown}; choose from {sorted(BUDGETS)}")
    rate = complex_matmul_rate()
    print(f"complex64 matmul (1024³): {rate:.2f} G/s")
    print("| method | first fit + evaluate, s | of it compiling, s | programs | m-SSIM |")
    print("|---|---|---|---|---|")
    out: dict = {"matmul_G_per_s": rate}
    for method in methods:
        runs = [first_fit(method) for _ in range(args.repeats)]
        median = {key: statistics.median(run[key] for run in runs) for key in runs[0]}
        out[method] = median
        print(
            f"| {method} | {median['seconds']:.1f} | {median['compile_seconds']:.1f} | "
            f"{median['programs']:.0f} | {median['m_ssim']:.3f} |",
            flush=True,
        )
    return out


if __name__ == "__main__":
    main()
