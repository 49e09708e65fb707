"""What a support buys: the cube at the paper's grids, on a hand-made support and on the
whole grid (issue: skip what a scene doesn't need).

    python -m benchmarks.support [--repeats 3] [--epochs 100] [--full-epochs 2]

Workload: the cube (2 m, ρ = 1) synthesised on the paper's forward grid (0.2 m over ±5 m,
51³), reconstructed on its inverse grid (0.4 m, 26³ = 17,576 points) from 100 training
viewpoints, scored on 100 others. The support is the truth on the inverse grid dilated by
one voxel. Prints, in one run:

- the machine's complex64 matmul rate;
- the operator's forward + adjoint over the 100 views, on the support and on the grid
  (medians), and their ratio;
- RIFT(N)-100 with the default recipe on the support: seconds and metrics;
- RIFT(N)-100 on the whole grid for ``--full-epochs`` epochs, and the whole run's time
  estimated from its seconds per epoch (the full run takes ~half an hour here);
- LSMR (20 steps) on the support and on the whole grid: seconds and metrics.
"""

from __future__ import annotations

import argparse

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import scipy.ndimage

import rift_jax as rj

from ._timing import complex_matmul_rate, median_seconds


def cube_support(scene: rj.Scene, grid: rj.Scene) -> np.ndarray:
    """The inverse-grid voxels nearest to the truth's (both, for a forward point halfway
    between two), dilated by one voxel."""
    points, _ = scene.occupied()
    position = (points + grid.extent) / grid.granularity
    mask = np.zeros(grid.shape, bool)
    for index in (np.floor(position + 1e-6), np.ceil(position - 1e-6)):
        mask[tuple(np.clip(index, 0, grid.shape[0] - 1).astype(int).T)] = True
    return scipy.ndimage.binary_dilation(mask)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--epochs", type=int, default=100)
    parser.add_argument("--full-epochs", type=int, default=2)
    args = parser.parse_args(argv)
    if args.full_epochs < 2:
        parser.error("--full-epochs must be at least 2 (the first epoch compiles)")

    radar = rj.Radar()
    scene = rj.scenes.cube(0.2)
    train, test = rj.Viewpoints.grid().split(100, 100, seed=0)
    grid = rj.Scene.empty(5.0, 0.4)
    support = cube_support(scene, grid)
    out = {"support_points": int(support.sum()), "grid_points": int(support.size)}
    print(f"support: {support.sum()} of {support.size} points")
    rate = complex_matmul_rate(repeats=args.repeats)
    out["matmul_G_per_s"] = rate
    print(f"complex64 matmul (1024³): {rate:.2f} G/s")

    for name, points in (("support", grid.points()[support.ravel()]), ("grid", grid.points())):
        op = rj.grt_operator(radar, train, points)
        both = eqx.filter_jit(lambda x, op=op: op.fn.adjoint(op.mv(x)))
        x = jnp.ones(len(points), jnp.complex64)
        out[f"forward_adjoint_{name}_s"] = median_seconds(both, x, repeats=args.repeats)
        print(f"forward + adjoint, 100 views, {name}: {out[f'forward_adjoint_{name}_s']:.3f} s")
    ratio = out["forward_adjoint_grid_s"] / out["forward_adjoint_support_s"]
    out["operator_speedup"] = ratio
    print(f"operator on the support: {ratio:.1f}x faster")

    common = dict(radar=radar, progress=False)
    runs = {
        "rift-n support": dict(method="rift-n", support=support, epochs=args.epochs),
        "rift-n grid (partial)": dict(method="rift-n", epochs=args.full_epochs),
        "lsmr support": dict(method="lsmr", support=support, iterations=20, tol=0.0),
        "lsmr grid": dict(method="lsmr", iterations=20, tol=0.0),
    }
    for name, options in runs.items():
        result = rj.fit(scene, train, **common, **options)
        metrics = result.evaluate(scene, test)
        out[name] = {"seconds": result.seconds, **metrics}
        print(
            f"{name:22s} {result.seconds:7.1f} s  m-SSIM {metrics['m_ssim']:.3f}  "
            f"m-COS {metrics['m_cos']:.3f}  t-IoU {metrics['t_iou']:.3f}  "
            f"p-RMSE {metrics['p_rmse']:.3f}  residual {metrics['residual']:.3f}"
        )
        if "partial" in name:
            per_epoch = float(np.median(np.diff(result.history.seconds)))
            estimate = result.history.seconds[0] + per_epoch * (args.epochs - 1)
            out["rift-n grid estimate_s"] = estimate
            print(f"{'':22s} {per_epoch:.1f} s per epoch: {args.epochs} epochs ≈ {estimate:.0f} s")
    speedup = out["rift-n grid estimate_s"] / out["rift-n support"]["seconds"]
    out["rift_speedup_estimate"] = speedup
    print(f"RIFT(N)-100 on the support: ≈ {speedup:.0f}x faster than on the whole grid")
    return out


if __name__ == "__main__":
    main()
