"""Reconstruct a scene from a file of radar measurements, as you would your own data.

    python docs/examples/your_own_data.py --out your_own_data

Step 1 stands in for your measurements: it synthesises the signals a small pyramid returns
to 30 viewpoints and saves them to ``measurements.h5``, the file your own tools would write
(its layout: docs/examples/your_own_data.md). From step 2 on, the script only reads that
file: it loads the signals, radar and viewpoints, reconstructs the scene by least squares,
saves the reconstruction (``reconstruction.h5``), exports its bright voxels as a point
cloud for 3-D viewers (``reconstruction.ply``: MeshLab, CloudCompare, ParaView), and draws
its maximum-intensity projections beside a 3-D view (``your_own_data.png``).
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no window

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import rift_jax as rj  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("your_own_data"), help="folder")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    # 1. Measurements (stand-in): a 1.4 m pyramid seen from 30 directions, 20 dB SNR.
    radar = rj.Radar(n_frequencies=16, n_tx=8, n_rx=8)
    truth = rj.scenes.pyramid(0.2, extent=1.0, base=1.4, height=1.4)
    viewpoints = rj.Viewpoints.grid(6, 5, azimuth_range=(0, 5 / 3 * np.pi), polar_range=(0.3, 1.5))
    rj.save(args.out / "measurements.h5", rj.synthesize(truth, viewpoints, radar, snr_db=20))

    # 2. Load them: signals (n_views, n_freq, n_tx, n_rx), their Radar and Viewpoints.
    data = rj.load(args.out / "measurements.h5")
    print(f"loaded {data.signal.shape} signals from {len(data.viewpoints)} viewpoints")

    # 3. Reconstruct on a 0.2 m grid over ±1 m, and keep the result.
    result = rj.fit(
        data,
        data.viewpoints,
        extent=1.0,
        granularity=0.2,
        method="lsmr",
        iterations=30,
        progress=False,
    )
    rj.save(args.out / "reconstruction.h5", result)
    print(f"lsmr: relative residual {result.residual:.3f} in {result.seconds:.1f} s")

    # 4. Export for 3-D viewers: voxels with |ρ| ≥ 30 % of the brightest.
    rj.export_ply(args.out / "reconstruction.ply", result, threshold=0.3)

    # 5. The figure: maximum-intensity projections and a 3-D view of the same voxels.
    figure(result.scene, threshold=0.3).savefig(args.out / "your_own_data.png", dpi=110)
    return result


def figure(scene, threshold):
    """|ρ| projected along z, y and x (the brightest voxel on each line of sight), and the
    voxels with |ρ| ≥ ``threshold``·max as a 3-D scatter coloured by |ρ|."""
    magnitude = np.abs(np.asarray(scene.reflectivity))
    peak, edge = magnitude.max(), scene.extent + scene.granularity / 2
    fig = plt.figure(figsize=(14, 3.8), layout="constrained")
    grid = fig.add_gridspec(1, 4, width_ratios=(1, 1, 1, 1.25))
    for i, (axis, (a, b)) in enumerate(zip((2, 1, 0), ("xy", "xz", "yz"), strict=True)):
        ax = fig.add_subplot(grid[i])
        image = ax.imshow(
            magnitude.max(axis=axis).T,
            origin="lower",
            cmap="viridis",
            vmin=0,
            vmax=peak,
            extent=(-edge, edge, -edge, edge),
        )
        ax.set(title=f"MIP over {'zyx'[i]}", xlabel=f"{a} (m)", ylabel=f"{b} (m)")
    ax = fig.add_subplot(grid[3], projection="3d")
    keep = magnitude.ravel() >= threshold * peak
    x, y, z = scene.points()[keep].T
    ax.scatter(x, y, z, c=magnitude.ravel()[keep], cmap="viridis", vmin=0, vmax=peak, s=30)
    ticks = (-scene.extent, 0, scene.extent)
    ax.set(xticks=ticks, yticks=ticks, zticks=ticks, xlabel="x (m)", ylabel="y (m)")
    ax.set(zlabel="z (m)", title=f"3-D: |ρ| ≥ {threshold:.0%} of max")
    ax.set_box_aspect((1, 1, 1), zoom=0.9)
    fig.colorbar(image, ax=ax, label="|ρ|", shrink=0.8, pad=0.1)
    return fig


if __name__ == "__main__":
    main()
