"""GRT operator throughput, latency and memory (issue: "exact, fast GRT operator").

    python -m benchmarks.grt [--repeats 5] [--views 8] [--authors-repeats 3]
        [--skip-memory] [--skip-synthesis] [--skip-authors] [--skip-scale-out]

Workload: the paper radar (100 frequencies, 16 x 16 antennas), V = 26³ = 17,576 voxels on
the 0.4 m grid over ±5 m. Prints, in one run:
- the machine's complex64 matmul rate (G complex multiply-adds/s);
- one view: forward and forward + backward (adjoint) seconds, and G/s = 100·256·V / s;
- a *plain* call, ``rj.grt.forward(points, rho, tx, rx, freqs)`` on host NumPy arrays with
  no jit of the caller's, against the authors' per-frequency algorithm on the same view
  (target: ≥ 200x);
- several views through the operator (both cores): seconds per view and G/s;
- one RIFT(N) optimizer step on 10 views (forward, backward through the INR, AdamW);
- scale-out: the operator's throughput on 2 devices against 1, each in a fresh process
  (``RIFT_JAX_CPU_DEVICES``; target ≥ 1.8x);
- peak memory of one view at V = 51³ (XLA's buffer assignment for the compiled forward);
- synthesising all 2,601 paper viewpoints of the sphere (4,169 occupied voxels at 0.2 m).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

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
    parser.add_argument("--authors-repeats", type=int, default=3)
    parser.add_argument("--skip-authors", action="store_true")
    parser.add_argument("--skip-scale-out", action="store_true")
    parser.add_argument("--throughput-only", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.throughput_only:  # the child process of the scale-out measure
        print(json.dumps(_throughput(args.views, args.repeats)))
        return {}

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

    host_points = grid.points()  # float64 NumPy, as a user holds them
    host_rho = np.asarray(rho)
    t_plain = median_seconds(
        lambda: grt.forward(host_points, host_rho, tx, rx, freqs), repeats=args.repeats
    )
    out["plain_call_forward_s"] = t_plain
    print(f"plain call rj.grt.forward (host):   {t_plain:6.3f} s  {work / t_plain / 1e9:5.2f} G/s")
    if not args.skip_authors:
        t_authors = median_seconds(
            lambda: authors_forward(host_points, host_rho, tx, rx, freqs),
            repeats=args.authors_repeats,
        )
        out |= {"authors_forward_s": t_authors, "plain_call_speedup": t_authors / t_plain}
        print(
            f"authors' per-frequency algorithm:   {t_authors:6.3f} s  -> plain call is "
            f"{t_authors / t_plain:5.0f}x faster (target >= 200x)"
        )

    per_view = _throughput(args.views, args.repeats)
    out |= per_view
    t_many, t_many_both = per_view["per_view_forward_s"], per_view["per_view_forward_backward_s"]
    print(
        f"{args.views} views, forward, per view:      {t_many:6.3f} s  "
        f"{work / t_many / 1e9:5.2f} G/s "
        f"({work / t_many / 1e9 / rate:4.0%} of matmul)"
    )
    print(f"{args.views} views, forward + backward, per view: {t_many_both:6.3f} s")

    t_step = _rift_step_seconds(radar, points)
    out["rift_step_10_views_s"] = t_step
    print(f"RIFT(N) step, 10 views (median):    {t_step:6.3f} s")

    if not args.skip_scale_out:
        one, two = (_throughput_in_process(n, args.views, args.repeats) for n in (1, 2))
        ratio = one["per_view_forward_s"] / two["per_view_forward_s"]
        ratio_both = one["per_view_forward_backward_s"] / two["per_view_forward_backward_s"]
        out |= {"scale_out_1_device": one, "scale_out_2_devices": two}
        out |= {"scale_out_forward_ratio": ratio, "scale_out_forward_backward_ratio": ratio_both}
        print(
            f"scale-out, {args.views} views per call, seconds per view: 1 device "
            f"{one['per_view_forward_s']:.3f} / {one['per_view_forward_backward_s']:.3f}, "
            f"2 devices {two['per_view_forward_s']:.3f} / "
            f"{two['per_view_forward_backward_s']:.3f} (forward / forward + backward): "
            f"{ratio:.2f}x / {ratio_both:.2f}x (target >= 1.8x)"
        )

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


def authors_forward(points, rho, tx, rx, frequencies, *, threads: int | None = None):
    """The authors' operator algorithm (RIFT_Public's ``forward_operator_lessparallel``,
    re-expressed in NumPy complex64): distances once, then a loop over frequencies, each
    building the dense [V, n_tx, n_rx] field ρ·exp(j k R_b)/R_b² and summing it over the
    voxels. Torch spreads each frequency's work over every core; here the frequencies are
    spread over ``threads`` (default: every core) NumPy threads (its ufuncs release the
    GIL), so both sides of the comparison use the whole machine."""
    points, tx, rx = (np.asarray(a, np.float32) for a in (points, tx, rx))
    rho = np.asarray(rho, np.complex64)
    r_tx = np.linalg.norm(points[:, None] - tx[None], axis=-1)
    r_rx = np.linalg.norm(points[:, None] - rx[None], axis=-1)
    r_b = r_tx[:, :, None] + r_rx[:, None, :]
    gain = (1.0 / r_b**2).astype(np.float32)
    k = (2 * np.pi * np.asarray(frequencies) / rj.C0).astype(np.float32)
    out = np.empty((len(k), len(tx), len(rx)), np.complex64)

    def one(i):
        field = rho[:, None, None] * gain * np.exp(1j * (k[i] * r_b))
        out[i] = field.sum(axis=0)

    with ThreadPoolExecutor(threads or len(os.sched_getaffinity(0))) as pool:
        list(pool.map(one, range(len(k))))
    return out


def _throughput(n_views: int, repeats: int) -> dict:
    """Seconds per view of the operator's forward and forward + adjoint over ``n_views``."""
    radar = rj.Radar()
    points = rj.Scene.empty(5.0, 0.4).points()
    rho = jax.lax.complex(*jax.random.normal(jax.random.key(1), (2, len(points))))
    op = rj.grt_operator(radar, rj.Viewpoints.grid(n_views, 1, polar_range=(1.0, 1.0)), points)
    round_trip = eqx.filter_jit(lambda r: op.fn.adjoint(op.mv(r)))
    return {
        "devices": jax.device_count(),
        "per_view_forward_s": median_seconds(op.mv, rho, repeats=repeats) / n_views,
        "per_view_forward_backward_s": median_seconds(round_trip, rho, repeats=repeats) / n_views,
    }


def _throughput_in_process(n_devices: int, n_views: int, repeats: int) -> dict:
    """`_throughput` in a fresh process started with ``n_devices`` CPU devices."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["RIFT_JAX_CPU_DEVICES"] = str(n_devices)
    command = [sys.executable, "-m", "benchmarks.grt", "--throughput-only"]
    command += ["--views", str(n_views), "--repeats", str(repeats)]
    done = subprocess.run(command, env=env, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def _rift_step_seconds(radar, points, n_views: int = 10, epochs: int = 4) -> float:
    """Median seconds of one RIFT(N) optimizer step on ``n_views`` views (one step per
    epoch: one pass, ``epoch_views=None``; the first epoch, which compiles, is left out)."""
    viewpoints = rj.Viewpoints.grid(n_views, 1, polar_range=(1.0, 1.0))
    op = rj.grt_operator(radar, viewpoints, points)
    signal = op.mv(jnp.ones(len(points), jnp.complex64))
    # retries=0: four steps fit little, and a collapse's retry would add runs, not change
    # the step timed
    result = rj.solvers.rift(
        op, signal, model="rift-n", epochs=epochs, epoch_views=None, retries=0, progress=False
    )
    return float(np.median(np.diff(result.history.seconds)))


_RSS_PROBE = """
import resource, numpy as np, jax, jax.numpy as jnp
import rift_jax as rj
from rift_jax import grt

def peak():  # VmHWM: ru_maxrss would carry the parent's peak over fork and exec
    try:
        with open("/proc/self/status") as status:
            line = next(line for line in status if line.startswith("VmHWM:"))
        return int(line.split()[1]) * 1024
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024

radar = rj.Radar()
tx, rx = rj.antenna_positions(radar, 0.7, 1.1)
def run(granularity):
    points = rj.Scene.empty(5.0, granularity).points().astype(np.float32)
    rho = jnp.ones(len(points), jnp.complex64)
    grt.forward(points, rho, tx, rx, radar.frequencies).block_until_ready()
run(2.5)
before = peak()
run(0.2)
print(before, peak())
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
