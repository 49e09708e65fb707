"""GRT operator throughput, latency and memory (issue: "exact, fast GRT operator").

    python -m benchmarks.grt [--repeats 5] [--views 8] [--skip-memory] [--skip-synthesis]

Workload: the paper radar (100 frequencies, 16 x 16 antennas), V = 26³ = 17,576 voxels on
the 0.4 m grid over ±5 m. Prints, in one run:
- the machine's complex64 matmul rate (G complex multiply-adds/s);
- one view: forward and forward + backward (adjoint) seconds, and G/s = 100·256·V / s;
- several views through the operator (both cores): seconds per view and G/s;
- peak memory of one view at V = 51³ (XLA's buffer assignment for the compiled forward);
- synthesising all 2,601 paper viewpoints of the sphere (4,169 occupied voxels at 0.2 m).
"""

from __future__ import annotations

import argparse
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import rift_jax as rj
from rift_jax import grt

from ._timing import complex_matmul_rate, median_seconds


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description="GRT throughput benchmark")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--skip-memory", action="store_true")
    parser.add_argument("--skip-synthesis", action="store_true")
    args = parser.parse_args(argv)

    radar = rj.Radar()
    grid = rj.Scene.empty(5.0, 0.4)
    points = grid.points().astype(np.float32)
    n = points.shape[0]
    work = radar.n_frequencies * radar.n_tx * radar.n_rx * n  # complex multiply-adds per view
    rho = jax.lax.complex(*jax.random.normal(jax.random.key(1), (2, n)))
    tx, rx = rj.antenna_positions(radar, 0.7, 1.1)
    freqs = radar.frequencies
    out = {"devices": str(jax.devices()), "voxels": n}
    print(f"devices: {jax.devices()}  backend: {jax.default_backend()}  V = {n}")

    rate = complex_matmul_rate(repeats=args.repeats)
    out["matmul_G_per_s"] = rate
    print(f"complex64 matmul (1024³):           {rate:6.2f} G/s")

    forward = jax.jit(lambda r: grt.forward(points, r, tx, rx, freqs))
    both = jax.jit(
        lambda r: grt.adjoint(points, grt.forward(points, r, tx, rx, freqs), tx, rx, freqs)
    )
    t_fwd = median_seconds(forward, rho, repeats=args.repeats)
    t_both = median_seconds(both, rho, repeats=args.repeats)
    out |= {"one_view_forward_s": t_fwd, "one_view_forward_backward_s": t_both}
    print(
        f"one view, forward:                  {t_fwd:6.3f} s  {work / t_fwd / 1e9:5.2f} G/s "
        f"({work / t_fwd / 1e9 / rate:4.0%} of matmul)"
    )
    print(f"one view, forward + backward:       {t_both:6.3f} s")

    vps = rj.Viewpoints.grid(args.views, 1, polar_range=(1.0, 1.0))
    op = rj.grt_operator(radar, vps, points)
    mv = eqx.filter_jit(op.mv)
    round_trip = eqx.filter_jit(lambda r: op.fn.adjoint(op.mv(r)))
    t_many = median_seconds(mv, rho, repeats=args.repeats) / args.views
    t_many_both = median_seconds(round_trip, rho, repeats=args.repeats) / args.views
    out |= {"per_view_forward_s": t_many, "per_view_forward_backward_s": t_many_both}
    print(
        f"{args.views} views, forward, per view:      {t_many:6.3f} s  "
        f"{work / t_many / 1e9:5.2f} G/s "
        f"({work / t_many / 1e9 / rate:4.0%} of matmul)"
    )
    print(f"{args.views} views, forward + backward, per view: {t_many_both:6.3f} s")

    if not args.skip_memory:
        big = rj.Scene.empty(5.0, 0.2).points().astype(np.float32)
        rho_big = jnp.ones(big.shape[0], jnp.complex64)
        compiled = jax.jit(lambda r: grt.forward(big, r, tx, rx, freqs)).lower(rho_big).compile()
        mem = compiled.memory_analysis()
        out["xla_temp_bytes_51cubed"] = mem.temp_size_in_bytes
        before, after = _process_peak_rss()
        out["process_peak_rss_bytes_51cubed"] = after
        print(
            f"one view at V = 51³ = {big.shape[0]}: XLA temporaries "
            f"{mem.temp_size_in_bytes / 2**20:.1f} MiB; whole-process peak RSS "
            f"{after / 2**20:.0f} MiB ({before / 2**20:.0f} MiB before it, JAX warmed up)"
        )

    if not args.skip_synthesis:
        start = time.perf_counter()
        data = rj.synthesize(rj.scenes.sphere(0.2), rj.Viewpoints.grid(), radar)
        data.signal.block_until_ready()
        seconds = time.perf_counter() - start
        out["synthesis_2601_sphere_s"] = seconds
        print(f"synthesise 2,601 views of the sphere: {seconds:6.1f} s (compile included)")
    return out


_RSS_PROBE = """
import resource, numpy as np, jax, jax.numpy as jnp
import rift_jax as rj
from rift_jax import grt
radar = rj.Radar()
tx, rx = rj.antenna_positions(radar, 0.7, 1.1)
def run(granularity):
    points = rj.Scene.empty(5.0, granularity).points().astype(np.float32)
    rho = jnp.ones(len(points), jnp.complex64)
    grt.forward(points, rho, tx, rx, radar.frequencies).block_until_ready()
run(2.5)
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
run(0.2)
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(before * 1024, after * 1024)
"""


def _process_peak_rss() -> tuple[int, int]:
    """Peak resident memory (bytes) of a fresh process (so nothing else this benchmark ran
    counts) before and after one V = 51³ forward, JAX already initialised and warmed up."""
    import subprocess
    import sys

    result = subprocess.run(
        [sys.executable, "-c", _RSS_PROBE], capture_output=True, text=True, check=True
    )
    before, after = result.stdout.strip().splitlines()[-1].split()
    return int(before), int(after)


if __name__ == "__main__":
    main()
