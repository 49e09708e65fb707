"""Predict what the radar sees from viewpoints it was never trained on.

    python docs/examples/unseen_viewpoints.py --out unseen_viewpoints/

Trains on 40 viewpoints above the pyramid (polar angles 0.3-1.2 rad from the zenith) and
predicts the signals of 20 viewpoints below them (1.4-1.6 rad, near the horizon), where
no training view looked from. Four reconstructions of the same data (0.4 m grid): least
squares (LSMR) and RIFT(N) on the paper's 2x coarser inverse grid, LSMR on the data's own
grid, and RIFT(N) trained coarse to fine, ending on the data's grid. Writes
``unseen_viewpoints.png`` (predicted against true phase, per method) and
``unseen_viewpoints.json`` (p-RMSE and residual per method), and prints a Markdown table.
"""

import argparse
import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import rift_jax as rj  # noqa: E402

RUNS = {  # label: fit options
    "LSMR, 0.8 m grid": dict(method="lsmr", granularity=0.8, iterations=100),
    "RIFT(N), 0.8 m grid": dict(method="rift-n", granularity=0.8, epochs=50),
    "LSMR, 0.4 m grid": dict(method="lsmr", granularity=0.4, iterations=50),
    "RIFT(N), 0.8 m → 0.4 m": dict(
        method="rift-n", granularity=0.8, epochs=50, train_granularity=0.4
    ),
}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("unseen_viewpoints"))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    radar = rj.Radar(n_frequencies=16, n_tx=8, n_rx=8)  # the paper's: 100, 16 x 16
    scene = rj.scenes.pyramid(0.4, extent=2.4)  # 2 m base at z = -1, apex at z = +1
    turn = 2 * math.pi * 9 / 10  # 10 azimuths without repeating 0 at 2π
    train = rj.Viewpoints.grid(10, 4, (0.0, turn), polar_range=(0.3, 1.2))
    test = rj.Viewpoints.grid(10, 2, (0.3, turn + 0.3), polar_range=(1.4, 1.6))
    truth = rj.synthesize(scene, test, radar).signal  # what the unseen views would record

    rows, predictions = {}, {}
    for label, options in RUNS.items():
        result = rj.fit(scene, train, radar=radar, seed=args.seed, progress=False, **options)
        predictions[label] = result.predict(test).signal
        rows[label] = {
            "p_rmse": rj.metrics.p_rmse(predictions[label], truth),
            "residual": result.residual,
            "m_ssim": rj.metrics.m_ssim(result.scene, scene),
            "seconds": result.seconds,
        }
        print(f"{label}: p-RMSE {rows[label]['p_rmse']:.3f} rad")

    lines = ["| reconstruction | p-RMSE, unseen views (rad) | data residual | m-SSIM |"]
    lines += ["|---|---|---|---|"] + [
        f"| {label} | {r['p_rmse']:.3f} | {r['residual']:.3f} | {r['m_ssim']:.3f} |"
        for label, r in rows.items()
    ]
    print("\n".join(lines))
    (args.out / "unseen_viewpoints.json").write_text(json.dumps(rows, indent=1))

    # 3,000 samples of the unseen views whose magnitude is at least 10 % of the peak: their
    # true phase against the predicted one. A perfect prediction lies on the diagonal (mod 2π).
    truth = np.asarray(truth).ravel()
    strong = np.flatnonzero(np.abs(truth) >= 0.1)
    strong = np.random.default_rng(0).choice(strong, min(3000, strong.size), replace=False)
    fig, axes = plt.subplots(2, 2, figsize=(7, 7), sharex=True, sharey=True)
    for ax, (label, predicted) in zip(axes.flat, predictions.items(), strict=True):
        predicted = np.asarray(predicted).ravel()
        ax.scatter(np.angle(truth[strong]), np.angle(predicted[strong]), s=3, alpha=0.4)
        ax.plot([-math.pi, math.pi], [-math.pi, math.pi], color="k", lw=0.8)
        ax.set_title(f"{label}: p-RMSE {rows[label]['p_rmse']:.2f} rad", fontsize=10)
        ax.set_xlim(-math.pi, math.pi)
        ax.set_ylim(-math.pi, math.pi)
    for ax in axes[1]:
        ax.set_xlabel("true phase (rad)")
    for ax in axes[:, 0]:
        ax.set_ylabel("predicted phase (rad)")
    fig.suptitle(f"{len(test)} unseen viewpoints below the {len(train)} training views")
    fig.tight_layout()
    fig.savefig(args.out / "unseen_viewpoints.png", dpi=110)
    return rows


if __name__ == "__main__":
    main()
