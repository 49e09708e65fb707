"""Synthesis demo: the paper's sphere seen from a ring of viewpoints, and its backprojection.

    python -m experiments.synthesis_demo [--scale quick|default] [--out DIR]

Synthesises the normalised signals of the sphere (r = 2 m, 0.2 m grid, paper radar), then
backprojects them (the operator's adjoint) onto the 0.4 m grid, and writes a figure of the
signal of one view and maximum-intensity projections of the backprojection, plus timings.
(A placeholder main job until the weak-target experiment lands.)
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

import rift_jax as rj

from ._output import save_figure, write_json


@dataclasses.dataclass(frozen=True)
class Config:
    n_azimuth: int = 24
    n_polar: int = 12
    forward_granularity: float = 0.2
    inverse_granularity: float = 0.4
    out: str = "results/synthesis_demo"


SCALES = {"quick": Config(n_azimuth=4, n_polar=3), "default": Config()}


def main(cfg: Config) -> dict:
    out = Path(cfg.out)
    scene = rj.scenes.sphere(cfg.forward_granularity)
    viewpoints = rj.Viewpoints.grid(cfg.n_azimuth, cfg.n_polar, polar_range=(0.1, np.pi - 0.1))
    radar = rj.Radar()
    print(f"devices: {jax.devices()}")
    print(f"sphere: {scene.occupied()[1].size} occupied voxels; {len(viewpoints)} viewpoints")

    start = time.perf_counter()
    data = rj.synthesize(scene, viewpoints, radar)
    data.signal.block_until_ready()
    synth_s = time.perf_counter() - start
    print(f"synthesised {data.signal.shape} in {synth_s:.1f} s (compile included)")

    inverse = rj.Scene.empty(scene.extent, cfg.inverse_granularity)
    op = rj.grt_operator(radar, viewpoints, inverse.points())
    start = time.perf_counter()
    image = eqx.filter_jit(op.fn.adjoint)(data.signal)
    image = np.abs(np.asarray(image)).reshape(inverse.shape)
    back_s = time.perf_counter() - start
    print(f"backprojected onto {inverse.shape} in {back_s:.1f} s (compile included)")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(15, 3.4))
    axes[0].imshow(np.abs(np.asarray(data.signal[0, :, :, 0])).T, aspect="auto", origin="lower")
    axes[0].set(title="|S| of view 0, RX 0", xlabel="frequency index", ylabel="TX")
    span = [-scene.extent, scene.extent, -scene.extent, scene.extent]
    for ax, axis, name in zip(axes[1:], (2, 1, 0), ("x-y", "x-z", "y-z"), strict=True):
        ax.imshow(image.max(axis=axis).T, origin="lower", extent=span, cmap="magma")
        ax.set(title=f"backprojection MIP ({name})", xlabel="m", ylabel="m")
    figure = save_figure(fig, out / "synthesis_demo.png")
    summary = {
        "config": dataclasses.asdict(cfg),
        "occupied_voxels": int(scene.occupied()[1].size),
        "signal_shape": list(data.signal.shape),
        "scale": data.scale,
        "synthesis_seconds": synth_s,
        "backprojection_seconds": back_s,
        "versions": {"rift_jax": rj.__version__, "jax": jax.__version__},
    }
    results = write_json(out / "results.json", summary)
    print(f"wrote {figure} and {results}")
    return summary


def cli(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", choices=sorted(SCALES), default="default")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    cfg = SCALES[args.scale]
    if args.out:
        cfg = dataclasses.replace(cfg, out=args.out)
    return main(cfg)


if __name__ == "__main__":
    cli()
