"""Ideas that could let RIFT beat FISTA where data are scarce and noisy, on the stress grid.

    python -m experiments.rift_ideas [--scale quick|default] [--out DIR] [--seed 0]
                                     [--resume] [--no-progress] [--part K/N]

Each idea is `fit(method="rift-n")` at its defaults plus one option (`IDEAS`):

- **LS start** (``init="fista"``): training starts from the INR fitted to FISTA's image on
  the same support and data (`rift_jax.solvers.rift`, ``init``);
- **sparsity** (``sparsity=0.1``): the loss gains ‖ρ‖₁/(√k‖ρ‖₂), a scale-free sparsity
  prior, FISTA's kind of prior (`rift_jax.solvers.Recipe`);
- **hash grid** (``model="hash-grid"``): a multiresolution hash encoding and a small MLP
  (`rift_jax.HashGrid`, Instant-NGP's, as DART uses) in place of RIFT(N)'s MLP;
- **robust loss** (``loss="robust"``): the default before complex MSE, which fits |P| to
  |S| entry by entry, the noise's magnitude included; kept to show what the change did
  (docs/rift.md, "On the stress grid: complex MSE against the robust loss": MSE better in
  28 of 40 cells from 30 and 100 views).

They run on the stress grid's cells where a prior should matter most (10 and 30 training
views at 0 dB; `experiments.stability`), beside RIFT(N) and FISTA at their defaults, each
cell on the very data of its stress-grid cell (the same scene, draw of views, noise and
seed), so every method in a cell is on the same points and data. Scales: quick (the
tests: the stress grid's quick scale) and default (the stress grid's default scale; 68
minutes on 2 cores for three ideas when an epoch from 10 views was one step, ~2-3 hours for
four now that it is ten, `Recipe.epoch_views`, estimated from ~80 s per RIFT run).

Writes results.json, results.md (per cell every variant's m-SSIM; per variant the cells
where it is at least FISTA's and its median) and reconstructions.npz into ``--out``.
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from pathlib import Path

import numpy as np

from . import stability
from .runner import Run, command, environment_line, write_atomic

IDEAS = {
    "RIFT(N)+LS start": {"init": "fista"},
    "RIFT(N)+sparsity": {"sparsity": 0.1},
    "RIFT(hash grid)": {"model": "hash-grid"},
    "RIFT(N)+robust loss": {"loss": "robust"},
}
VARIANTS = ("RIFT(N)", *IDEAS, "FISTA")
SNR = 0.0  # the cells: 0 dB, from the stress grid's two fewest view counts
SCALES = {
    name: dataclasses.replace(stability.SCALES[name], methods=("rift-n", "fista"))
    for name in ("quick", "default")
}


def runs(cfg: stability.Config) -> list[Run]:
    """The stress grid's RIFT(N) and FISTA runs in the cells studied (their seeds as the
    grid rotates them), and each idea's run beside its RIFT(N) one."""
    views = sorted(cfg.views)[:2]
    out = []
    for run in stability.runs(cfg):
        if run.n_train not in views or run.options.get("snr_db") != SNR:
            continue
        out.append(run)
        if run.method == "rift-n":
            for idea, extra in IDEAS.items():
                label = idea + run.label.removeprefix("RIFT(N)")
                out.append(dataclasses.replace(run, label=label, options=run.options | extra))
    return out


def variant(row: dict) -> str:
    """The row's variant: its label up to the number of views."""
    return row["run"].rsplit(" views", 1)[0].rsplit(" ", 1)[0]


def report(results: dict, volumes: dict, figures: bool, cfg: stability.Config, out: Path) -> None:
    rows = [row | {"method": variant(row)} for row in results["rows"]]
    for row in rows:
        row["noise"] = stability.noise_name(row["options"].get("snr_db"))
    cells = sorted({stability._cell(r) for r in rows}, key=lambda c: (c[1], c[0]))
    ssim = {(stability._cell(r), r["method"]): r["m_ssim"] for r in rows}
    lines = [
        f"# RIFT's ideas against FISTA, scale `{results['scale']}`",
        "",
        f"The stress grid's cells at {stability.noise_name(SNR)} from "
        f"{' and '.join(map(str, sorted(cfg.views)[:2]))} training views (its scale "
        f"`{results['scale']}`: the same scenes, radar, grids and data, one seed per cell as "
        "the grid rotates them). Every variant at `fit`'s defaults plus its own option: "
        + "; ".join(f"{name}: `{opts}`" for name, opts in IDEAS.items())
        + ". m-SSIM (↑):",
        "",
        "| scene | views | seed | " + " | ".join(VARIANTS) + " |",
        "|---|---|---|" + "---|" * len(VARIANTS),
    ]
    seeds = {stability._cell(r): r["seed"] for r in rows}
    for cell in cells:
        values = [ssim.get((cell, v)) for v in VARIANTS]
        best = max((v for v in values if v is not None), default=None)
        shown = [
            "–" if v is None else (f"**{v:.3f}**" if v == best else f"{v:.3f}") for v in values
        ]
        lines.append(f"| {cell[0]} | {cell[1]} | {seeds[cell]} | " + " | ".join(shown) + " |")
    lines += ["", "| variant | cells at least FISTA's | median m-SSIM | median seconds |"]
    lines.append("|---|---|---|---|")
    seconds = defaultdict(list)
    for row in rows:
        seconds[row["method"]].append(row["fit_seconds"])
    for name in VARIANTS:
        pairs = [(ssim.get((c, name)), ssim.get((c, "FISTA"))) for c in cells]
        pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
        mine = [ssim[c, name] for c in cells if (c, name) in ssim]
        if not mine:
            continue
        lines.append(
            f"| {name} | {sum(a >= b for a, b in pairs)} of {len(pairs)} | "
            f"{np.median(mine):.3f} | {np.median(seconds[name]):.0f} |"
        )
    lines += ["", environment_line(results), ""]
    write_atomic(out / "results.md", "\n".join(lines))


def main(
    cfg: stability.Config,
    *,
    out: Path,
    scale: str = "custom",
    seed: int = 0,
    resume: bool = False,
    progress: bool = True,
    part: tuple[int, int] | None = None,
) -> dict:
    """Every run of ``cfg``'s cells studied; the results dict as in ``out/results.json``."""
    results = stability.on_the_grid(
        "rift_ideas", cfg, runs(cfg), report, out=out, scale=scale, seed=seed, resume=resume,
        progress=progress, part=part,
    )  # fmt: skip
    print(f"{len(results['rows'])} runs; wrote results.md, results.json to {out}/")
    return results


def cli(argv=None) -> dict:
    return command(argv, __doc__, SCALES, "rift_ideas", main)


if __name__ == "__main__":
    cli()
