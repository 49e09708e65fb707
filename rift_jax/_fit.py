"""`fit`: from a scene (simulated) or measured signals to a reconstructed scene, by any method.

The user-facing entry point. It builds the one GRT operator for the inverse grid, hands it
to the chosen solver, and wraps the solver's `Solution` in a `FitResult` that knows how to
predict unseen viewpoints and score itself with the paper's metrics. Whether a fit likely
failed, and what its input warns of, is `rift_jax._checks`'s.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Callable
from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex

from . import _metrics
from ._checks import (
    FitWarning,
    check_fit,
    warn_if_failed,
    warn_if_phaseless,
    warn_unless_nested,
)
from ._geometry import C0, Radar, Viewpoints
from ._models import Field
from ._operator import grt_operator
from ._scenes import Scene, grid_size
from ._solvers import Diverged, History, Outcome, Stop
from ._solvers.methods import METHODS
from ._support import (
    Support,
    as_mask,
    estimate_support,
    mask_at,
    nearest_voxels,
    voxels_holding,
)
from ._synthesis import PointScatterers, RadarData, synthesize
from ._validation import (
    check_finite,
    check_instance,
    check_nonnegative_int,
    check_positive,
    is_finite_nonnegative,
)

AUTO = "auto"  # not a solver: a choice between them (`rift_jax._selection`)
DEFAULT_METHOD = "fista"
"""`fit`'s method when none is named: FISTA, its λ chosen on held-out viewpoints (its
``sparsity="auto"``). Replayed on all 150 cells of the stress grid at every method's
defaults it was within 0.05 m-SSIM of the best method in nearly all of them and failed
none; RIFT(N) was within 0.05 in few. Before, with a fixed λ, neither was best everywhere
and the default was ``"auto"``, the one of FISTA and RIFT(N) that predicts held-out views
better; beside the held-out λ that choice took RIFT(N) where FISTA's image is far better
(docs/experiments.md, "FISTA's λ on held-out views")."""


@dataclasses.dataclass(frozen=True)
class FitResult:
    """A reconstruction and how it was obtained.

    **Fields:**

    - `scene`: the reconstructed `Scene` on the inverse grid. Its reflectivity is in the units
      of the input scene (for measured signals: of ``signal`` itself).
    - `history`: per-iteration relative data residual and wall time (`History`).
    - `seconds`: wall time of the reconstruction, compilation included (not synthesis).
    - `method`, `options`: what ran, with which options.
    - `stopped`: why and when it stopped, a `rift_jax.solvers.Stop` (see `Solution`).
    - `radar`, `viewpoints`: the training geometry.
    - `stats`: solver-specific numbers.
    - `field`: for RIFT, the trained continuous scene (a `Field`, in the units of `scene`);
      None for the grid solvers.
    - `support`: the boolean (n, n, n) mask of the grid points the reconstruction used (ρ = 0
      elsewhere, also in `render`), or None for the whole grid. ``stats["support_leak"]``
      says whether it dropped part of the scene (see `fit`).
    - `trained`: with a finer ``train_granularity``, the reconstruction on that grid (RIFT:
      the field where it was trained last; least squares: its solution; zero elsewhere):
      what `predict` synthesises from. None otherwise.
    - `points`: for ``method="points"``, the `PointScatterers` found (in the units of
      `scene`; None if none was): what `predict` synthesises from. `scene` is them spread
      onto the inverse grid (`PointScatterers.resample`), for the image metrics.
    """

    scene: Scene
    history: History
    seconds: float
    method: str
    options: dict[str, Any]
    stopped: Stop
    radar: Radar
    viewpoints: Viewpoints
    stats: dict[str, Any] = dataclasses.field(default_factory=dict)
    field: Field | None = None
    support: np.ndarray | None = None
    trained: Scene | None = None
    points: PointScatterers | None = None

    @property
    def n_points(self) -> int:
        """How many points of the inverse grid the reconstruction used (all of them without
        a support); with ``train_granularity``, ``stats["support_points"]`` counts the finer
        grid's (where the checks ran: for RIFT, unless its run ended in the coarse
        stage)."""
        return int(self.scene.reflectivity.size if self.support is None else self.support.sum())

    @property
    def residual(self) -> float:
        """The last relative data residual the solver recorded (NaN if none)."""
        return float(self.history.residual[-1]) if len(self.history) else float("nan")

    def predict(self, viewpoints: Viewpoints) -> RadarData:
        """The reconstruction's signals at ``viewpoints``, normalised like `synthesize`
        (max |S| = 1): the GRT of `scene`, or of `trained` when the fit ran on a finer
        grid (for RIFT: the INR's rendering on the points it was trained on); for point
        scatterers, theirs from their exact positions. A reconstruction of ρ = 0 (FISTA on
        data that its noise swamps, a zero signal's) predicts zeros (``scale`` 1)."""
        if self.points is not None:
            return synthesize(self.points, viewpoints, self.radar)
        scene = self.scene if self.trained is None else self.trained
        if not np.any(np.asarray(scene.reflectivity)):  # `synthesize` refuses an empty scene
            check_instance("predict: `viewpoints`", viewpoints, Viewpoints, "rift_jax.Viewpoints")
            zeros = jnp.zeros((len(viewpoints), *self.radar.signal_shape), jnp.complex64)
            return RadarData(zeros, 1.0, viewpoints, self.radar)
        return synthesize(scene, viewpoints, self.radar)

    def render(self, granularity: float, extent: float | None = None) -> Scene:
        """The INR evaluated on another grid (``±extent``, default the scene's, at
        ``granularity``): the field is continuous. For point scatterers, they are spread
        onto that grid (`PointScatterers.resample`). Only for RIFT and point results."""
        if self.method == "points":
            return self._render_points(granularity, extent)
        if self.field is None:
            raise ValueError(
                f"FitResult.render: method {self.method!r} reconstructs on a grid, not a "
                "continuous field; use `result.scene.resample(...)` instead (or "
                "`result.trained`, its solution on a finer `train_granularity`'s grid)."
            )
        grid = Scene.empty(self.scene.extent if extent is None else extent, granularity)
        points = grid.points()
        rho = np.asarray(self.field.render(points))
        if self.support is not None:  # zero outside the support, where it was never trained
            rho = np.where(mask_at(self.support, self.scene, points), rho, 0)
        return Scene(
            jnp.asarray(rho.reshape(grid.shape), jnp.complex64), grid.extent, grid.granularity
        )

    def _render_points(self, granularity: float, extent: float | None) -> Scene:
        extent = self.scene.extent if extent is None else extent
        if self.points is None:  # none found: an empty box
            return Scene.empty(extent, granularity)
        if np.abs(self.points.points).max() > extent:
            raise ValueError(
                f"FitResult.render: `extent` ({extent} m) leaves out some of the point "
                "scatterers found; give one that holds them (or leave it out)."
            )
        moved = PointScatterers(self.points.points, self.points.reflectivity, extent)
        return moved.resample(granularity)

    def evaluate(
        self, truth: Scene | PointScatterers, test_viewpoints: Viewpoints, *, threshold: float = 0.2
    ) -> dict[str, float]:
        """The paper's four metrics against ``truth``: m-SSIM, m-COS, t-IoU (truth resampled
        to the inverse grid; `PointScatterers` spread onto it, see their `resample`) and
        p-RMSE of the predicted signals at ``test_viewpoints`` against the truth's (for
        point scatterers, from their exact positions). Also the recorded data ``residual``.
        A ``method="points"`` fit against a `PointScatterers` truth is also scored as
        detections (`rift_jax.metrics.match_points`, within a quarter of the shortest
        wavelength): ``detected``, ``missed``, ``false_points``, ``position_max``,
        ``position_rms`` (m) and ``amplitude_error``."""
        if not isinstance(truth, Scene | PointScatterers):
            raise ValueError(
                "FitResult.evaluate: `truth` must be a rift_jax.Scene or PointScatterers, got "
                f"{type(truth).__name__}."
            )
        image = truth
        if isinstance(truth, PointScatterers):  # the metrics compare volumes on one grid
            image = truth.resample(self.scene.granularity)
        matched = {}
        if self.method == "points" and isinstance(truth, PointScatterers):
            gate = C0 / float(np.max(self.radar.frequencies)) / 4
            matched = _metrics.match_points(self.points, truth, gate=gate)
        return {
            **matched,
            "m_ssim": _metrics.m_ssim(self.scene, image),
            "m_cos": _metrics.m_cos(self.scene, image),
            "t_iou": _metrics.t_iou(self.scene, image, threshold=threshold),
            "p_rmse": _metrics.p_rmse(
                self.predict(test_viewpoints), synthesize(truth, test_viewpoints, self.radar)
            ),
            "residual": self.residual,
        }


def fit(
    scene_or_signal: Scene
    | PointScatterers
    | RadarData
    | Complex[Array, "n_views n_freq n_tx n_rx"],
    viewpoints: Viewpoints,
    *,
    radar: Radar | None = None,
    method: str = DEFAULT_METHOD,
    granularity: float | None = None,
    extent: float | None = None,
    snr_db: float | None = None,
    support: None | str | np.ndarray | Scene = "auto",
    seed: int = 0,
    progress: bool = True,
    monitor: Callable[[int, float, Callable[[], Scene]], bool | None] | None = None,
    time_limit: float | None = None,
    **options,
) -> FitResult:
    """Reconstruct a scene from radar signals at ``viewpoints``.

    - Given a `Scene`: its signals at ``viewpoints`` are synthesised on its own grid (the
      forward grid; with noise if ``snr_db``), and the scene is reconstructed on the inverse
      grid of ``granularity`` over the same extent (default: twice the scene's granularity,
      the paper's 0.2 m → 0.4 m).
    - Given `PointScatterers`: as a `Scene`, synthesised from their exact positions, on the
      grid of ``granularity`` (required: they have no grid of their own) over their extent.
    - Given measured signals (a `RadarData`, or a complex array (n_views, n_freq, n_tx, n_rx)
      in the order of ``viewpoints``): reconstructs on the grid ``±extent`` at
      ``granularity`` (both required).

    **Arguments:**

    - `scene_or_signal`: a `Scene`, `PointScatterers`, a `RadarData`, or a complex array.
    - `viewpoints`: a `Viewpoints`, one per signal.
    - `radar`: a `Radar` (default the paper's; a `RadarData` brings its own).
    - `method`: ``"fista"`` (the default: jaxopt, least squares with a sparse prior, its
      λ chosen on held-out viewpoints, `rift_jax.solvers.fista`; the best method, or
      within 0.05 m-SSIM of it, nearly everywhere on the stress grid at every method's
      defaults, docs/solvers.md, "Which method"; where the noise level is known, as
      below, its λ is at least the noise's own backprojection, so that it keeps no point
      the noise could have made), ``"auto"`` (FISTA or RIFT(N), chosen on held-out
      viewpoints, below),
      ``"kaczmarz"`` (the paper's baseline), ``"lsmr"`` (lineax),
      ``"gauss-newton"`` (optimistix; ``damped=True`` for Levenberg-Marquardt), or RIFT:
      ``"rift-n"`` / ``"rift-s"`` (an INR trained with optax; see `rift_jax.solvers.rift`
      and `Recipe`; where the noise level is known, as below, its stopping rule and
      collapse check count the loss above the noise's share), or ``"points"``: point
      scatterers at continuous positions, on no grid
      (`rift_jax.solvers.point_scatterers`; for scenes of a few dozen isolated
      scatterers, which no grid holds; ``support`` does not apply, the checks below do not
      run, and the noise level, from ``snr_db``, a `RadarData`'s own, or ``noise=`` in the
      signal's units, sets when it stops). ``"auto"`` is the method that predicts
      viewpoints it did not see best. A fifth of the viewpoints (at least 2, evenly spread)
      is held out; each of ``candidates`` (default ``("fista", "rift-n")``; or a mapping
      of methods to their options) is fitted on the rest, on one support estimated once
      from every viewpoint; each is scored by the residual ‖y − g·Aρ‖/‖y‖ its prediction
      of the held-out signals leaves at its best complex gain g. The first candidate wins
      unless a later one's is lower by more than one standard error of the sum of their
      paired per-view differences (the one-standard-error rule; one that collapsed or
      diverged ranks last); the winner is fitted again on every viewpoint (if that fit
      collapses or diverges, the next candidate is, and ``rejected`` says why; if every
      one does, the first ranked is returned with its failure): the result is that
      method's, with
      ``stats["selection"]`` (each candidate's held-out residual and its per-view shares,
      seconds, stop, failure and the warnings that it likely failed, which are recorded,
      not raised) and the whole choice's time in ``seconds``. The input's warnings (a grid
      that does not nest, a phaseless signal) are said once, before any fit, so a warnings
      filter that makes them errors stops the call there; those of later fits are said
      once, after them (or, when a fit raised, added to its error's notes). It takes no
      solver options (they differ between methods; give them in ``candidates``) and no
      `monitor` or `time_limit`.
      From fewer than 5 viewpoints, or on a zero signal, the candidates are tried in
      their order, unscored.
    - `granularity`, `extent`: the inverse grid (metres).
    - `snr_db`: noise added to synthesised signals (Scene input only).
    - `support`: which grid points may be non-zero. ``"auto"`` (the default, for every
      method): estimated from the signal by `rift_jax.estimate_support` with its
      defaults (a thresholded backprojection sampled finer than the grid; call it yourself
      to tune it), counted in ``seconds`` (its share: ``stats["support_seconds"]``). None:
      every grid point (the paper's setting). A boolean mask of the grid's shape, or a
      `Scene` on the same grid (its non-zero voxels): only those. The
      operator is `grt_operator` on the support's points only, so every method's cost
      falls with it; ρ = 0 elsewhere. Their count is padded to a shared size with points
      that hold ρ = 0 (`rift_jax._support.Support`), so that fits on supports of about the
      same size reuse compiled programs; the answer is the unpadded one. Afterwards
      ``stats["support_leak"]`` is the largest backprojection |Aᴴr| of the data residual r
      *outside* the support, relative to the data's peak backprojection on it (screened by
      a fast backprojection of the whole grid and exact at its maximum, from at most 100
      of the viewpoints, evenly spread; its seconds, with the other checks' and counted in
      ``seconds``, are ``stats["support_leak_seconds"]``): near 0
      when the support holds the scene and the fit explains the data, high when it dropped
      a scatterer, and also high when the data hold what no grid point explains (noise,
      the paper's two-grid protocol). A starting `x0` is given on the whole grid.

      Every fit is then checked on the same viewpoints (``stats["data_residual"]``, the
      relative residual ‖y − Aρ‖/‖y‖ of the returned ρ (with a finer
      ``train_granularity``, of what was solved there: `trained`), and ``stats["coherence"]``,
      cos(|ρ|, |Aᴴy|) over the reconstruction's points where ρ ≠ 0), and a `FitWarning`
      names the likely cause and the option that helps when the fit explains the data no better
      than the zero image (residual ≥ 1), or when a RIFT field is unlike the data's
      backprojection while it does not explain the data (coherence < 0.65 trained with
      complex MSE, < 0.8 with another loss, and a residual ≥ 0.5 beyond the noise's, where
      ``snr_db`` is known: the smooth-blob collapse).
    - `seed`: seeds noise, Kaczmarz's block order, FISTA's power iteration and noise
      draw, and RIFT's initialisation and viewpoint order.
    - `progress`: show a progress bar on runs longer than two seconds.
    - `monitor`: ``monitor(iteration, seconds, current)`` after every iteration (sweep,
      check, epoch), where ``current()`` is the best reconstruction so far as a `Scene` on
      the inverse grid (for RIFT, the best field's rendering, zero off the support; for
      least squares on a finer ``train_granularity``, its values at the inverse grid's
      points, as `scene`): what
      stopping now would give, to draw run time against error. ``seconds`` run on the
      clock of `FitResult.seconds` (from the start of the reconstruction, a support
      estimate included); the monitor's own time is left out of it and of the history. A
      monitor that returns True ends the run there (`Outcome.STOPPED`), keeping the best
      so far (for RIFT, without the collapse check and its retries).
    - `time_limit`: seconds on that clock: the run ends after the iteration in which the
      clock passes it (`Outcome.STOPPED`), with the best reconstruction so far. An
      iteration is a sweep, a check or an epoch, so a run may overshoot by up to one (FISTA
      with its λ path: one step of the path and one of the final solve).
      FISTA's λ path (its ``sparsity="auto"``) is watched too: a limit passed there ends
      the path, and the final solve, one step, starts from the best λ's image so far
      (fitted on four fifths of the views); name a ``sparsity`` to spend a tight budget
      on one solve. A `monitor` sees the path's solves as well, each from iteration 1.
    - `**options`: passed to the solver (``iterations``, ``tol``, ``relaxation``, ...; for
      RIFT ``recipe``, ``epochs``, ``loss``, ``prune``, ...; see `rift_jax.solvers`).
      Every grid method also takes ``train_granularity``: it works on the points of the
      grid of that granularity (e.g. the data's own) that fall in the support. RIFT
      trains there coarse to fine, for its last ``fine_epochs`` (default half the epochs;
      after the coarse stage, which `patience` may end sooner); least squares solves for
      those points from the start, so that both compare on the same points. `scene` stays
      on the inverse grid, for the paper's metrics (RIFT: its rendering; least squares:
      the solution at the inverse grid's points, the same points where the grids nest),
      and `predict` uses what was solved (`FitResult.trained`).

    **Returns:** a `FitResult`.

    **Raises:** ValueError for bad input; `rift_jax.solvers.Diverged` (a ValueError)
    if a run diverges (a non-finite residual, loss or gradient), with the best result so far
    in its ``.result``.
    """
    if method != AUTO and method not in METHODS:
        raise ValueError(
            f"fit: unknown `method` {method!r}; choose one of {sorted([*METHODS, AUTO])}."
        )
    check_instance("fit: `viewpoints`", viewpoints, Viewpoints, "rift_jax.Viewpoints")
    check_nonnegative_int("fit: `seed`", seed)
    if method == AUTO:  # it calls fit for each candidate: imported here, not at the top
        from ._selection import fit_auto

        return fit_auto(
            scene_or_signal, viewpoints, radar=radar, granularity=granularity, extent=extent,
            snr_db=snr_db, support=support, seed=seed, progress=progress, monitor=monitor,
            time_limit=time_limit, **options,
        )  # fmt: skip
    chosen = METHODS[method]
    check_options(method, options)
    # snr_db becomes the data's own: measured data (a RadarData) say their noise
    signal, scale, radar, extent, granularity, snr_db = _data(
        scene_or_signal, viewpoints, radar, extent, granularity, snr_db, seed
    )
    grid = Scene.empty(extent, granularity)
    check_train_granularity(options, granularity)  # before a support estimate's cost
    if chosen.scatterers:
        return _fit_scatterers(
            method, signal, scale, viewpoints, radar, grid, snr_db, support, monitor,
            time_limit, progress, options,
        )  # fmt: skip
    start = time.perf_counter()  # the support check counts in the reconstruction's time
    noise = _noise(options, signal, scale, snr_db)  # σ per sample, where known
    # the residual a perfect fit leaves on data whose noise is known: ‖n‖/‖s + n‖
    noise_floor = 0.0
    if noise.get("noise"):
        power = float(np.mean(np.abs(np.asarray(signal)) ** 2))
        noise_floor = float(np.sqrt(min(noise["noise"] ** 2 / power, 1.0)))
    points = grid.points()
    operator = grt_operator(radar, viewpoints, points)
    support_stats = {}  # where a support's own cost goes: the estimate, the leak check
    if isinstance(support, str) and support == "auto":
        if not np.any(np.asarray(signal)):
            support = None  # a zero signal shows no support; every solver returns zero
        else:
            estimating = time.perf_counter()
            support = estimate_support(signal, viewpoints, grid, radar=radar)
            support_stats["support_seconds"] = time.perf_counter() - estimating
    mask = None if support is None else as_mask(support, grid)
    on = None if mask is None else Support.padded(mask)  # the operator's points
    if on is not None:
        operator = on.operator(radar, viewpoints, points)
    if chosen.seeded:
        options = {"seed": seed, **options}
    solver_options = options
    if "noise" in chosen.options:  # RIFT: what of its loss is noise; FISTA: λ's floor
        solver_options = options | noise
    if isinstance(options.get("init"), Field):  # a result's field is in the scene's units
        solver_options = {**solver_options, "init": options["init"].scaled(1 / scale)}
    if chosen.inr:  # the grid's coordinate scale, with or without a support
        solver_options = {"extent": float(np.max(np.abs(points))), **solver_options}
    # where the solver's unknowns live: the inverse grid's points (on the support, if any),
    # or, for least squares with `train_granularity`, the finer grid's points in the support
    fine_solve = False  # least squares on the finer grid's points (`train_granularity`)
    solved_on = on
    fine = fine_on = None
    if "train_granularity" in options:
        solver_options = dict(solver_options)
        if (fine_granularity := solver_options.pop("train_granularity")) is not None:
            fine = Scene.empty(extent, fine_granularity)
            candidates = fine.points()
            keep = np.ones(len(candidates), bool)
            if mask is not None:
                keep = mask_at(mask, grid, candidates)
                fine_on = Support.padded(keep.reshape(fine.shape))
            if chosen.inr:  # coarse to fine: the field's last epochs train there
                solver_options["fine_points"] = candidates[keep]
            else:  # least squares: those points are the unknowns, from the start
                fine_solve, solved_on = True, fine_on
                operator = _operator_on(fine_on, radar, viewpoints, candidates)
    if on is not None and options.get("x0") is not None:  # a start on the whole grid
        x0 = np.asarray(options["x0"]).reshape(-1)
        if x0.shape != (mask.size,):
            raise ValueError(
                f"fit: `x0` must have one value per grid point ({mask.size}), got {x0.shape}."
            )
        solver_options = {**solver_options, "x0": on.restrict(x0)}

    if monitor is not None and not callable(monitor):
        raise ValueError(f"fit: `monitor` must be callable, got {type(monitor).__name__}.")
    if time_limit is not None:
        check_positive("fit: `time_limit`", time_limit)
    if monitor is not None or time_limit is not None:

        def current_scene(current) -> Scene:  # the solver's ρ (or RIFT's field) as a Scene
            if isinstance(current, Field):
                rho = np.asarray(current.scaled(scale).render(points))
                if mask is not None:
                    rho = np.where(mask.ravel(), rho, 0)
            else:
                rho = np.asarray(current) * scale
                if solved_on is not None:
                    rho = solved_on.embed(rho)
                if fine_solve:
                    rho = _at_points(rho, fine, points)
            values = jnp.asarray(rho.reshape(grid.shape), jnp.complex64)
            return Scene(values, extent, granularity)

        def watch(iteration, _, current):  # on fit's clock: a support estimate counts too
            looked = time.perf_counter()
            seconds = looked - start - watched[0]
            stop = monitor is not None and monitor(
                iteration, seconds, lambda: current_scene(current())
            )
            watched[0] += time.perf_counter() - looked
            return bool(stop) or (time_limit is not None and seconds >= time_limit)

        solver_options = {**solver_options, "monitor": watch}
    watched = [0.0]  # the monitor's seconds: not the reconstruction's

    def result(solution) -> FitResult:
        rho = np.asarray(solution.rho) * scale
        stats = dict(solution.stats)
        if solved_on is not None:  # ρ = 0 outside the support
            rho = solved_on.embed(rho)
        field = None if solution.field is None else solution.field.scaled(scale)
        trained = None
        if fine_solve:  # least squares on the finer grid: its image, sampled
            values = jnp.asarray(rho.reshape(fine.shape), jnp.complex64)
            trained = Scene(values, extent, fine.granularity)
            rho = _at_points(rho, fine, points)
        if fine is not None and "active" in stats:  # the field where it was trained
            where = np.flatnonzero(keep)[stats.pop("active")]
            values = np.zeros(keep.size, np.complex64)
            values[where] = np.asarray(field.render(candidates[where]))
            trained = Scene(jnp.asarray(values.reshape(fine.shape)), extent, fine.granularity)
            # on the inverse grid too, ρ = 0 in voxels that hold no trained point
            rho = np.where(voxels_holding(grid, candidates[where]).ravel(), rho, 0)
        # The checks read what was solved, on its points: with a finer `train_granularity`,
        # `trained` on that grid (RIFT's rendering on the inverse grid explains less of the
        # data and follows the backprojection less: a coarse-to-fine fit of m-SSIM 0.98
        # scored cos 0.78 there, a false collapse warning)
        checked = time.perf_counter()
        by, solved, on_points, checked_on = operator, rho, points, on
        if trained is not None:
            by = operator if fine_solve else _operator_on(fine_on, radar, viewpoints, candidates)
            solved, on_points, checked_on = trained.reflectivity, candidates, fine_on
        solved = np.asarray(solved).ravel()
        kept = jnp.asarray(solved if checked_on is None else checked_on.restrict(solved)) / scale
        checks = check_fit(by, signal, kept, checked_on, on_points, viewpoints)
        check_seconds = time.perf_counter() - checked
        stats |= checks
        if checked_on is not None:
            stats |= {
                "support_points": checked_on.n_points,
                "support_leak_seconds": check_seconds,
                **support_stats,
            }
        warn_if_failed(method, stats, mask is not None, noise_floor)
        scene = Scene(jnp.asarray(rho.reshape(grid.shape), jnp.complex64), extent, granularity)
        seconds = time.perf_counter() - start - watched[0]
        return FitResult(
            scene,
            solution.history,
            seconds,
            method,
            options,
            solution.stopped,
            radar,
            viewpoints,
            stats,
            field,
            mask,
            trained,
        )

    try:
        return result(chosen.solve(operator, signal, progress=progress, **solver_options))
    except Diverged as error:
        error.result = result(error.solution)
        raise


def check_options(method: str, options: dict) -> None:
    """A ValueError for an option ``method`` does not take, a non-finite one, or a start
    that cannot go with ``train_granularity``: what `fit` checks before any work."""
    METHODS[method].check(method, options)
    if (noise := options.get("noise")) is not None and not is_finite_nonnegative(noise):
        raise ValueError(
            "fit: `noise` must be a finite number ≥ 0 (the noise's standard deviation per "
            "sample, in the units of the signal given, or of a RadarData's `signal * scale`) "
            f"or None, got {noise!r}."
        )
    for name, value in options.items():  # e.g. tol=nan: no comparison with it ever stops
        if isinstance(value, float | np.floating) and not np.isfinite(value):
            raise ValueError(f"fit: option `{name}` must be finite, got {value!r}.")
    fine_start = options.get("train_granularity") is not None and options.get("x0") is not None
    if fine_start and not METHODS[method].inr:
        raise ValueError(
            "fit: `x0` is a start on the inverse grid; it cannot start a solve on the points "
            "of `train_granularity`'s grid (leave one out)."
        )


def check_train_granularity(options: dict, granularity: float) -> None:
    """A ValueError unless ``options``' `train_granularity` (if any) is finer than the
    inverse grid's ``granularity``."""
    fine = options.get("train_granularity")
    if fine is not None and not (isinstance(fine, int | float) and 0 < fine < granularity):
        raise ValueError(
            "fit: `train_granularity` must be finer than the inverse grid's "
            f"granularity ({granularity} m) and > 0, got {fine!r}."
        )


def _fit_scatterers(
    method, signal, scale, viewpoints, radar, grid, snr_db, support, monitor, time_limit,
    progress, options,
) -> FitResult:  # fmt: skip
    """`fit` for a method that finds point scatterers (`Method.scatterers`): no grid, no
    operator, no support; the noise level follows from ``snr_db`` when it is known."""
    if not (support is None or (isinstance(support, str) and support == "auto")):
        raise ValueError(
            f"fit: method {method!r} places scatterers anywhere in the box; it takes no "
            "`support` (leave it out)."
        )
    if monitor is not None or time_limit is not None:
        raise ValueError(f"fit: method {method!r} takes no `monitor` or `time_limit`.")
    del progress  # a run is a few dozen rounds, each reported in its history
    solver_options = options | _noise(options, signal, scale, snr_db)
    start = time.perf_counter()
    solution = METHODS[method].solve(signal, viewpoints, radar, grid.extent, **solver_options)
    seconds = time.perf_counter() - start
    points, scene = solution.field, grid  # the grid is all zeros: the scene if none is found
    if points is not None:
        points = PointScatterers(
            points.points, np.asarray(points.reflectivity) * scale, points.extent
        )
        scene = points.resample(grid.granularity)
    stats = dict(solution.stats)  # no points: the residual is the data's own, 1
    stats["data_residual"] = float(solution.history.residual[-1]) if len(solution.history) else 1.0
    if solution.stopped.outcome is Outcome.BUDGET:
        warnings.warn(
            f"fit ({method}): all `max_points` rounds ran, and the {stats['points']} points "
            f"found leave a relative residual of {stats['data_residual']:.2f} "
            "(‖y − model‖/‖y‖): the scene may hold more scatterers than `max_points` (raise it), "
            "or more than the radar tells apart (each view sees a scatterer's range only "
            "modulo c/Δf, in about F − 1 range cells: docs/solvers.md, 'Point scatterers').",
            FitWarning,
            stacklevel=3,  # the caller of fit
        )
    return FitResult(
        scene, solution.history, seconds, method, options, solution.stopped, radar,
        viewpoints, stats, points=points,
    )  # fmt: skip


def _noise(options: dict, signal, scale: float, snr_db: float | None) -> dict:
    """``{"noise": σ}``, the noise's standard deviation per sample in the solver's units
    (the signal normalised by ``scale``), for the methods that take it (`points`, RIFT, FISTA)
    and `fit`'s own checks: the user's ``noise`` (checked by `check_options`, in the
    signal's units), else the σ that ``snr_db`` implies, as `synthesize` adds it; ``{}``
    when neither is known."""
    if (noise := options.get("noise")) is not None:
        return {"noise": float(noise) / scale}
    if snr_db is None:
        return {}
    power = float(np.mean(np.abs(np.asarray(signal)) ** 2))
    ratio = 10 ** (-snr_db / 10)
    return {"noise": float(np.sqrt(power * ratio / (1 + ratio)))}


def _operator_on(on: Support | None, radar: Radar, viewpoints: Viewpoints, points: np.ndarray):
    """`grt_operator` on a grid's ``points`` (flat), or on those of its support ``on``."""
    return (
        grt_operator(radar, viewpoints, points)
        if on is None
        else on.operator(radar, viewpoints, points)
    )


def _at_points(values, fine: Scene, points: np.ndarray) -> np.ndarray:
    """``values`` on ``fine``'s grid (flat) at ``points`` (another grid's, flat): each takes
    its nearest fine point's value, that very point where the grids nest (a shift of at
    most half a fine spacing per axis where they do not). For least squares solved on a
    finer grid this is what RIFT's rendering on the inverse grid is for its field: the
    solution at the inverse grid's points, not an average around them."""
    index, _ = next(nearest_voxels(fine, points))  # a tie goes to the lower point
    index = np.clip(index, 0, fine.shape[0] - 1)  # the grids span the same box
    return np.asarray(values).reshape(fine.shape)[tuple(index.T)]


def _data(data, viewpoints, radar, extent, granularity, snr_db, seed):
    """(normalised signal, its scale, radar, extent, granularity, the noise's SNR in dB
    where known: ``snr_db`` for a Scene, a `RadarData`'s own, None for an array) for
    `fit`'s input."""
    if radar is not None:
        check_instance("fit: `radar`", radar, Radar, "a rift_jax.Radar")
    if isinstance(data, Scene | PointScatterers):
        if extent is not None and extent != data.extent:
            raise ValueError(
                f"fit: `extent` ({extent}) must be left out or equal the scene's ({data.extent})."
            )
        if granularity is None and isinstance(data, PointScatterers):
            raise ValueError(
                "fit: given PointScatterers, pass the inverse grid's `granularity` (m): they "
                "have no grid of their own to default to."
            )
        granularity = 2 * data.granularity if granularity is None else granularity
        grid_size(data.extent, granularity, "fit")  # a grid with points, or say which argument
        data_ = synthesize(data, viewpoints, radar, snr_db=snr_db, seed=seed)
        if isinstance(data, Scene):  # point scatterers share no grid with any
            warn_unless_nested(data, granularity)
        return data_.signal, data_.scale, data_.radar, data.extent, granularity, snr_db
    if snr_db is not None:
        raise ValueError("fit: `snr_db` applies to a Scene; measured signals carry their noise.")
    if extent is None or granularity is None:
        raise ValueError(
            "fit: given signals rather than a Scene, pass the grid to reconstruct on as "
            "`extent` (half-width, m) and `granularity` (m)."
        )
    grid_size(extent, granularity, "fit")
    if isinstance(data, RadarData):
        if radar is not None and radar != data.radar:
            raise ValueError("fit: `radar` differs from the RadarData's own radar.")
        if len(data.viewpoints) != len(viewpoints):
            raise ValueError(
                f"fit: the RadarData has {len(data.viewpoints)} viewpoints but `viewpoints` "
                f"has {len(viewpoints)}."
            )
        warn_if_phaseless(data.signal)
        return data.signal, data.scale, data.radar, extent, granularity, data.snr_db
    radar = Radar() if radar is None else radar
    signal = np.asarray(data)
    if not np.issubdtype(signal.dtype, np.number):
        raise ValueError(
            "fit: the signal (`scene_or_signal`) must be a complex array, got dtype "
            f"{signal.dtype}."
        )
    expected = (len(viewpoints), *radar.signal_shape)
    if signal.shape != expected:
        raise ValueError(
            f"fit: the signal (`scene_or_signal`) must have shape {expected} (n_views, n_freq, "
            f"n_tx, n_rx) for {len(viewpoints)} viewpoints and this radar, got {signal.shape}."
        )
    check_finite(signal, "fit: the signal (`scene_or_signal`)")
    peak = float(np.max(np.abs(signal)))
    warn_if_phaseless(signal)
    scale = peak if peak > 0 else 1.0  # solvers work on O(1) data; ρ is scaled back
    return signal / scale, scale, radar, extent, granularity, None
