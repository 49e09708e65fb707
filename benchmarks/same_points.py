"""Methods on the same points: least squares and RIFT on the data's own grid, beside the
inverse grid every other comparison uses.

    RIFT_JAX_CPU_DEVICES=1 python -m benchmarks.same_points [--scenes parking_lot,pyramid]
                                                             [--snrs none,0]

Training RIFT down to the forward granularity (``train_granularity``) fits it on the grid
the data were made on: the "inverse crime" the paper's two grids avoid. A comparison with
least squares on the inverse grid, twice as coarse, then puts the methods on different
points. This benchmark puts them on the same ones. At the stress grid's default scale
(±4.8 m, forward 0.4 m / inverse 0.8 m, 16 frequencies, 8 × 8 antennas, 100 training and
20 test views, seed 0), every method on ``support="auto"``, it prints per scene and noise:
LSMR and FISTA on the 0.4 m grid, RIFT(N) trained coarse to fine down to it, and FISTA and
RIFT(N) on the 0.8 m grid alone, each with m-SSIM, unseen-view p-RMSE (rad), the data
residual (`fit`'s check) and seconds (compilation included), and the machine's matmul rate.
"""

from __future__ import annotations

import argparse
import time
import warnings

import rift_jax as rj
from experiments.runner import build_scene, draw, noise_name

from ._timing import complex_matmul_rate

FORWARD, INVERSE, EXTENT = 0.4, 0.8, 4.8
RUNS = {
    "LSMR, data's 0.4 m grid": {"method": "lsmr", "granularity": FORWARD},
    "FISTA, data's 0.4 m grid": {"method": "fista", "granularity": FORWARD},
    "RIFT(N), 0.8 m trained down to 0.4 m": {"method": "rift-n", "train_granularity": FORWARD},
    "FISTA, 0.8 m grid": {"method": "fista"},
    "RIFT(N), 0.8 m grid": {"method": "rift-n"},
}


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="parking_lot,pyramid,cube,random-0")
    parser.add_argument("--snrs", default="none,0", help="SNRs in dB, 'none': noise-free")
    args = parser.parse_args(argv)
    snrs = [None if s == "none" else float(s) for s in args.snrs.split(",")]
    radar = rj.Radar(n_frequencies=16, n_tx=8, n_rx=8)
    train, test = draw(rj.Viewpoints.grid(), 100, 20, 0)
    print(f"this machine's complex64 matmul (1024³): {complex_matmul_rate():.1f} G/s")
    print("| scene | noise | run | m-SSIM | p-RMSE (rad) | residual | s |")
    print("|---|---|---|---|---|---|---|")
    rows = []
    for name in args.scenes.split(","):
        scene = build_scene(name, FORWARD, EXTENT)
        for snr in snrs:
            for label, options in RUNS.items():
                start = time.perf_counter()
                with warnings.catch_warnings():  # a failed fit is a row here, not a warning
                    warnings.simplefilter("ignore", rj.FitWarning)
                    result = rj.fit(scene, train, radar=radar, snr_db=snr, progress=False,
                                    **options)  # fmt: skip
                metrics = result.evaluate(scene, test)
                row = {"scene": name, "noise": noise_name(snr), "run": label, **metrics}
                row |= {"data_residual": result.stats["data_residual"]}
                row |= {"seconds": time.perf_counter() - start}
                rows.append(row)
                print(
                    f"| {name} | {row['noise']} | {label} | {row['m_ssim']:.3f} | "
                    f"{row['p_rmse']:.3f} | {row['data_residual']:.3f} | {row['seconds']:.0f} |",
                    flush=True,
                )
    return rows


if __name__ == "__main__":
    main()
