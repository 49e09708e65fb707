"""rift_jax on several hosts: one process per host, every device of every host working.

Launch one copy per host, the same command on each but for ``--process-id``:

    python docs/examples/multihost.py --coordinator HOST0:12355 --processes 2 --process-id 0
    python docs/examples/multihost.py --coordinator HOST0:12355 --processes 2 --process-id 1

(Under SLURM, or another launcher JAX knows, leave the three options out:
``jax.distributed.initialize()`` then finds them itself.) Every process builds the same
radar, viewpoints and grid; JAX then sees every host's devices, and rift_jax splits the
viewpoints over all of them. Process 0 writes the results to ``--out``.
"""

import argparse

import jax


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--coordinator", help="HOST:PORT of process 0")
    parser.add_argument("--processes", type=int)
    parser.add_argument("--process-id", type=int)
    parser.add_argument("--out", default="multihost.npz")
    args = parser.parse_args(argv)

    # Before anything else touches JAX's devices. CPU hosts talk through gloo; GPUs use NCCL.
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(args.coordinator, args.processes, args.process_id)  # None: found

    import numpy as np

    import rift_jax as rj

    radar = rj.Radar(n_frequencies=16, n_tx=8, n_rx=8)
    scene = rj.scenes.cube(0.25, extent=1.0, edge=1.0)
    train, test = rj.Viewpoints.grid(6, 4, polar_range=(0.4, 1.2)).split(20, 4, seed=0)
    print(
        f"process {jax.process_index()}: {jax.local_device_count()} of {jax.device_count()} devices"
    )

    # Synthesis, the operator, every solver and RIFT split the views over all devices of all
    # hosts; what comes back to Python (data, reconstructions) is gathered to every process.
    data = rj.synthesize(scene, train, radar)
    lsmr = rj.fit(
        data, train, method="lsmr", granularity=0.25, extent=1.0, iterations=20, progress=False
    )
    rift = rj.fit(  # each epoch 5 passes over the 20 views (`epoch_views`): 10 steps
        data, train, method="rift-n", granularity=0.25, extent=1.0, epochs=4, progress=False
    )
    scores = {
        name: r.evaluate(scene, test)["m_ssim"] for name, r in (("lsmr", lsmr), ("rift", rift))
    }
    print(f"process {jax.process_index()}: m-SSIM {scores}")
    if jax.process_index() == 0:
        np.savez(
            args.out,
            signal=np.asarray(data.signal),
            lsmr=np.asarray(lsmr.scene.reflectivity),
            rift=np.asarray(rift.scene.reflectivity),
        )


if __name__ == "__main__":
    main()
