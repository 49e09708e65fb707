"""What every paper experiment does: draw viewpoints, reconstruct, score, save, resume.

An experiment is a list of `Run`s over named scenes. `execute` fits each run with
`rift_jax.fit`, scores it with `FitResult.evaluate`, and after every run writes
``results.json`` (config, metrics, histories, wall times, versions) and
``reconstructions.npz`` (every reconstruction and the truths on the inverse grid) atomically,
then calls the experiment's `report` to redraw its table and figures. ``--resume`` keeps the
runs already written and does only the rest.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

import rift_jax as rj

from ._output import check_writable, write_atomic, write_json

MODEL_LABELS = {"rift-n": "RIFT(N)", "rift-s": "RIFT(S)"}
"""The paper's names of the `fit` methods that train an INR."""
STRONGEST_LS = "FISTA"  # the label of the strongest least squares (method "fista")


@dataclasses.dataclass(frozen=True)
class Run:
    """One reconstruction: ``method`` from ``n_train`` viewpoints of scene ``scene``."""

    scene: str
    label: str  # the paper's name: "LS-100", "RIFT(N)-1000", ...
    method: str  # a `rift_jax.fit` method
    n_train: int
    options: Mapping = dataclasses.field(default_factory=dict)  # passed to `fit`
    seed: int | None = None  # `fit`'s seed (the INR's start, the noise); None: the experiment's


def rift_options(n_train: int, steps: int, batch_views: int = 10) -> dict:
    """Options giving a RIFT run about ``steps`` optimizer steps whatever its number of
    views, so RIFT-100 and RIFT-1000 get the same compute; the learning rate halves three
    times (after a quarter, half and three quarters of the steps), as in the default
    recipe (every 25 of 100 epochs)."""
    epochs = max(1, round(steps * batch_views / n_train))
    return {"epochs": epochs, "halve_every": epochs / 4, "batch_views": batch_views}


@dataclasses.dataclass(frozen=True)
class Budget:
    """What each run of an experiment may spend, and when it stops early.

    Kaczmarz runs at most ``sweeps`` sweeps and stops once its residual stalls by ``ls_tol``
    (0: every sweep). RIFT runs about ``rift_steps`` optimizer steps of 10 views, stops after
    ``rift_patience`` epochs without progress (None: never), and trains only where
    |ρ| ≥ ``rift_prune``·max, re-chosen every ``recheck_every`` epochs (None: everywhere).
    ``support`` restricts every method to a support (`rift_jax.fit`'s option; None: the
    whole grid). FISTA, the strongest least squares (docs/solvers.md), runs at most
    ``fista_iterations`` and stops once converged (its default tol)."""

    sweeps: int
    rift_steps: int
    ls_tol: float = 0.0
    rift_prune: float | None = None
    rift_patience: int | None = None
    recheck_every: int = 10
    support: str | None = None
    fista_iterations: int = 100

    def ls(self) -> dict:
        """`fit` options of a Kaczmarz run."""
        return {"iterations": self.sweeps, "tol": self.ls_tol} | self._support()

    def fista(self) -> dict:
        """`fit` options of a FISTA run."""
        return {"iterations": self.fista_iterations} | self._support()

    def rift(self, n_train: int) -> dict:
        """`fit` options of a RIFT run from ``n_train`` views."""
        options = rift_options(n_train, self.rift_steps) | self._support()
        if self.rift_prune is not None:
            options |= {"prune": self.rift_prune, "recheck_every": self.recheck_every}
        if self.rift_patience is not None:
            options |= {"patience": self.rift_patience}
        return options

    def _support(self) -> dict:
        return {} if self.support is None else {"support": self.support}

    def describe(self, model: str = "RIFT", fista: bool = False) -> str:
        """The budgets in words, for a results page (FISTA's too, if it ran)."""
        ls = f"Kaczmarz {self.sweeps} sweep(s)"
        if self.ls_tol:
            ls = (
                f"Kaczmarz at most {self.sweeps} sweeps, stopped when the residual stalls "
                f"(tol {self.ls_tol:g})"
            )
        rift = f"{model} default recipe, {self.rift_steps} steps of 10 views per run"
        if self.rift_patience:
            rift = (
                f"{model} default recipe, at most {self.rift_steps} steps of 10 views per "
                f"run, stopped after {self.rift_patience} epochs without progress"
            )
        if self.rift_prune:
            rift += (
                f", trained where |ρ| ≥ {self.rift_prune:g}·max (an active set, re-chosen "
                f"every {self.recheck_every} epochs)"
            )
        text = f"{ls}; {rift}"
        if fista:
            text += (
                f"; FISTA (sparse prior, default λ) at most {self.fista_iterations} "
                "iterations, stopped once converged"
            )
        if self.support == "auto":
            text += (
                '; every method on the support estimated from its training data (`support="auto"`)'
            )
        return text


PAPER_STOPPING = {
    "ls_tol": 1e-3,
    "rift_prune": 0.05,
    "rift_patience": 10,
    "recheck_every": 2,
    "support": "auto",
}
"""How the paper-scale scene studies skip what a scene does not need: every method on the
support estimated from its data, RIFT on an active set, and each run stopped once
converged. The weak target takes all but the support (its 36° aperture leaves the
estimate 92-99 % of the grid: docs/solvers.md)."""


PAPER_SCENES = ("sphere", "cube", "pyramid", "parking_lot", "highway", "weak_target")


def build_scene(name: str, granularity: float, extent: float) -> rj.Scene:
    """The scene called ``name`` on the grid ±``extent`` at ``granularity``: a paper scene
    (the weak target at 4:1) or "random-K" (`rift_jax.scenes.random_primitives`, seed K)."""
    seed = name.removeprefix("random-")
    if name.startswith("random-") and seed.isdigit():
        return rj.scenes.random_primitives(int(seed), granularity, extent=extent)
    if name not in PAPER_SCENES:
        raise ValueError(
            f"build_scene: `name` must be one of {list(PAPER_SCENES)} or 'random-K', got {name!r}."
        )
    if name == "weak_target":
        return rj.scenes.weak_target(0.25, granularity, extent=extent)
    return getattr(rj.scenes, name)(granularity, extent=extent)


def noise_name(snr: float | None) -> str:
    """A noise level as the tables name it: "noise-free" or e.g. "20 dB"."""
    return "noise-free" if snr is None else f"{snr:g} dB"


def draw(pool: rj.Viewpoints, n_train: int, n_test: int, seed: int):
    """(train, test): one seeded test set shared by every run, and training sets drawn from
    the rest in one fixed order, so LS-100 ⊂ LS-200 ⊂ ... and all runs face the same test."""
    if n_train + n_test > len(pool):
        raise ValueError(
            f"draw: {n_train} training + {n_test} test viewpoints exceed the {len(pool)} in "
            "the pool."
        )
    test, train = pool.split(n_test, n_train, seed=seed)  # split's first draw is the test set
    return train, test


def fit_and_evaluate(scene, train, test, *, radar, method, granularity, seed, progress, options):
    """Reconstruct ``scene`` from its signals at ``train`` on the inverse grid of
    ``granularity`` and score it against the truth at ``test``: (FitResult, metrics).

    A run that diverges (least squares or RIFT) is scored on its best iterate before the
    divergence; its ``result.stopped`` says ``Outcome.DIVERGED`` and where (the paper, too,
    reports its failed runs)."""
    try:
        result = rj.fit(
            scene,
            train,
            radar=radar,
            method=method,
            granularity=granularity,
            seed=seed,
            progress=progress,
            **options,
        )
    except rj.solvers.Diverged as error:
        result = error.result
        print(f"{method}: {error}; scoring the best iterate before it", flush=True)
    return result, result.evaluate(scene, test)


def history_record(history) -> dict:
    """A run's `History` as JSON: seconds, relative residual and (RIFT) loss per iteration."""
    return {
        "seconds": history.seconds.tolist(),
        "residual": history.residual.tolist(),
        "loss": None if history.loss is None else history.loss.tolist(),
    }


def seconds_per_iteration(result) -> float:
    """The median seconds per iteration (sweep or epoch); the whole fit if it had one."""
    seconds = result.history.seconds
    return float(np.median(np.diff(seconds))) if len(seconds) > 1 else result.seconds


def versions() -> dict:
    import equinox
    import jax
    import jaxlib
    import lineax
    import optax
    import optimistix
    import skimage

    try:  # the commit that produced the results, when run from a git checkout
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = None
    return {
        "git_commit": commit,
        "rift_jax": rj.__version__,
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "equinox": equinox.__version__,
        "optax": optax.__version__,
        "lineax": lineax.__version__,
        "optimistix": optimistix.__version__,
        "numpy": np.__version__,
        "scikit-image": skimage.__version__,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "devices": [str(d) for d in jax.devices()],
        "cpu_count": os.cpu_count(),
    }


def execute(
    name: str,
    scale: str,
    cfg,
    scenes: Mapping[str, rj.Scene | rj.PointScatterers],
    runs: list[Run],
    *,
    pool: rj.Viewpoints,
    radar: rj.Radar,
    inverse: float | Mapping[str, float],
    n_test: int,
    seed: int,
    out: Path,
    report: Callable[[dict, dict, bool], None],
    analyse: Callable[[dict, np.ndarray, np.ndarray], dict] | None = None,
    resume: bool = False,
    progress: bool = True,
) -> dict:
    """Do every run not yet in ``out`` (with ``resume``), writing after each. Returns the
    results dict (as in ``results.json``).

    ``inverse`` is the inverse grid's granularity, or one per scene (a scene's truth volume
    and runs share its grid; to reconstruct one truth at several, name it once per grid).

    ``report(results, volumes, figures)`` writes the experiment's table, and its figures
    when ``figures`` (at the end, and at most once a minute before: drawing takes seconds).
    ``analyse(row, reconstruction, truth)`` (both on the inverse grid) adds
    experiment-specific numbers to a run's row; they are derived from the saved
    reconstructions at every save, so ``resume`` also refreshes them."""
    out = Path(out)
    config = json.loads(json.dumps(dataclasses.asdict(cfg)))  # tuples as JSON lists
    results = {"experiment": name, "scale": scale, "config": config, "seed": seed}
    results |= {"rows": [], "histories": {}, "wall_seconds": 0.0}
    volumes: dict[str, np.ndarray] = {}
    if resume and (out / "results.json").exists():
        done = json.loads((out / "results.json").read_text())
        if (done["config"], done["seed"]) != (config, seed):
            raise SystemExit(
                f"--resume: {out / 'results.json'} was measured with another config or seed; "
                "choose another --out or drop --resume."
            )
        if not (out / "reconstructions.npz").exists():
            raise SystemExit(f"--resume: {out / 'reconstructions.npz'} is missing.")
        results = done
        with np.load(out / "reconstructions.npz") as saved:
            volumes = {key: saved[key] for key in saved.files}
        results.setdefault("resumed_with", []).append(versions())  # the first run's stay
        print(f"resuming: {len(done['rows'])} runs kept from {out / 'results.json'}", flush=True)
    else:
        results["versions"] = versions()
    grids = {key: inverse for key in scenes} if not isinstance(inverse, Mapping) else inverse
    for key, scene in scenes.items():  # a Scene resampled, PointScatterers spread
        volumes[f"truth/{key}"] = np.asarray(scene.resample(grids[key]).reflectivity)

    drawn = time.perf_counter()

    def save(final: bool):
        nonlocal drawn
        if analyse is not None:
            for row in results["rows"]:
                volume = volumes[f"{row['scene']}/{row['run']}"]
                row |= analyse(row, volume, volumes[f"truth/{row['scene']}"])
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **volumes)
        write_atomic(out / "reconstructions.npz", buffer.getvalue())
        write_json(out / "results.json", results)
        figures = final or time.perf_counter() - drawn > 60
        report(results, volumes, figures)
        if figures:
            drawn = time.perf_counter()

    for run in runs:
        if any(r["scene"] == run.scene and r["run"] == run.label for r in results["rows"]):
            continue
        train, test = draw(pool, run.n_train, n_test, seed)
        run_seed = seed if run.seed is None else run.seed
        start = time.perf_counter()
        result, metrics = fit_and_evaluate(
            scenes[run.scene],
            train,
            test,
            radar=radar,
            method=run.method,
            granularity=grids[run.scene],
            seed=run_seed,
            progress=progress,
            options=dict(run.options),
        )
        wall = time.perf_counter() - start
        history = result.history
        row = {"scene": run.scene, "run": run.label, "method": run.method}
        row |= {"n_train": run.n_train, "options": dict(run.options)} | metrics
        row["seed"] = run_seed
        row |= {
            "fit_seconds": result.seconds,
            "wall_seconds": wall,  # fit + evaluation (test signals of truth and prediction)
            "iterations": len(history),
            "seconds_per_iteration": seconds_per_iteration(result),
            "stopped": result.stopped.to_json(),  # an Outcome and the iteration it came at
            "points": result.n_points,  # the operator's unknowns (the support's, if any)
            "active_points": result.stats.get("active_points"),  # RIFT's final active set
            # RIFT's collapse check: what was retried, and what still holds (None: nothing)
            "remedies": result.stats.get("remedies", []),
            "collapse": result.stats.get("collapse"),
        }
        results["rows"].append(row)
        results["wall_seconds"] += wall
        results["histories"][f"{run.scene}/{run.label}"] = history_record(history)
        volumes[f"{run.scene}/{run.label}"] = np.asarray(result.scene.reflectivity)
        print(
            f"{run.scene} {run.label}: m-SSIM {row['m_ssim']:.4f}  m-COS {row['m_cos']:.4f}  "
            f"t-IoU {row['t_iou']:.4f}  p-RMSE {row['p_rmse']:.4f}  ({wall:.0f} s)",
            flush=True,
        )
        save(final=False)
    save(final=True)
    return results


def parse(argv, doc: str, scales: Mapping, name: str):
    """The command line every experiment shares: (config, args) with ``args.out`` set."""
    parser = argparse.ArgumentParser(
        prog=f"python -m experiments.{name}",
        description=doc.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--scale",
        choices=list(scales),
        default="default",
        help="quick: seconds, for tests; default: ≤ 10 minutes on a 2-core CPU; paper: the "
        "paper's sizes (hours to days)",
    )
    parser.add_argument("--out", type=Path, default=None, help="default: results/NAME_SCALE")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--resume", action="store_true", help="keep the runs already in --out")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    args = parser.parse_args(argv)
    args.out = args.out or Path("results") / f"{name}_{args.scale}"
    try:
        check_writable(args.out)
    except OSError as error:  # an existing file, a read-only place: say so before any run
        parser.error(f"argument --out: cannot write results to {args.out}: {error}")
    return scales[args.scale], args


def command(argv, doc: str, scales: Mapping, name: str, main: Callable[..., dict]) -> dict:
    """Parse the shared command line and call ``main(cfg, out=, scale=, seed=, resume=,
    progress=)``."""
    cfg, args = parse(argv, doc, scales, name)
    return main(
        cfg,
        out=args.out,
        scale=args.scale,
        seed=args.seed,
        resume=args.resume,
        progress=not args.no_progress,
    )


def table(rows, columns: list[tuple[str, Callable[[dict], str]]]) -> str:
    """A Markdown table of ``rows`` with ``(header, cell(row))`` columns."""
    head = "| " + " | ".join(h for h, _ in columns) + " |"
    rule = "|" + "---|" * len(columns)
    body = ["| " + " | ".join(cell(row) for _, cell in columns) + " |" for row in rows]
    return "\n".join([head, rule, *body])


def run_cell(row: dict) -> str:
    """The run's label, marked ‡ if it diverged (scored on its best iterate before that)."""
    return row["run"] + (" ‡" if diverged(row) else "")


def diverged(row: dict) -> bool:
    """Whether the run of ``row`` diverged (`rift_jax.solvers.Outcome.DIVERGED`)."""
    return rj.solvers.Stop.from_json(row["stopped"]).outcome is rj.solvers.Outcome.DIVERGED


METRIC_COLUMNS = [
    ("m-SSIM", lambda r: f"{r['m_ssim']:.4f}"),
    ("m-COS", lambda r: f"{r['m_cos']:.4f}"),
    ("t-IoU", lambda r: f"{r['t_iou']:.4f}"),
    ("p-RMSE (rad)", lambda r: f"{r['p_rmse']:.3f}"),
    ("residual", lambda r: f"{r['residual']:.3f}"),
    ("iterations", lambda r: str(r["iterations"])),
    ("s", lambda r: f"{r['wall_seconds']:.0f}"),
]


def environment_line(results: dict) -> str:
    v = results["versions"]
    return (
        f"Seed {results['seed']}; {len(results['rows'])} runs in "
        f"{results['wall_seconds'] / 60:.1f} min (fit + evaluation) on {v['cpu_count']} CPU "
        f"cores ({', '.join(v['devices'])}); rift_jax {v['rift_jax']}, jax {v['jax']}, "
        f"Python {v['python']}."
    )
