"""Point scatterers at continuous positions (`fit(..., method="points")`): greedy detection
and joint refinement, in the spirit of Newtonized OMP (Mamandipoor, Ramasamy and Madhow,
arXiv:1509.01942) and RELAX (Li and Stoica).

Why: at a 3 mm wavelength a sub-voxel offset decorrelates the phase, so no grid explains
off-grid scatterers (docs/experiments.md, "Model mismatch"). Here the scene is K points,
each a continuous position x_k and a complex amplitude a_k, and the model is the GRT summed
over them exactly (`rift_jax.grt`'s, unexpanded):

    S_v[f, m, n] = Σ_k a_k g_v(x_k)[f, m, n],     g_v(x) = A(r_t, r_r) exp(j k_f (r_t + r_r)),

with r_t = |x − tx_{v,m}|, r_r = |x − rx_{v,n}| and the radar's spreading law A. Phases
k·R reach 10⁴-10⁵ rad and the positions are wanted to micrometres: positions, distances,
phases and atoms are all float64 (the method runs under ``jax.enable_x64``; its arrays are
the samples times K, small beside a grid's).

Each round adds one point:

1. **Detect.** The largest of a smooth, cheap score of the residual r over a lattice of the
   box: each view's range-profile energy Q_v(R) = Σ_{m,n} |Σ_f r_v[f,m,n] e^{−j k_f R}|²,
   read at the bistatic range R of the array's centre and summed over the views. Coherent
   over frequencies only, it is smooth on the range resolution (c/2B, 1.5 cm for 10 GHz),
   not on the wavelength; its tables are max-filtered over the ranges one lattice cell
   spans (and the array's own spread), so that the coarse lattice cannot step over a peak.
   The best few cells are localised, and the one whose point removes most energy is kept.
2. **Localise.** The same score on a finer lattice around the cell; then per antenna pair,
   at each pair's own range; then the coherent score c(x) = |⟨g(x), r⟩|²/‖g(x)‖² (the
   energy one scatterer at x removes from r) on a λ/8 lattice around that; then Newton on c
   (its 3 × 3 Hessian by `jax.hessian`), each step clipped to λ/8.
3. **Refine.** Every amplitude by least squares; each point re-localised by Newton against
   the residual of the others (cyclically); points closer than λ/8 merged, points that
   explain nothing dropped. After the last round, a joint Levenberg-Marquardt (optimistix)
   over all positions and amplitudes.
4. **Stop** when the best new point would remove less energy than noise could (a
   CFAR-style threshold from the noise level, when known), or less than ``floor`` times
   the data's energy, or the residual is below ``tol``, or at ``max_points``.
"""

from __future__ import annotations

import functools
import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Complex, Float

from .._geometry import C0, Radar, Viewpoints, antennas_at
from .._synthesis import PointScatterers
from .._validation import check_positive, check_positive_int
from ._solution import History, Outcome, Solution, Stop

_CANDIDATES = 4  # cells localised per round: the one whose point removes most energy is kept
_COARSE_CELLS = 48  # lattice cells per axis of the box at the first level (at most)
_BEAM = 2000  # cells kept at each level of the detection's coarse-to-fine search
_QUANTILE = 0.2  # the detection score's quantile over the views (`_read`)
_P_FALSE_ALARM = 1e-2  # the noise threshold's false-alarm rate over the whole box


class Geometry(NamedTuple):
    """A dataset's antennas and wavenumbers, host float64: ``tx`` (V, M, 3), ``rx``
    (V, N, 3), ``k`` (F,) = 2πf/c0, and the spreading ``law`` ("paper", "radar-equation" or
    "far-field")."""

    tx: np.ndarray
    rx: np.ndarray
    k: np.ndarray
    law: str

    @classmethod
    def of(cls, radar: Radar, viewpoints: Viewpoints) -> Geometry:
        pairs = [antennas_at(radar, *pose) for pose in zip(*viewpoints.poses(radar), strict=True)]
        tx = np.stack([np.asarray(t, np.float64) for t, _ in pairs])
        rx = np.stack([np.asarray(r, np.float64) for _, r in pairs])
        law = radar.spreading if radar.near_field else "far-field"
        return cls(tx, rx, 2 * np.pi * radar.frequencies / C0, law)

    @property
    def wavelength(self) -> float:
        return float(2 * np.pi / self.k.max())

    @property
    def range_resolution(self) -> float:
        """c/2B (one way; m): a range profile's peak width. A single frequency: infinite."""
        band = self.k.max() - self.k.min()
        return math.inf if band == 0 else float(np.pi / band)

    def arrays(self):
        return jnp.asarray(self.tx), jnp.asarray(self.rx), jnp.asarray(self.k)


# ---- the model (float64; call inside jax.enable_x64) ----------------------------------


def _sides(x, tx, rx):
    """Each antenna's distance to the point ``x`` (3,): (V, M) and (V, N)."""
    return jnp.sqrt(jnp.sum((tx - x) ** 2, -1)), jnp.sqrt(jnp.sum((rx - x) ** 2, -1))


def _amplitude(r_t, r_r, law: str):
    """The GRT's spreading factor for every pair, (V, M, N)."""
    r_t, r_r = r_t[:, :, None], r_r[:, None, :]
    if law == "paper":
        return 1.0 / (r_t + r_r) ** 2
    if law == "radar-equation":
        return 1.0 / (r_t * r_r)
    return jnp.ones(jnp.broadcast_shapes(r_t.shape, r_r.shape))


def atom(x, tx, rx, k, law: str) -> Complex[Array, "v f m n"]:
    """g(x): the signals of a unit scatterer at ``x`` (float64 (3,)), complex128."""
    r_t, r_r = _sides(x, tx, rx)
    e_t = jnp.exp(1j * k[None, :, None] * r_t[:, None, :])  # (V, F, M)
    e_r = jnp.exp(1j * k[None, :, None] * r_r[:, None, :])  # (V, F, N)
    return _amplitude(r_t, r_r, law)[:, None] * e_t[..., :, None] * e_r[..., None, :]


def signals(points, amplitudes, tx, rx, k, law: str) -> Complex[Array, "v f m n"]:
    """Σ_k a_k g(x_k): the signals of point scatterers (float64 positions (K, 3))."""
    g = jax.vmap(atom, (0, None, None, None, None))(points, tx, rx, k, law)
    return jnp.tensordot(amplitudes, g, 1)


def _projection(x, r, tx, rx, k, law: str):
    """(⟨g(x), r⟩, ‖g(x)‖²) without forming g: the pairs' phasors are separable."""
    r_t, r_r = _sides(x, tx, rx)
    e_t = jnp.exp(-1j * k[None, :, None] * r_t[:, None, :])
    e_r = jnp.exp(-1j * k[None, :, None] * r_r[:, None, :])
    amp = _amplitude(r_t, r_r, law)
    received = jnp.sum(r * amp[:, None] * e_r[:, :, None, :], axis=-1)  # (V, F, M)
    return jnp.sum(received * e_t), k.shape[0] * jnp.sum(amp**2)


def coherent(x, r, tx, rx, k, law: str) -> Float[Array, ""]:
    """c(x) = |⟨g(x), r⟩|²/‖g(x)‖²: the energy that one scatterer at ``x`` removes from r."""
    inner, norm = _projection(x, r, tx, rx, k, law)
    return jnp.abs(inner) ** 2 / norm


def _pairs(x, r, tx, rx, k) -> Float[Array, ""]:
    """Σ_{v,m,n} |Σ_f r e^{−j k_f (r_t + r_r)}|² at ``x``: coherent over frequencies only, each
    pair at its own range (smooth on the range resolution, not on the wavelength)."""
    r_t, r_r = _sides(x, tx, rx)
    e_t = jnp.exp(-1j * k[None, :, None] * r_t[:, None, :])
    e_r = jnp.exp(-1j * k[None, :, None] * r_r[:, None, :])
    return jnp.sum(jnp.abs(jnp.sum(r * e_r[:, :, None, :] * e_t[..., None], axis=1)) ** 2)


def _score(kind: str, x, r, tx, rx, k, law: str):
    return coherent(x, r, tx, rx, k, law) if kind == "coherent" else _pairs(x, r, tx, rx, k)


@functools.partial(jax.jit, static_argnames=("kind", "law"))
def _on_lattice(kind: str, points, r, tx, rx, k, law: str):
    """`_score` ``kind`` ("coherent" or "pairs") at each of ``points``."""
    return jax.lax.map(lambda x: _score(kind, x, r, tx, rx, k, law), points, batch_size=64)


@functools.partial(jax.jit, static_argnames=("kind", "law", "steps"))
def _newton(kind: str, x, r, tx, rx, k, step_limit, law: str, steps: int = 16):
    """Newton ascent of `_score` ``kind`` from ``x``: ``steps`` steps, each at most
    ``step_limit`` metres (uphill along the gradient where the Hessian is not negative
    definite). A step that does not raise the score is refused, and the limit quartered."""

    def score(x):
        return _score(kind, x, r, tx, rx, k, law)

    def body(_, carry):
        x, limit = carry
        value, gradient = jax.value_and_grad(score)(x)
        hessian = jax.hessian(score)(x)
        newton = -jnp.linalg.solve(hessian, gradient)
        uphill = gradient / jnp.maximum(jnp.linalg.norm(gradient), 1e-300) * limit
        step = jnp.where(jnp.all(jnp.linalg.eigvalsh(hessian) < 0), newton, uphill)
        step = step * jnp.minimum(1.0, limit / jnp.maximum(jnp.linalg.norm(step), 1e-300))
        better = score(x + step) > value
        return jnp.where(better, x + step, x), jnp.where(better, limit, limit / 4)

    return jax.lax.fori_loop(0, steps, body, (x, jnp.asarray(step_limit, x.dtype)))[0]


# ---- the range-profile tables for detection -------------------------------------------


class _Tables(NamedTuple):
    start: np.ndarray  # (V,) the first tabulated bistatic range of each view (m)
    step: float  # their spacing (m)
    energy: np.ndarray  # (V, S) the range-profile energy Q_v
    centre_tx: np.ndarray  # (V, 3) each view's array centres
    centre_rx: np.ndarray
    spread: float  # how far a pair's bistatic range may be from the centres' (m)


@jax.jit
def _profiles(r, k, ranges):
    """Q_v(R_s) = Σ_{m,n} |Σ_f r_v[f,m,n] e^{−j k_f R_s}|² for each view's ranges (V, S)."""

    def one(args):
        r_v, ranges_v = args
        e = jnp.exp(-1j * ranges_v[:, None] * k[None, :])  # (S, F)
        p = jnp.einsum("sf,fmn->smn", e, r_v)
        return jnp.sum(jnp.abs(p) ** 2, axis=(1, 2))

    return jax.lax.map(one, (r, ranges))


def _tables(r, geometry: Geometry, extent: float, finest: float) -> _Tables:
    """The range-profile tables of the residual ``r`` (a float64 JAX array), sampled finely
    enough for lattices down to ``finest`` metres."""
    centre_tx, centre_rx = geometry.tx.mean(1), geometry.rx.mean(1)
    step = min(geometry.range_resolution, 2 * finest) / 8
    reach = 2 * math.sqrt(3) * extent  # |ΔR| ≤ 2|Δx| anywhere in the box
    middle = np.linalg.norm(centre_tx, axis=1) + np.linalg.norm(centre_rx, axis=1)
    n = int(math.ceil(2 * reach / step)) + 1
    start = middle - reach
    ranges = jnp.asarray(start[:, None] + step * np.arange(n)[None])
    energy = np.asarray(_profiles(r, jnp.asarray(geometry.k), ranges))
    spread = np.max(np.linalg.norm(geometry.tx - centre_tx[:, None], axis=-1)) + np.max(
        np.linalg.norm(geometry.rx - centre_rx[:, None], axis=-1)
    )
    return _Tables(start, step, energy, centre_tx, centre_rx, float(spread))


def _filtered(tables: _Tables, cell: float) -> _Tables:
    """The tables max-filtered over the bistatic ranges that a lattice cell of ``cell``
    metres covers (and the array's spread): the lattice point nearest a peak reads it."""
    half = int(math.ceil((math.sqrt(3) * cell + tables.spread) / tables.step))
    padded = np.pad(tables.energy, ((0, 0), (half, half)), mode="edge")
    energy = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1, axis=1).max(-1)
    return tables._replace(energy=energy)


def _read(tables: _Tables, points: np.ndarray) -> np.ndarray:
    """The detection score at ``points`` (L, 3): a low quantile (`_QUANTILE`) over the
    views of Q_v(R_v(x)), each view's table divided by its mean. A scatterer at x shows in
    every view's profile; elsewhere a view reads energy only where some scatterer's range
    (or its alias, every c/Δf of bistatic range) happens to fall. A sum over the views
    cannot tell the two apart once the scatterers fill the profiles; a low quantile can."""
    n = tables.energy.shape[1]
    energy = tables.energy / np.maximum(tables.energy.mean(1, keepdims=True), 1e-300)
    values = np.empty((len(points), len(tables.start)))
    for v in range(len(tables.start)):
        bistatic = np.linalg.norm(points - tables.centre_tx[v], axis=1) + np.linalg.norm(
            points - tables.centre_rx[v], axis=1
        )
        position = np.clip((bistatic - tables.start[v]) / tables.step, 0, n - 1.000001)
        low = position.astype(np.int64)
        frac = position - low
        values[:, v] = (1 - frac) * energy[v, low] + frac * energy[v, low + 1]
    return np.quantile(values, _QUANTILE, axis=1)


def _children(cells: np.ndarray, size: float, extent: float) -> np.ndarray:
    """Each cell (a centre, side ``size``) split into 3³ cells of side size/3."""
    offsets = (size / 3) * np.stack(
        np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1
    ).reshape(-1, 3)
    children = (cells[:, None] + offsets[None]).reshape(-1, 3)
    return children[np.all(np.abs(children) <= extent, axis=1)]


def _lattice(centre: np.ndarray, half_width: float, spacing: float, extent: float) -> np.ndarray:
    """The points of a cubic lattice of ``spacing`` within ``half_width`` of ``centre``,
    inside the box ±``extent``."""
    n = max(1, int(round(half_width / spacing)))
    axis = spacing * np.arange(-n, n + 1)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    points = centre + grid
    return points[np.all(np.abs(points) <= extent, axis=1)]


def _local_maxima(points: np.ndarray, score: np.ndarray, count: int, apart: float):
    """The ``count`` best of ``points`` by ``score``, each more than ``apart`` from the
    better ones."""
    chosen: list[np.ndarray] = []
    for i in np.argsort(score)[::-1]:
        if all(np.max(np.abs(points[i] - c)) > apart for c in chosen):
            chosen.append(points[i])
            if len(chosen) == count:
                break
    return chosen


class _Search(NamedTuple):
    """How finely `_detect` looks (m)."""

    coarse: float  # the lattice over the whole box, refined threefold down to `finest`
    finest: float  # the last range-table level
    pairs: float  # around that (each antenna pair at its own range)
    coherent: float  # around that (the coherent score): λ/8

    @classmethod
    def of(cls, geometry: Geometry, extent: float) -> _Search:
        resolution = min(geometry.range_resolution, 2 * extent)
        pairs = resolution / 6
        coarse = max(2 * extent / _COARSE_CELLS, pairs)
        finest = coarse
        while finest > resolution / 2:
            finest /= 3
        return cls(coarse, finest, pairs, geometry.wavelength / 8)


def _detect(residual, geometry: Geometry, arrays, extent: float, search: _Search):
    """The point that removes the most energy from ``residual`` (float64 JAX array) among
    the best few cells of a coarse-to-fine search, each localised (module docstring, steps
    1-2): (x, c(x))."""
    tx, rx, k = arrays
    tables = _tables(residual, geometry, extent, search.finest)
    size = search.coarse
    cells = _lattice(np.zeros(3), extent, size, extent)
    while True:
        scores = _read(_filtered(tables, size), cells)
        if size <= search.finest * 1.0001:
            break
        cells = _children(cells[np.argsort(scores)[::-1][:_BEAM]], size, extent)
        size /= 3
    best, best_gain = None, -1.0
    for cell in _local_maxima(cells, scores, _CANDIDATES, 2 * size):
        x = jnp.asarray(cell)
        # the pairs' score peaks within ~1 mm of a strong scatterer (measured): the
        # coherent lattice searches half its spacing around that
        for kind, radius, spacing, limit in (
            ("pairs", search.pairs, search.pairs, search.pairs / 2),
            ("coherent", search.pairs / 2, search.coherent, search.coherent),
        ):
            around = jnp.asarray(_lattice(np.asarray(x), radius, spacing, extent))
            scores = _on_lattice(kind, around, residual, tx, rx, k, geometry.law)
            x = _newton(kind, around[jnp.argmax(scores)], residual, tx, rx, k, limit, geometry.law)
        gain = float(_on_lattice("coherent", x[None], residual, tx, rx, k, geometry.law)[0])
        if gain > best_gain:
            best, best_gain = np.clip(np.asarray(x), -extent, extent), gain
    return best, best_gain


@functools.partial(jax.jit, static_argnames="law")
def _amplitudes(points, y, tx, rx, k, law: str):
    """Least-squares amplitudes of point scatterers at ``points`` (K, 3) for data ``y``."""
    g = jax.vmap(atom, (0, None, None, None, None))(points, tx, rx, k, law)
    g = g.reshape(points.shape[0], -1)
    return jnp.linalg.lstsq(g.T, y.reshape(-1))[0]


@functools.partial(jax.jit, static_argnames="law")
def _cyclic(points, amplitudes, y, tx, rx, k, step_limit, law: str):
    """Each point re-localised by Newton against the residual of the others, in turn, and
    its amplitude re-fitted (one cycle)."""

    def one(carry, j):
        points, amplitudes = carry
        others = y - signals(points, amplitudes.at[j].set(0), tx, rx, k, law)
        x = _newton("coherent", points[j], others, tx, rx, k, step_limit, law)
        inner, norm = _projection(x, others, tx, rx, k, law)
        return (points.at[j].set(x), amplitudes.at[j].set(inner / norm)), None

    return jax.lax.scan(one, (points, amplitudes), jnp.arange(points.shape[0]))[0]


@functools.partial(jax.jit, static_argnames="law")
def _energies(points, amplitudes, tx, rx, k, law: str):
    """|a_k|² ‖g(x_k)‖²: the energy each point contributes on its own."""

    def norm(x):
        r_t, r_r = _sides(x, tx, rx)
        return k.shape[0] * jnp.sum(_amplitude(r_t, r_r, law) ** 2)

    return jnp.abs(amplitudes) ** 2 * jax.vmap(norm)(points)


def _prune(points, amplitudes, geometry: Geometry, arrays, threshold: float):
    """The points, less those closer than λ/8 to a stronger one (merged into it: the
    amplitudes are re-fitted afterwards) and those that contribute less than ``threshold``
    of energy."""
    energy = np.asarray(_energies(jnp.asarray(points), jnp.asarray(amplitudes), *arrays,
                                  geometry.law))  # fmt: skip
    keep: list[int] = []
    for i in np.argsort(energy)[::-1]:
        close = any(np.linalg.norm(points[i] - points[j]) < geometry.wavelength / 8 for j in keep)
        if not close and energy[i] >= threshold:
            keep.append(i)
    keep.sort()
    return points[keep], amplitudes[keep]


def point_scatterers(
    signal: Complex[Array, "n_views n_freq n_tx n_rx"],
    viewpoints: Viewpoints,
    radar: Radar,
    extent: float,
    *,
    max_points: int = 20,
    noise: float | None = None,
    tol: float = 1e-4,
    floor: float = 1e-6,
    refine_steps: int = 50,
) -> Solution:
    """Point scatterers that explain ``signal`` (module docstring): greedy detection, each
    round refined jointly, and a joint Levenberg-Marquardt at the end.

    **Arguments:**

    - `signal`: (n_views, n_freq, n_tx, n_rx) complex, seen by ``radar`` at ``viewpoints``.
    - `extent`: half-width of the box (m) the scatterers lie in.
    - `max_points`: at most this many scatterers.
    - `noise`: the standard deviation of the data's complex noise per sample, if known:
      points that remove less energy than the largest that noise alone would give over the
      box (at a false-alarm rate of 1 %) are not added.
    - `tol`: stop once the relative residual ‖y − Σ a g‖/‖y‖ is below this.
    - `floor`: nor are points that remove less than this fraction of the data's energy.
    - `refine_steps`: the final joint Levenberg-Marquardt's step budget (0: none).

    **Returns:** a `Solution` whose ``field`` is the `PointScatterers` (amplitudes in the
    units of ``signal``), ``rho`` their amplitudes, and ``history`` one entry per round
    (the relative residual once the round's point is added and refined).
    """
    check_positive("points: `extent`", extent)
    check_positive_int("points: `max_points`", max_points)
    for name, value in (("tol", tol), ("floor", floor)):
        if not (isinstance(value, int | float) and 0 <= value < 1):
            raise ValueError(f"points: `{name}` must be a number in [0, 1), got {value!r}.")
    if noise is not None and not (isinstance(noise, int | float) and noise >= 0):
        raise ValueError(f"points: `noise` must be a number ≥ 0 or None, got {noise!r}.")
    if not isinstance(refine_steps, int) or refine_steps < 0:
        raise ValueError(f"points: `refine_steps` must be an integer ≥ 0, got {refine_steps!r}.")
    geometry = Geometry.of(radar, viewpoints)
    y_host = np.asarray(signal, np.complex128)
    if y_host.shape != (len(viewpoints), *radar.signal_shape):
        raise ValueError(
            f"points: `signal` must have shape {(len(viewpoints), *radar.signal_shape)}, got "
            f"{y_host.shape}."
        )
    started = time.perf_counter()
    energy = float(np.vdot(y_host, y_host).real)
    search = _Search.of(geometry, extent)
    threshold = floor * energy
    if noise:
        cell = (geometry.wavelength / 4) ** 2 * min(geometry.range_resolution, 2 * extent)
        cells = (2 * extent) ** 3 / cell
        threshold = max(threshold, noise**2 * math.log(cells / _P_FALSE_ALARM))
    points = np.zeros((0, 3))
    amplitudes = np.zeros(0, np.complex128)
    residuals, seconds = [], []
    outcome = Outcome.BUDGET
    with jax.enable_x64(True):
        arrays = geometry.arrays()
        y = jnp.asarray(y_host)
        residual = y
        for _ in range(max_points):
            if energy == 0 or float(jnp.linalg.norm(residual)) <= tol * math.sqrt(energy):
                outcome = Outcome.CONVERGED
                break
            x, gain = _detect(residual, geometry, arrays, extent, search)
            if gain < threshold:
                outcome = Outcome.CONVERGED
                break
            points = np.concatenate([points, x[None]])
            amplitudes = np.asarray(_amplitudes(jnp.asarray(points), y, *arrays, geometry.law))
            moved, amplitudes = _cyclic(
                jnp.asarray(points), jnp.asarray(amplitudes), y, *arrays, search.coherent,
                geometry.law,
            )  # fmt: skip
            points = np.clip(np.asarray(moved), -extent, extent)
            points, amplitudes = _prune(points, np.asarray(amplitudes), geometry, arrays,
                                        threshold)  # fmt: skip
            amplitudes = np.asarray(_amplitudes(jnp.asarray(points), y, *arrays, geometry.law))
            residual = y - signals(jnp.asarray(points), jnp.asarray(amplitudes), *arrays,
                                   geometry.law)  # fmt: skip
            residuals.append(float(jnp.linalg.norm(residual)) / math.sqrt(energy))
            seconds.append(time.perf_counter() - started)
        if len(points) and refine_steps:
            points, amplitudes = _joint(points, amplitudes, y, geometry, arrays, refine_steps)
            points = np.clip(points, -extent, extent)
            residual = y - signals(jnp.asarray(points), jnp.asarray(amplitudes), *arrays,
                                   geometry.law)  # fmt: skip
            residuals.append(float(jnp.linalg.norm(residual)) / math.sqrt(energy))
            seconds.append(time.perf_counter() - started)
    history = History(np.asarray(residuals), np.asarray(seconds))
    scatterers = None
    if len(points):
        scatterers = PointScatterers(points, amplitudes.astype(np.complex64), extent)
    stats = {"points": len(points), "threshold": threshold / energy if energy else 0.0}
    return Solution(
        jnp.asarray(amplitudes, jnp.complex64), history, Stop(outcome, len(history)), stats,
        field=scatterers,
    )  # fmt: skip


def _joint(points, amplitudes, y, geometry: Geometry, arrays, steps: int):
    """Every position and amplitude refined together by Levenberg-Marquardt (optimistix),
    positions as offsets in units of λ/8 (so that both kinds of unknowns are O(1))."""
    unit = geometry.wavelength / 8
    origin = jnp.asarray(points)

    def residual(params, _):
        offsets, re, im = params
        model = signals(origin + unit * offsets, re + 1j * im, *arrays, geometry.law)
        difference = (y - model).reshape(-1)
        return jnp.concatenate([difference.real, difference.imag])

    start = (jnp.zeros_like(origin), jnp.asarray(amplitudes.real), jnp.asarray(amplitudes.imag))
    solver = optx.LevenbergMarquardt(rtol=1e-12, atol=1e-12)
    solution = optx.least_squares(residual, solver, start, max_steps=steps, throw=False)
    offsets, re, im = solution.value
    refined = np.asarray(origin + unit * offsets)
    before = float(jnp.linalg.norm(residual(start, None)))
    after = float(jnp.linalg.norm(residual(solution.value, None)))
    if not after <= before:  # never worse than what the rounds reached
        return points, amplitudes
    return refined, np.asarray(re + 1j * im)
