"""Plain calls compile once, and 1 or 4 devices give the same answers (the suite's own
processes run on one device per core, 2 on the CI machine).

The device count is fixed when JAX starts, so each count runs in a fresh process
(``RIFT_JAX_CPU_DEVICES``), which writes its results for this process to compare.
"""

import os
import subprocess
import sys
import textwrap
import time

import jax
import numpy as np
import pytest
from conftest import compilations

import rift_jax as rj
from rift_jax import grt

# Every sharded path: views split (9 views ≥ devices), voxels split (one view, 729 voxels
# ≥ devices × chunk 64), padding of both (9 views and 729 voxels on 4 devices), Kaczmarz's
# own voxel split, RIFT's view batches and gradient, and a library loop (jaxopt's, in
# FISTA) around the operator. LSMR and Gauss-Newton are loops around the same operator
# calls; left out, as each solver compiled in two processes costs the suite ~10 s.
_WORKLOAD = textwrap.dedent(
    """
    import sys
    import jax, numpy as np
    import rift_jax as rj
    from rift_jax import grt, solvers

    radar = rj.Radar(n_frequencies=8, n_tx=4, n_rx=4)
    viewpoints = rj.Viewpoints.grid(3, 3, polar_range=(0.4, 1.2))
    scene = rj.scenes.cube(0.25, extent=1.0, edge=1.0)
    points = scene.points()
    op = rj.grt_operator(radar, viewpoints, points, chunk_size=64)
    rho = scene.reflectivity.ravel().astype(np.complex64)
    tx, rx = rj.antenna_positions(radar, 0.7, 1.1)
    one = grt.forward(points, rho, tx, rx, radar.frequencies, chunk_size=64)
    signal = rj.synthesize(scene, viewpoints, radar).signal
    out = {
        "devices": jax.device_count(),
        "forward_one_view": one,
        "adjoint_one_view": grt.adjoint(points, one, tx, rx, radar.frequencies, chunk_size=64),
        "view": op.fn.view(rho, 4),
        "view_adjoint": op.fn.view_adjoint(one, 4),
        "operator": op.mv(rho),
        "operator_adjoint": op.fn.adjoint(signal),
        "synthesize": signal,
        "kaczmarz": solvers.kaczmarz(op, signal, iterations=2, progress=False).rho,
        "fista": solvers.fista(op, signal, iterations=3, power_iterations=3, progress=False).rho,
        "rift": solvers.rift(
            op, signal, model="rift-n", epochs=3, batch_views=3, epoch_views=None, width=16,
            depth=2, progress=False,
        ).rho,
    }
    np.savez(sys.argv[1], **{k: np.asarray(v) for k, v in out.items()})
    """
)


def cpu_processes(devices: int) -> dict[str, str]:
    """The environment of a subprocess on ``devices`` CPU devices, on CPU whatever the
    machine has (on a GPU machine JAX would otherwise pick its one GPU)."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    return env | {"RIFT_JAX_CPU_DEVICES": str(devices), "JAX_PLATFORMS": "cpu"}


def wait_all(runs: list[subprocess.Popen], what: str, timeout: float = 600) -> None:
    """Wait for every run; fail as soon as one fails (a multihost peer whose partner died
    would wait for it), and end the rest then, so that none outlives its test."""
    deadline = time.monotonic() + timeout
    try:
        while any(run.poll() is None for run in runs):
            failed = [i for i, run in enumerate(runs) if run.poll() not in (None, 0)]
            assert not failed, f"{what}: process {failed[0]} failed"
            assert time.monotonic() < deadline, f"{what}: still running after {timeout} s"
            time.sleep(0.2)
        codes = [run.returncode for run in runs]
        assert codes == [0] * len(runs), f"{what}: exit codes {codes}"
    finally:
        for run in runs:
            if run.poll() is None:
                run.kill()
                run.wait()


@pytest.fixture(scope="module")
def by_device_count(tmp_path_factory):
    folder = tmp_path_factory.mktemp("devices")
    script = folder / "workload.py"
    script.write_text(_WORKLOAD)
    runs = {}
    for n in (1, 4):  # side by side: most of each run is compilation on one core
        command = [sys.executable, str(script), str(folder / f"{n}.npz")]
        runs[n] = subprocess.Popen(command, env=cpu_processes(n))
    wait_all(list(runs.values()), "the workload on 1 and 4 devices")
    return {n: dict(np.load(folder / f"{n}.npz")) for n in runs}


@pytest.mark.slow
def test_results_do_not_depend_on_the_device_count(by_device_count):
    """Same numbers on 1 and 4 devices: exactly where each view runs whole on one device,
    to float32 rounding where partial sums over voxels or views are added in another order
    (and through a few solver iterations)."""
    base, other = by_device_count[1], by_device_count[4]
    assert int(other["devices"]) == 4
    for name, expected in base.items():
        if name == "devices":
            continue
        got = other[name]
        assert got.shape == expected.shape, name
        error = np.linalg.norm(got - expected) / np.linalg.norm(expected)
        assert error < 2e-5, f"{name}: 4 devices differ from 1 by {error:.2e}"
    np.testing.assert_array_equal(other["operator"], base["operator"])


@pytest.mark.slow  # as test_operator's view-block test
def test_plain_calls_compile_once(caplog):
    """A second plain call with new values of the same shapes compiles nothing (before the
    kernels were jitted, every call traced and compiled the whole scan again: 0.8 s). For
    the solvers: `tests/test_precision.py::test_what_each_solver_compiles`."""
    radar = rj.Radar(n_frequencies=6, n_tx=3, n_rx=4)
    points = rj.grid_points(1.0, 0.25)
    rho = np.ones(len(points), np.complex64)
    viewpoints = rj.Viewpoints.grid(3, 2)
    op = rj.grt_operator(radar, viewpoints, points)
    scene = rj.scenes.sphere(0.25, extent=1.0, radius=0.5)

    def calls(angle, scale, index):
        tx, rx = rj.antenna_positions(radar, angle, 1.1)
        signal = grt.forward(points, scale * rho, tx, rx, radar.frequencies)
        data = op.mv(scale * rho)
        return {
            "grt.forward": lambda: signal,
            "grt.adjoint": lambda: grt.adjoint(points, signal, tx, rx, radar.frequencies),
            "operator": lambda: op.mv(scale * rho),
            "operator adjoint": lambda: op.transpose().mv(data),
            "view": lambda: op.fn.view(scale * rho, index),
            "view_adjoint": lambda: op.fn.view_adjoint(data[0], index),
            "synthesize": lambda: rj.synthesize(scene, viewpoints, radar).signal,
        }

    for call in calls(0.3, 1.0, 1).values():  # first calls compile
        jax.block_until_ready(call())
    smaller = rj.grt_operator(radar, viewpoints, points[:-1])  # the check can see one
    assert compilations(caplog, lambda: smaller.mv(rho[:-1]))
    for name, call in calls(0.9, 2.0, np.int64(4)).items():
        assert compilations(caplog, call) == [], f"{name} compiled again"


@pytest.mark.slow
def test_the_multihost_example_matches_one_process(tmp_path):
    """docs/examples/multihost.py run as two processes (two 'hosts' on this machine, talking
    through gloo) gives the single process's signal and least-squares image. (RIFT is only
    checked to run: Adam amplifies float32 rounding differences between device layouts.)"""
    import socket

    script = os.path.join(os.path.dirname(__file__), "..", "docs", "examples", "multihost.py")

    def launch(processes: int, process_id: int, port: int, out):
        command = [sys.executable, script, "--coordinator", f"localhost:{port}"]
        command += ["--processes", str(processes), "--process-id", str(process_id)]
        return subprocess.Popen(command + ["--out", str(out)], env=cpu_processes(1))

    ports = []
    for _ in range(2):
        with socket.socket() as s:
            s.bind(("localhost", 0))
            ports.append(s.getsockname()[1])
    runs = [launch(2, i, ports[0], tmp_path / "two.npz") for i in (0, 1)]
    runs.append(launch(1, 0, ports[1], tmp_path / "one.npz"))
    wait_all(runs, "the multihost example")
    one, two = np.load(tmp_path / "one.npz"), np.load(tmp_path / "two.npz")
    np.testing.assert_array_equal(two["signal"], one["signal"])
    error = np.linalg.norm(two["lsmr"] - one["lsmr"]) / np.linalg.norm(one["lsmr"])
    assert error < 1e-5
    assert np.all(np.isfinite(two["rift"])) and np.any(two["rift"] != 0)


def test_kernels_inside_a_users_shard_map_and_on_pinned_inputs():
    """The voxel split stays out of the way: inside a caller's `shard_map` each call runs
    whole on its device, and an input pinned to one device runs there."""
    from jax.sharding import AxisType
    from jax.sharding import PartitionSpec as P

    n = jax.device_count()
    if n < 2:
        pytest.skip("needs several devices (rift_jax makes one per CPU core)")
    radar = rj.Radar(n_frequencies=6, n_tx=3, n_rx=4)
    points = rj.grid_points(1.0, 0.25)  # 729 voxels: a plain call splits them
    tx, rx = rj.antenna_positions(radar, 0.7, 1.1)
    rhos = np.random.default_rng(0).normal(size=(n, len(points))).astype(np.complex64)
    plain = np.stack([grt.forward(points, r, tx, rx, radar.frequencies) for r in rhos])

    mesh = jax.make_mesh((n,), ("user",), axis_types=(AxisType.Auto,))
    per_device = jax.shard_map(
        lambda r: grt.forward(points, r[0], tx, rx, radar.frequencies)[None],
        mesh=mesh,
        in_specs=P("user"),
        out_specs=P("user"),
    )
    np.testing.assert_allclose(per_device(rhos), plain, rtol=1e-5, atol=1e-6 * np.abs(plain).max())
    pinned = jax.device_put(rhos[0], jax.devices()[1])
    signal = grt.forward(points, pinned, tx, rx, radar.frequencies)
    np.testing.assert_allclose(signal, plain[0], rtol=1e-5, atol=1e-6 * np.abs(plain).max())
    assert signal.sharding.device_set == {jax.devices()[1]}
