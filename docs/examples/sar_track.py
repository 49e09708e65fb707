"""Reconstruct a scene from a monostatic circular SAR track, stored in and read from HDF5.

    python docs/examples/sar_track.py --out sar_track

A radar of your own: one antenna that transmits and receives (monostatic), 32 frequencies,
flown on three circles around the scene (2, 4 and 6 m up, 8 m out, 24 pulses each) and
looking at its centre. Step 1 stands in for the measurement: it synthesises the signals a
small pyramid returns, with 20 dB of noise, and writes them to ``sar_track.h5`` with the
radar and every pulse's pose. From step 2 on, the script only reads that file: it
reconstructs with FISTA on the 0.2 m grid the pyramid was made on (a scatterer between
grid points is another matter: see the page), and draws the track and the images.
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no window

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import rift_jax as rj  # noqa: E402


def track(radius=8.0, heights=(2.0, 4.0, 6.0), pulses=24):
    """Positions (n, 3) of circular passes at these heights, ``pulses`` per circle."""
    angle = np.linspace(0.0, 2 * np.pi, pulses, endpoint=False)
    return np.concatenate(
        [np.stack([radius * np.cos(angle), radius * np.sin(angle), np.full(pulses, h)], 1)
         for h in heights]
    )  # fmt: skip


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("sar_track"), help="folder")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    # 1. The measurement (stand-in): one antenna at the radar frame's origin, 32 frequencies
    #    over 95-105 GHz, looking at the scene's centre from each pulse's position.
    radar = rj.Radar.from_antennas(
        tx=[[0.0, 0.0, 0.0]], rx=[[0.0, 0.0, 0.0]], frequencies=np.linspace(95e9, 105e9, 32)
    )
    poses = rj.Viewpoints.from_poses(track(), look_at=(0.0, 0.0, 0.0))
    truth = rj.scenes.pyramid(0.2, extent=1.0, base=1.4, height=1.4)
    rj.save(args.out / "sar_track.h5", rj.synthesize(truth, poses, radar, snr_db=20))

    # 2. Read it back: signals (n_pulses, n_freq, 1, 1), the radar and the poses.
    data = rj.load(args.out / "sar_track.h5")
    print(f"loaded {data.signal.shape} signals from {len(data.viewpoints)} poses")

    # 3. Reconstruct on the 0.2 m grid over ±1 m with FISTA on an estimated support, and
    #    keep the result. (Leave `method` out and fit also trains RIFT(N), keeping whichever
    #    predicts held-out poses better: about three fits' time.)
    result = rj.fit(
        data, data.viewpoints, extent=1.0, granularity=0.2, method="fista", progress=False
    )
    rj.save(args.out / "sar_track_fit.h5", result)
    print(
        f"{result.method}: relative residual {result.residual:.3f}, "
        f"m-SSIM {rj.metrics.m_ssim(result.scene, truth):.3f}, "
        f"t-IoU {rj.metrics.t_iou(result.scene, truth):.3f} in {result.seconds:.1f} s"
    )
    figure(data.viewpoints, truth, result.scene).savefig(args.out / "sar_track.png", dpi=110)
    return result


def figure(viewpoints, truth, reconstruction):
    """The track around the scene's box, and |ρ| of the truth and of the reconstruction
    projected along y (the brightest voxel on each line of sight)."""
    fig = plt.figure(figsize=(13, 4), layout="constrained")
    ax = fig.add_subplot(1, 3, 1, projection="3d")
    x, y, z = viewpoints.positions.T
    ax.plot(x, y, z, ".", color="tab:red", label="pulses")
    ax.quiver(x, y, z, *(0.15 * viewpoints.orientations[:, :, 2].T), color="tab:red", lw=0.5)
    edge = truth.extent
    signs = (-edge, edge)
    corners = np.array([[a, b, c] for a in signs for b in signs for c in signs])
    ax.scatter(*corners.T, color="black", s=4, label="scene box")
    ax.set(xlabel="x (m)", ylabel="y (m)", zlabel="z (m)", title="Monostatic circular track")
    ax.set_box_aspect((1, 1, 0.5))
    ax.legend(loc="upper left", fontsize="small")
    edge = truth.extent + truth.granularity / 2
    for i, (scene, title) in enumerate(((truth, "truth"), (reconstruction, "reconstruction"))):
        magnitude = np.abs(np.asarray(scene.reflectivity)).max(axis=1)
        ax = fig.add_subplot(1, 3, i + 2)
        image = ax.imshow(
            magnitude.T / magnitude.max(), origin="lower", cmap="viridis", vmin=0, vmax=1,
            extent=(-edge, edge, -edge, edge),
        )  # fmt: skip
        ax.set(title=f"{title}: max |ρ| over y", xlabel="x (m)", ylabel="z (m)")
    fig.colorbar(image, ax=ax, label="|ρ| / max", shrink=0.8)
    return fig


if __name__ == "__main__":
    main()
