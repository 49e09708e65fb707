"""What FISTA's λ chosen on held-out views costs, and what it buys, against the fixed λ.

    python -m benchmarks.fista_lambda [--scenes cube,random-0] [--views 30,100] [--repeats 3]
                                      [--out results/fista_lambda.json]

At the stress grid's default scale (±4.8 m, forward 0.4 m / inverse 0.8 m, 16 frequencies,
8 × 8 antennas, 20 test views, seed 0, noise-free), on one support per cell (estimated
once, outside the timing, as `fit`'s ``support="auto"`` would), it fits FISTA with the old
fixed ``sparsity=0.05`` and with ``sparsity="auto"`` (the default), each compiled first
and timed as the median of ``--repeats`` fits, and prints both beside each other with
their m-SSIM, m-COS and t-IoU, the sparsity chosen, the ratio of their times, and the
machine's matmul rate, and writes the rows and the rate to ``--out`` (JSON, atomically).
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings
from pathlib import Path

import numpy as np

import rift_jax as rj
from experiments import stability
from experiments.runner import build_scene, draw, write_json

from ._timing import complex_matmul_rate

SCALE = stability.SCALES["default"]  # the stress grid's: its scenes' size, grids and radar
SPARSITIES = {"fixed 0.05": 0.05, "held-out": "auto"}


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="cube,random-0")
    parser.add_argument("--views", default="30,100")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path("results/fista_lambda.json"))
    args = parser.parse_args(argv)
    radar = SCALE.radar()
    grid = rj.Scene.empty(SCALE.extent, SCALE.inverse)
    rate = complex_matmul_rate()
    print(f"this machine's complex64 matmul (1024³): {rate:.1f} G/s")
    print("| scene | views | λ | sparsity | m-SSIM | m-COS | t-IoU | median s | × fixed |")
    print("|---|---|---|---|---|---|---|---|---|")
    rows = []
    for name in args.scenes.split(","):
        scene = build_scene(name, SCALE.forward, SCALE.extent)
        for n_views in map(int, args.views.split(",")):
            train, test = draw(rj.Viewpoints.grid(), n_views, SCALE.n_test, 0)
            data = rj.synthesize(scene, train, radar)
            signal = np.asarray(data.signal) * data.scale
            support = rj.estimate_support(signal, train, grid, radar=radar)
            seconds = {}
            for label, sparsity in SPARSITIES.items():
                fit = dict(radar=radar, extent=SCALE.extent, granularity=SCALE.inverse,
                           method="fista", support=support, sparsity=sparsity,
                           progress=False)  # fmt: skip

                def run(signal=signal, train=train, fit=fit):
                    with warnings.catch_warnings():  # a failed fit is a row here
                        warnings.simplefilter("ignore", rj.FitWarning)
                        return rj.fit(signal, train, **fit)

                result = run()  # compiles; `fit` blocks until its result is ready
                times = []
                for _ in range(args.repeats):
                    start = time.perf_counter()
                    run()
                    times.append(time.perf_counter() - start)
                seconds[label] = statistics.median(times)
                metrics = result.evaluate(scene, test)
                row = {
                    "scene": name,
                    "views": n_views,
                    "lambda": label,
                    "sparsity": result.stats["sparsity"],
                    "seconds": seconds[label],
                }
                row |= {k: metrics[k] for k in ("m_ssim", "m_cos", "t_iou")}  # fmt: skip
                rows.append(row)
                ratio = seconds[label] / seconds["fixed 0.05"]
                print(f"| {name} | {n_views} | {label} | {row['sparsity']:g} | "
                      f"{row['m_ssim']:.3f} | {row['m_cos']:.3f} | {row['t_iou']:.3f} | "
                      f"{row['seconds']:.2f} | {ratio:.1f} |", flush=True)  # fmt: skip
    write_json(args.out, {"matmul_G_per_s": rate, "repeats": args.repeats, "rows": rows})
    print(f"wrote {args.out}")
    return rows


if __name__ == "__main__":
    main()
