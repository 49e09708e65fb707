"""Runs: what every experiment and benchmark does — draw viewpoints, reconstruct, score,
save, resume — and the paper's own numbers to put beside ours.

The one public module for runs (experiments and `benchmarks` alike). An experiment is a
list of `Run`s over named scenes. `execute` fits each run with
`rift_jax.fit`, scores it with `FitResult.evaluate`, and after every run writes
``results.json`` (config, metrics, histories, wall times, versions) and
``reconstructions.npz`` (every reconstruction and the truths on the inverse grid) atomically,
then calls the experiment's `report` to redraw its table and figures. ``--resume`` keeps the
runs already written and does only the rest.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import inspect
import io
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Collection, Mapping
from pathlib import Path
from typing import Any

import jax
import numpy as np

import rift_jax as rj
from benchmarks._timing import complex_matmul_rate
from rift_jax import _io

# -- writing: an interrupted run never leaves a half-written file ---------------------------


def write_atomic(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` to ``path`` atomically (rift_jax's writer: a temporary file beside
    it, renamed into place), creating its folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, str):
        data = data.encode("utf-8")  # results carry π, ±, √: not the locale's business
    return _io.write_atomic(path, lambda f: f.write(data))


def check_writable(directory: str | Path) -> None:
    """Create ``directory`` if needed and write (and drop) a temporary file in it: an OSError
    now, before any run, rather than at the first save after minutes or hours of work."""
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise NotADirectoryError(f"{directory} is a file, not a directory")
    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryFile(dir=directory, prefix=".probe.", suffix=".tmp"):
        pass


def write_json(path: str | Path, obj) -> Path:
    return write_atomic(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")


def write_npz(path: str | Path, arrays: Mapping[str, np.ndarray]) -> Path:
    """Write ``arrays`` as a compressed ``.npz`` atomically."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return write_atomic(path, buffer.getvalue())


def save_figure(fig, path: str | Path) -> Path:
    """Render a matplotlib figure to PNG bytes, then write them atomically."""

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    return write_atomic(path, buffer.getvalue())


# -- the paper's numbers ------------------------------------------------------------------
# The paper's reported numbers, for the tables that put ours beside them.
#
# Each entry is (m-SSIM, m-COS, t-IoU, p-RMSE) from Table 1 (cube), the appendix tables
# (sphere, pyramid, mini highway) and Table 2 (mini parking lot). A † in the paper marks a
# failed run; those rows are kept and flagged in `FAILED`.

TABLES: dict[str, dict[str, tuple[float, float, float, float]]] = {
    "cube": {
        "LS-100": (0.0704, 0.5698, 0.0578, 0.0155),
        "LS-200": (0.0908, 0.6689, 0.1663, 0.0153),
        "LS-500": (0.1128, 0.7822, 0.1243, 0.0151),
        "LS-1000": (0.1706, 0.8511, 0.2183, 0.0150),
        "RIFT(N)-100": (0.6395, 0.9792, 0.3677, 0.0147),
        "RIFT(S)-100": (0.1435, 0.6957, 0.3302, 0.0152),
        "RIFT(N)-1000": (0.6298, 0.9833, 0.3714, 0.0145),
        "RIFT(S)-1000": (0.6045, 0.9606, 0.3688, 0.0147),
    },
    "sphere": {
        "LS-100": (0.0762, 0.5986, 0.0897, 0.0151),
        "LS-200": (0.1007, 0.7090, 0.1741, 0.0150),
        "LS-500": (0.1813, 0.8412, 0.2130, 0.0148),
        "LS-1000": (0.2890, 0.8886, 0.2736, 0.0146),
        "RIFT(N)-100": (0.8343, 0.9917, 0.3540, 0.0187),
        "RIFT(S)-100": (0.2858, 0.9473, 0.3412, 0.0145),
        "RIFT(N)-1000": (0.0018, 0.1893, 0.0893, 0.0214),
        "RIFT(S)-1000": (0.6002, 0.9744, 0.3726, 0.0145),
    },
    "pyramid": {
        "LS-100": (0.1163, 0.5584, 0.0576, 0.0151),
        "LS-200": (0.1444, 0.7012, 0.1740, 0.0149),
        "LS-500": (0.3065, 0.8158, 0.1257, 0.0147),
        "LS-1000": (0.4258, 0.8689, 0.1822, 0.0146),
        "RIFT(N)-100": (0.8926, 0.9840, 0.2549, 0.0185),
        "RIFT(S)-100": (0.0266, 0.1774, 0.0581, 0.0159),
        "RIFT(N)-1000": (0.9513, 0.9845, 0.2537, 0.0186),
        "RIFT(S)-1000": (0.6385, 0.9271, 0.2730, 0.0147),
    },
    "parking_lot": {
        "LS-2500": (0.1662, 0.5931, 0.0356, 0.0153),
        "RIFT(N)-1000": (0.5705, 0.7833, 0.0244, 0.0152),
        "RIFT(S)-1000": (0.6639, 0.9120, 0.0345, 0.0149),
    },
    "highway": {
        "LS-2500": (0.1914, 0.5725, 0.0128, 0.0154),
        "RIFT(N)-1000": (0.7354, 0.8778, 0.0854, 0.0160),
        "RIFT(S)-1000": (0.6897, 0.9116, 0.0913, 0.0160),
    },
}

FAILED = {("sphere", "RIFT(N)-1000"), ("pyramid", "RIFT(S)-100")}
"""Runs the paper marks with † (training failed)."""

WEAK_TARGET = {
    "LS": "not resolved at any ratio",
    "RIFT": "resolved down to 4:1 (the weaker bar's reflectivity diminished, its place right)",
}
"""Section 4.3 gives no numbers, only these findings (Figure 5)."""


def paper_row(scene: str, label: str) -> str:
    """The paper's four numbers as ``a / b / c / d`` (``†`` if failed), or ``–``."""
    values = TABLES.get(scene, {}).get(label)
    if values is None:
        return "–"
    text = " / ".join(f"{v:.4f}" for v in values)
    return text + (" †" if (scene, label) in FAILED else "")


# -- runs -----------------------------------------------------------------------------------

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
    recipe (every 25 of 100 epochs). Every step is taken (``patience=None``): a budget
    that stops early says so itself. From fewer views than the recipe's `epoch_views`, an
    epoch is one pass (``epoch_views=None``), so that a small budget is its own step count
    (several passes per epoch would round it up to ⌈100/n⌉ steps); from as many, the
    options are what they were before `epoch_views` existed."""
    epochs = max(1, round(steps * batch_views / n_train))
    options = {
        "loss": "mse",  # `Recipe`'s default, named: a results file says which loss ran
        "epochs": epochs,
        "halve_every": epochs / 4,
        "batch_views": batch_views,
        "patience": None,
    }
    if rj.solvers.Recipe().passes(n_train) > 1:
        options["epoch_views"] = None
    return options


@dataclasses.dataclass(frozen=True)
class Budget:
    """What each run of an experiment may spend, and when it stops early.

    Kaczmarz runs at most ``sweeps`` sweeps and stops once its residual stalls by ``ls_tol``
    (0: every sweep). RIFT runs about ``rift_steps`` optimizer steps of 10 views, stops after
    ``rift_patience`` epochs without progress (None: never), and trains only where
    |ρ| ≥ ``rift_prune``·max, re-chosen every ``recheck_every`` epochs (None: everywhere;
    the default, `fit`'s, first chooses the set after 10 epochs on every point).
    ``support`` restricts every method to a support (`rift_jax.fit`'s option; None: the
    whole grid). FISTA, the strongest least squares (docs/solvers.md), runs at most
    ``fista_iterations`` and stops once converged (its default tol)."""

    sweeps: int
    rift_steps: int
    ls_tol: float = 0.0
    rift_prune: float | None = None
    rift_patience: int | None = None
    recheck_every: int = rj.solvers.Recipe.recheck_every  # `fit`'s own, not a copy of it
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
        else:  # named: `fit`'s default prunes
            options |= {"prune": None}
        return options | {"patience": self.rift_patience}

    def _support(self) -> dict:
        return {"support": self.support}  # named: `fit`'s default is "auto"

    def describe(
        self, model: str = "RIFT", fista: bool = False, support: Mapping | None = None
    ) -> str:
        """The budgets in words, for a results page (FISTA's too, if it ran; the support
        estimate's options, if the study set them: `execute`'s ``support``)."""
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
            support = dict(support or {})
            phrases = {
                "max_views": "from at most {} views",
                "threshold": "threshold {:g} of the backprojection's peak",
                "floor_factor": "at least {:g} times the backprojection's median voxel",
            }
            said = [phrases[key].format(support.pop(key)) for key in phrases if key in support]
            said += [f"{key}={value!r}" for key, value in support.items()]
            text += (
                '; every method on the support estimated from its training data (`support="auto"`'
                + "".join(f", {phrase}" for phrase in said)
                + ")"
            )
        return text


PAPER_STOPPING = {
    "ls_tol": 1e-3,
    "rift_prune": 0.05,
    "rift_patience": 10,
    "support": "auto",
}
"""How the paper-scale scene studies skip what a scene does not need: every method on the
support estimated from its data, RIFT on an active set, and each run stopped once
converged. How the estimate is made is the study's (`execute`'s ``support``: the weak
target's paper scale sets its own, `weak_target.Config.support_estimate`). The active set is
re-chosen as `fit`'s default does it, every 10 epochs (`Budget.recheck_every`), so first
after 10 epochs on every point: chosen after 2, it had dropped the weaker bar at 3:1 and
4:1 before the field learned it (docs/experiments.md, the weak target)."""


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


def fit_and_evaluate(
    scene, train, test, *, radar, method, granularity, seed, progress, options, monitor=None
):
    """Reconstruct ``scene`` from its signals at ``train`` on the inverse grid of
    ``granularity`` and score it against the truth at ``test``: (FitResult, metrics, the
    messages of the warnings that it likely failed). ``monitor`` is `fit`'s (e.g. a
    `Trace`).

    A run that diverges (least squares or RIFT) is scored on its best iterate before the
    divergence; its ``result.stopped`` says ``Outcome.DIVERGED`` and where (the paper, too,
    reports its failed runs). A run that `fit` warns may have failed (a `FitWarning`, or
    RIFT's `CollapseWarning`) is kept and scored as well: its row holds the warning, so a
    study can tell whether the warning was right."""

    def run():
        try:
            return rj.fit(
                scene,
                train,
                radar=radar,
                method=method,
                granularity=granularity,
                seed=seed,
                progress=progress,
                monitor=monitor,
                **options,
            )
        except rj.solvers.Diverged as error:
            print(f"{method}: {error}; scoring the best iterate before it", flush=True)
            return error.result

    # a likely failure is kept with the row; other warnings go on
    result, failed = rj.recorded_failures(run)
    warned = [str(warning.message) for warning in failed]
    return result, result.evaluate(scene, test), warned


class Trace:
    """A run's quality against its wall time, sampled while it runs (`fit`'s ``monitor``).

    Whenever the run's clock passes the next time of a geometric ladder (``first`` seconds,
    then every ``ratio`` times longer), the best reconstruction so far is scored: m-SSIM
    against the truth on the inverse grid, and p-RMSE at the first ``n_views`` test
    viewpoints (a few, since every sample synthesises them; its time is not the run's).
    `finish` adds the final result and each sample's data residual from the history.
    ``records`` then lists ``{"iteration", "seconds", "m_ssim", "p_rmse", "residual"}``.
    A run of several solves (FISTA's λ path, then its final solve; RIFT's retries) counts
    each solve's iterations from 1: samples of an earlier solve get ``residual`` None (the
    history is the last solve's).
    """

    def __init__(self, truth, test, radar, granularity, *, first=0.25, ratio=1.5, n_views=10):
        self.views = test[: min(n_views, len(test))]
        self.truth = truth.resample(granularity)
        self.radar, self.ratio = radar, ratio
        self.signals = rj.synthesize(truth, self.views, radar)  # the truth's, once
        self.next, self.records = first, []
        self.solve, self._last, self._solves = 0, 0, []  # which solve each record is of

    def __call__(self, iteration: int, seconds: float, current) -> None:
        if iteration <= self._last:  # its iterations count from 1 again: a new solve
            self.solve += 1
        self._last = iteration
        if seconds >= self.next:
            self.records.append(self._score(iteration, seconds, current()))
            self._solves.append(self.solve)
            while self.next <= seconds:
                self.next *= self.ratio

    def _score(self, iteration, seconds, scene) -> dict:
        p_rmse = math.pi / math.sqrt(3)  # a zero image has no phase: random phase's RMSE
        if scene.reflectivity.any():  # (synthesize refuses an empty scene)
            predicted = rj.synthesize(scene, self.views, self.radar)
            p_rmse = rj.metrics.p_rmse(predicted, self.signals)
        return {
            "iteration": iteration,
            "seconds": seconds,
            "m_ssim": float(rj.metrics.m_ssim(scene, self.truth)),
            "p_rmse": float(p_rmse),
        }

    def finish(self, result) -> list[dict]:
        """The records, closed by ``result`` itself, each with its iteration's residual.
        Iterations are the solver's own (LSMR's steps), as the monitor counts them; the
        history has one entry per ``check_every`` of them (1 for the other solvers)."""
        per_entry = int(result.stats.get("check_every", 1))
        residual = result.history.residual
        final = self._score(len(residual) * per_entry, result.seconds, result.scene)
        self.records.append(final)
        self._solves.append(self.solve)
        for record, solve in zip(self.records, self._solves, strict=True):
            k = min(record["iteration"] // per_entry, len(residual)) - 1
            if solve != self.solve:  # an earlier solve's: not in the result's history
                record["residual"] = None
            else:
                record["residual"] = float(residual[k]) if k >= 0 else 1.0
        return self.records


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
        "device_kind": jax.devices()[0].device_kind,  # an accelerator's name, e.g. "NVIDIA H100"
        "cpu_count": os.cpu_count(),
        # the machine's speed that day (shared machines vary 2-5×): read run times against it
        "matmul_rate_gmacs": complex_matmul_rate(),
    }


def release_compiled_programs(share: float = 0.5) -> bool:
    """Drop JAX's compiled programs (`jax.clear_caches`) once this process's memory mappings
    pass ``share`` of the kernel's limit; returns whether it did. Each XLA:CPU program holds
    mappings of its own (a stress-grid fit compiled 700-1,500, measured), and a study compiles
    hundreds of programs (every view count, support size and RIFT active set): at
    `vm.max_map_count` (65,530 here) LLVM fails with "Cannot allocate memory" although RAM is
    free, which stopped the stress grid twice, after 135 and 110 runs. Dropping them costs
    the next runs their compilations, and brought a process from 5,005 mappings back to 902.
    Linux only (``/proc``); elsewhere nothing is dropped."""
    try:
        limit = int(Path("/proc/sys/vm/max_map_count").read_text())
        with open("/proc/self/maps") as maps:
            count = sum(1 for _ in maps)
    except (OSError, ValueError):
        return False
    if count < share * limit:
        return False
    jax.clear_caches()
    gc.collect()
    return True


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
    trace: Mapping | None = None,
    notes: Mapping | None = None,
    resume: bool = False,
    per_run: Collection[str] = ("budget",),
    progress: bool = True,
    part: tuple[int, int] | None = None,
    support: Mapping[str, Any] | None = None,
) -> dict:
    """Do every run not yet in ``out`` (with ``resume``), writing after each. Returns the
    results dict (as in ``results.json``).

    ``inverse`` is the inverse grid's granularity, or one per scene (a scene's truth volume
    and runs share its grid; to reconstruct one truth at several, name it once per grid).

    ``report(results, volumes, figures)`` writes the experiment's table, and its figures
    when ``figures`` (at the end, and at most once a minute before: drawing takes seconds).
    ``analyse(row, reconstruction, truth)`` (both on the inverse grid) adds
    experiment-specific numbers to a run's row; they are derived from the saved
    reconstructions at every save, so ``resume`` also refreshes them. ``trace`` (`Trace`'s
    options, or None) samples each run's quality against its wall time into its row's
    ``trace``. ``part`` ``(k, n)`` does only runs k, k + n, k + 2n, ... (k from 1): one of
    n processes or machines sharing the study, each with its own ``out``;
    ``python -m experiments.merge`` joins them. ``notes`` go into the results as they are
    (the machine's matmul rate is recorded anyway, in ``versions``); a resumed run keeps
    the first run's and adds the new ones under ``resumed_notes``. ``support``: options of
    the shared ``support="auto"`` estimate (`SharedSupports`: `rift_jax.estimate_support`'s
    ``max_views``, ``threshold``, ...; None: its defaults, the estimate `fit` makes
    itself). Runs given a mask or ``support=None`` make no estimate; a traced study makes
    none either (each run's estimate is on its own clock, `fit`'s), so it refuses
    ``support``.

    ``resume`` refuses another seed or a changed setting of ``cfg``, except those named in
    ``per_run``: settings that only shape the runs (which runs, their `fit` options), which
    may change as long as every run already done is still asked for, unchanged. A setting
    the file lacks (added to the experiment since) must be at its default."""
    if trace is not None and support:
        raise ValueError(
            f"{name}: `support` options need the shared estimate, which a traced study does "
            f"not make (`trace` is set); got support={support!r}."
        )
    out = Path(out)
    config = _as_json(dataclasses.asdict(cfg))
    results = {"experiment": name, "scale": scale, "config": config, "seed": seed}
    results |= {"rows": [], "histories": {}, "wall_seconds": 0.0}
    volumes: dict[str, np.ndarray] = {}
    machine = versions()  # this process's machine and its speed today
    if resume and (out / "results.json").exists():
        done = json.loads((out / "results.json").read_text())
        changed = f"seed {done['seed']}, now {seed}" if done["seed"] != seed else None
        changed = changed or _changed_setting(cfg, done["config"], per_run)
        if changed:
            raise SystemExit(
                f"--resume: {out / 'results.json'} was measured with another config or seed "
                f"({changed}); choose another --out or drop --resume."
            )
        done["rows"] = [_upgrade(row, seed) for row in done["rows"]]
        _check_kept(done["rows"], runs, seed, out / "results.json")
        if not (out / "reconstructions.npz").exists():
            raise SystemExit(f"--resume: {out / 'reconstructions.npz'} is missing.")
        results = done | {"config": config}  # the file now holds runs of today's config
        if done["config"] != config:  # ... and says what its first runs were made under
            results.setdefault("resumed_from_configs", []).append(done["config"])
        with np.load(out / "reconstructions.npz") as saved:
            volumes = {key: saved[key] for key in saved.files}
        results.setdefault("resumed_with", []).append(machine)  # the first run's stay
        if notes:
            results.setdefault("resumed_notes", []).append(dict(notes))
        print(f"resuming: {len(done['rows'])} runs kept from {out / 'results.json'}", flush=True)
    else:
        results["versions"] = machine
        results |= {"notes": dict(notes or {})}
    print(f"complex64 matmul on this machine: {machine['matmul_rate_gmacs']:.1f} G/s", flush=True)
    results["planned_runs"] = len(runs)  # the report says when a stopped study is unfinished
    asked = runs
    results.pop("part", None)  # a folder of one part, resumed as a whole
    if part is not None:  # one of several processes: the study's every part[1]-th run
        asked = runs[part[0] - 1 :: part[1]]
        if not asked:
            raise ValueError(f"{name}: `part` {part[0]}/{part[1]} holds no run of the {len(runs)}.")
        results["part"] = list(part)
    grids = {key: inverse for key in scenes} if not isinstance(inverse, Mapping) else inverse
    for key, scene in scenes.items():  # a Scene resampled, PointScatterers spread
        volumes[f"truth/{key}"] = np.asarray(scene.resample(grids[key]).reflectivity)

    drawn = time.perf_counter()
    supports = SharedSupports(radar, support)

    order = {(run.scene, run.label): k for k, run in enumerate(runs)}

    def save(final: bool):
        nonlocal drawn
        # in the study's order, whatever order the runs were done in (parts, merges, resumes)
        results["rows"].sort(key=lambda row: order[row["scene"], row["run"]])
        if analyse is not None:
            for row in results["rows"]:
                volume = volumes[f"{row['scene']}/{row['run']}"]
                row |= analyse(row, volume, volumes[f"truth/{row['scene']}"])
        write_npz(out / "reconstructions.npz", volumes)
        write_json(out / "results.json", results)
        figures = final or time.perf_counter() - drawn > 60
        report(results, volumes, figures)
        if figures:
            drawn = time.perf_counter()

    for run in asked:
        if any(r["scene"] == run.scene and r["run"] == run.label for r in results["rows"]):
            continue
        release_compiled_programs()
        train, test = draw(pool, run.n_train, n_test, seed)
        run_seed = seed if run.seed is None else run.seed
        tracer = None
        if trace is not None:
            tracer = Trace(scenes[run.scene], test, radar, grids[run.scene], **trace)
        options = dict(run.options)
        shared = None
        if trace is None and isinstance(options.get("support", "auto"), str):
            # fit's default, named or not; a traced run keeps the estimate on fit's clock
            shared = supports.get(
                run.scene, scenes[run.scene], train, grids[run.scene], run_seed, options
            )
            options["support"] = shared.mask
        start = time.perf_counter()
        result, metrics, warned = fit_and_evaluate(
            scenes[run.scene],
            train,
            test,
            radar=radar,
            method=run.method,
            granularity=grids[run.scene],
            seed=run_seed,
            progress=progress,
            options=options,
            monitor=tracer,
        )
        wall = time.perf_counter() - start
        history = result.history
        row = {"scene": run.scene, "run": run.label, "method": run.method}
        row |= {"n_train": run.n_train, "options": dict(run.options)} | metrics
        row["seed"] = run_seed
        if tracer is not None:
            row["trace"] = tracer.finish(result)
        # a shared estimate counts in every run's own time, as if the run had made it
        own = 0.0 if shared is None else shared.seconds
        row |= {
            "fit_seconds": result.seconds + own,
            "wall_seconds": wall + own,  # fit + evaluation (test signals of truth, prediction)
            "iterations": len(history),
            "seconds_per_iteration": seconds_per_iteration(result),
            "stopped": result.stopped.to_json(),  # an Outcome and the iteration it came at
            "points": result.n_points,  # the operator's unknowns (the support's, if any)
            "active_points": result.stats.get("active_points"),  # RIFT's final active set
            # RIFT's collapse check: what was retried, and what still holds (None: nothing)
            "remedies": result.stats.get("remedies", []),
            "collapse": result.stats.get("collapse"),
            # what `fit`'s smooth-blob warning read, so that a study can re-judge it later
            "coherence": result.stats.get("coherence"),
            "sparsity": result.stats.get("sparsity"),  # FISTA's λ over max|Aᴴy|, as it ran
            "warnings": warned,  # where `fit` judged the run a likely failure
        }
        if shared is not None:  # estimated once for every run on the same data
            row |= {"support_seconds": shared.seconds, "support_reused": shared.reused}
        if "sparsity_path" in result.stats:  # FISTA's sparsity="auto": what it chose from
            row["sparsity_path"] = result.stats["sparsity_path"]
        if "selection" in result.stats:  # method "auto": what it chose, and why
            row["selection"] = result.stats["selection"]
        results["rows"].append(row)
        results["wall_seconds"] += wall + (own if shared and not shared.reused else 0.0)
        results["histories"][f"{run.scene}/{run.label}"] = history_record(history)
        volumes[f"{run.scene}/{run.label}"] = np.asarray(result.scene.reflectivity)
        print(
            f"{run.scene} {run.label}: m-SSIM {row['m_ssim']:.4f}  m-COS {row['m_cos']:.4f}  "
            f"t-IoU {row['t_iou']:.4f}  p-RMSE {row['p_rmse']:.4f}  ({wall:.0f} s)"
            + "".join(f"\n  warned: {message}" for message in warned),
            flush=True,
        )
        save(final=False)
    save(final=True)
    return results


@dataclasses.dataclass(frozen=True)
class EstimatedSupport:
    """A ``support="auto"`` estimate kept for the runs on the same data: the mask (None for a
    zero signal, as `fit` does: zero data show no support), the seconds it took, and
    whether the run asking for it is reusing it."""

    mask: np.ndarray | None
    seconds: float
    reused: bool


class SharedSupports:
    """``support="auto"`` estimated once per dataset (scene, training views, noise and its
    seed, inverse grid), not once per run: every method that runs on the same data gets the
    same mask, for the price of one estimate. `fit` then takes the mask as its support; the
    runner adds the estimate's seconds to every run's ``fit_seconds``, so each run's time
    is still what it would cost alone, and the row's ``support_seconds`` names the share.

    ``options``: `rift_jax.estimate_support`'s, for every estimate (None: its defaults, the
    estimate `fit` makes itself). Where a limited aperture leaves the backprojection's
    sidelobes high (the weak target's), more views (``max_views``) lower them, and a
    threshold set above them (``threshold``, ``floor_factor``) keeps less of the box."""

    def __init__(self, radar: rj.Radar, options: Mapping[str, Any] | None = None):
        self.radar = radar
        self.options = dict(options or {})
        self.estimates: dict = {}

    def get(self, name: str, scene, train, granularity, seed, options) -> EstimatedSupport:
        """The estimate for scene ``name`` from its signals at ``train`` (with the run's
        ``snr_db`` and noise ``seed``, as `fit` synthesises them) on the inverse grid of
        ``granularity``."""
        snr_db = options.get("snr_db")
        key = (name, train.azimuth.tobytes(), train.polar.tobytes(), granularity, snr_db)
        if train.positions is not None:  # poses: the angles alone do not tell them apart
            key += (train.positions.tobytes(), train.orientations.tobytes())
        key += (seed if snr_db is not None else None,)  # the noise's seed, if any noise
        if key in self.estimates:
            return dataclasses.replace(self.estimates[key], reused=True)
        signal = rj.synthesize(scene, train, self.radar, snr_db=snr_db, seed=seed).signal
        start = time.perf_counter()  # after the data, as `fit`'s own clock starts
        mask = None
        if np.any(np.asarray(signal)):
            grid = rj.Scene.empty(scene.extent, granularity)
            mask = rj.estimate_support(signal, train, grid, radar=self.radar, **self.options)
        self.estimates[key] = EstimatedSupport(mask, time.perf_counter() - start, False)
        return self.estimates[key]


def _as_json(value):
    return json.loads(json.dumps(value))  # tuples as lists, as results.json holds them


def _changed_setting(cfg, saved: dict, per_run: Collection[str]) -> str | None:
    """What in ``cfg`` forbids resuming a file whose config was ``saved`` (None: nothing).

    A setting in ``per_run`` may differ: `_check_kept` holds each kept row to the run asked
    for now. Any other setting the file has must be unchanged; one it lacks must be at its
    default, which is what the experiment did before the setting existed."""
    config = _as_json(dataclasses.asdict(cfg))
    dropped = sorted(saved.keys() - config.keys())
    if dropped:
        return f"{dropped[0]}: no longer a setting"
    for field in dataclasses.fields(cfg):
        key = field.name
        if key in per_run:
            continue
        if key in saved:
            if saved[key] != config[key]:
                return f"{key}: {saved[key]!r}, now {config[key]!r}"
            continue
        if field.default is not dataclasses.MISSING:
            default = field.default
        elif field.default_factory is not dataclasses.MISSING:
            default = field.default_factory()
        else:
            return f"{key}: new, and without a default"
        if dataclasses.is_dataclass(default):
            default = dataclasses.asdict(default)
        if _as_json(default) != config[key]:
            return f"{key}: new, and {config[key]!r} is not its default {default!r}"
    return None


def rift_loss(options: Mapping) -> str:
    """The loss a RIFT run with these options trained with: the one they name, else the
    default of the time when rows named none, the robust loss (the paper's under the paper's
    recipe)."""
    if "loss" in options:
        return options["loss"]
    return "paper" if options.get("recipe") == "paper" else "robust"


def _upgrade(row: dict, seed: int) -> dict:
    """A saved row as this version writes it. Rows from before typed outcomes (95641d3)
    said why a run ended in free text, and held a divergence's message under "diverged";
    rows from before rows held their seed were made with the file's. A RIFT row whose
    options name no `patience` ran every epoch: None was the default before 10; one that
    names no `prune` trained every point, one that names no `loss` trained with the robust
    loss (the paper's, under the paper's recipe), and a row that names no `support` ran on
    the whole grid (the defaults before "auto", 0.05 and complex MSE)."""
    row = {"seed": seed} | row
    options = row.get("options")
    if isinstance(options, dict):
        options = {"support": None} | options
        if str(row.get("method", "")).startswith("rift"):
            options = {"patience": None, "prune": None, "loss": rift_loss(options)} | options
        row["options"] = options
    legacy = row["stopped"]
    if not isinstance(legacy, str):
        return _lsmr_in_steps(row)
    outcome, at = None, row["iterations"]
    if legacy in ("iterations", "epochs"):  # least squares' budget, RIFT's
        outcome = rj.solvers.Outcome.BUDGET
    elif legacy == "tolerance":
        outcome = rj.solvers.Outcome.CONVERGED
    elif legacy == "zero signal":
        outcome, at = rj.solvers.Outcome.ZERO_SIGNAL, 0
    elif legacy.startswith("diverged at epoch "):
        outcome, at = rj.solvers.Outcome.DIVERGED, int(legacy.rsplit(" ", 1)[1])
    if outcome is None:
        raise SystemExit(
            f"--resume: run {row['scene']}/{row['run']} ended with {legacy!r}, which this "
            "version cannot read; choose another --out or drop --resume."
        )
    row = {key: value for key, value in row.items() if key != "diverged"}
    return _lsmr_in_steps(row | {"stopped": rj.solvers.Stop(outcome, at).to_json()})


def _lsmr_in_steps(row: dict) -> dict:
    """An LSMR row's `stopped` in LSMR steps. Rows from before 2d75a99 counted checks: their
    ``at`` is the history's length (``iterations``; one more after a divergence), where
    this version's is that times ``check_every``."""
    if row.get("method") != "lsmr" or not isinstance(row.get("options"), dict):
        return row
    options = _LSMR_DEFAULTS | row["options"]
    every = min(options["check_every"], options["iterations"])  # as lsmr checks
    at, checks = row["stopped"]["at"], row["iterations"]
    old, new = (checks, checks + 1), (checks * every, (checks + 1) * every)
    if every > 1 and at in old and at not in new:
        return row | {"stopped": row["stopped"] | {"at": at * every}}
    return row


_LSMR_DEFAULTS = {
    name: inspect.signature(rj.solvers.lsmr).parameters[name].default
    for name in ("check_every", "iterations")
}


def _check_kept(rows: list[dict], runs: list[Run], seed: int, path: Path) -> None:
    """Every saved row is a run still asked for, with the method, views, options and seed it
    would get now; otherwise resuming would mix two protocols in one table."""
    asked = {(run.scene, run.label): run for run in runs}
    for row in rows:
        name = f"{path}'s run {row['scene']}/{row['run']}"
        run = asked.get((row["scene"], row["run"]))
        if run is None:
            raise SystemExit(
                f"--resume: {name} is not one this config asks for; choose another --out or "
                "drop --resume."
            )
        now = {
            "method": run.method,
            "n_train": run.n_train,
            "options": _as_json(dict(run.options)),
            "seed": seed if run.seed is None else run.seed,
        }
        for key, value in now.items():
            if row[key] != value:
                raise SystemExit(
                    f"--resume: {name} was made with other settings ({key}: {row[key]!r}, "
                    f"now {value!r}); choose another --out or drop --resume."
                )


def parse(argv, doc: str, scales: Mapping, name: str, root: str = "results"):
    """The command line every experiment and benchmark shares: (config, args) with
    ``args.out`` set (default ``root/NAME_SCALE``)."""
    parser = argparse.ArgumentParser(
        prog=f"python -m {'benchmarks' if root == 'docs/results' else 'experiments'}.{name}",
        description=doc.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--scale",
        choices=list(scales),
        default="default",
        help="quick: seconds, for tests; default: minutes on a 2-core CPU (≤ 10; the weak "
        "target ~20); paper: the paper's sizes (hours to days)",
    )
    parser.add_argument("--out", type=Path, default=None, help="default: results/NAME_SCALE")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--resume", action="store_true", help="keep the runs already in --out")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    parser.add_argument(
        "--part",
        type=_part,
        default=None,
        metavar="K/N",
        help="do only runs K, K+N, K+2N, ... (K from 1 to N): one of N processes or machines "
        "sharing the study, each with its own --out; `python -m experiments.merge` joins them",
    )
    args = parser.parse_args(argv)
    args.out = args.out or Path(root) / f"{name}_{args.scale}"
    try:
        check_writable(args.out)
    except OSError as error:  # an existing file, a read-only place: say so before any run
        parser.error(f"argument --out: cannot write results to {args.out}: {error}")
    return scales[args.scale], args


def _part(text: str) -> tuple[int, int]:
    """``--part``'s K/N as (K, N), or argparse's error."""
    try:
        k, n = (int(x) for x in text.split("/"))
    except ValueError:
        k = n = 0
    if not 1 <= k <= n:
        raise argparse.ArgumentTypeError(f"expected K/N with 1 <= K <= N, got {text!r}")
    return k, n


def command(
    argv, doc: str, scales: Mapping, name: str, main: Callable[..., dict], root: str = "results"
) -> dict:
    """Parse the shared command line and call ``main(cfg, out=, scale=, seed=, resume=,
    progress=, part=)``."""
    cfg, args = parse(argv, doc, scales, name, root)
    return main(
        cfg,
        out=args.out,
        scale=args.scale,
        seed=args.seed,
        resume=args.resume,
        progress=not args.no_progress,
        part=args.part,
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


def figure_lines(names: tuple[str, ...], drawn: bool) -> list[str]:
    """The report's figures, embedded in its results.md (so that the page shows them, on
    GitHub and on the docs site), when the run draws them; lines to put before the
    environment line."""
    if not drawn:
        return []
    lines = ["## Figures", ""]
    for name in names:
        lines += [f"![{Path(name).stem.replace('_', ' ')}]({name})", ""]
    return lines


def _machine(v: dict) -> str:
    """The machine a versions record was made on: its CPU cores, or its accelerator."""
    devices = ", ".join(v["devices"])
    if v["devices"][0].lower().startswith(("cpu", "tfrt_cpu")):
        return f"{v['cpu_count']} CPU cores ({devices})"
    kind = v.get("device_kind", "accelerator")  # an accelerator: name it
    return f"{len(v['devices'])} × {kind} ({devices}) and {v['cpu_count']} CPU cores"


def environment_line(results: dict) -> str:
    v = results["versions"]
    done, planned = len(results["rows"]), results.get("planned_runs")
    count = f"{done} runs" if planned in (None, done) else f"{done} of {planned} runs (unfinished)"
    machine = _machine(v)
    # a resumed file's runs may come from other machines too: name them
    parts = results.get("parts", [])  # experiments.merge: runs from several processes
    ran = [p for p in parts if not p.get("replaced")]  # replays (`--replace`) ran later
    if len(ran) > 1:
        count += f" (in {len(ran)} parts run side by side; the time is their sum)"
    if replaced := sum(p.get("replaced", 0) for p in parts):
        count += f" ({replaced} of them replayed later, in {len(parts) - len(ran)} replays)"
    resumed = [m for p in parts for m in p["machines"]] + results.get("resumed_with", [])
    others = dict.fromkeys(_machine(r) for r in resumed if "devices" in r)
    others.pop(machine, None)
    # the first machine's speed that day (time_to_quality's first runs kept it in notes)
    if rate := v.get("matmul_rate_gmacs", results.get("notes", {}).get("matmul_rate_gmacs")):
        machine += f", its complex64 matmul at {rate:.1f} G/s"
    if others:
        machine += f", resumed on {'; '.join(others)}"
    line = (
        f"Seed {results['seed']}; {count} in {results['wall_seconds'] / 60:.1f} min "
        f"(fit + evaluation) on {machine}; rift_jax {v['rift_jax']}, jax {v['jax']}, "
        f"Python {v['python']}."
    )
    # a resumed file's runs may come from several versions of the code: say which
    runs = [v, *resumed]
    commits = list(dict.fromkeys(c[:7] for c in (r.get("git_commit") for r in runs) if c))
    if len(commits) > 1:
        line += f" Code at commit {commits[0]}, resumed at {', '.join(commits[1:])}."
    elif commits:
        line += f" Code at commit {commits[0]}."
    return line
