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
   read at the bistatic range R of the array's centre, its low quantile over the views
   (`_read`). Coherent over frequencies only, it is smooth on the range resolution (c/2B,
   1.5 cm for 10 GHz), not on the wavelength; its tables are max-filtered over the ranges
   one lattice cell spans (and the array's own spread), so that the coarse lattice cannot
   step over a peak. The best few cells are localised, and the one whose point removes
   most energy is kept. Each view sees ranges only modulo c/Δf, in about F − 1 range
   cells: once the scatterers fill them, no view tells where they are (docs/solvers.md).
2. **Localise.** Per antenna pair, at each pair's own range (a lattice around the cell,
   then Newton); then the coherent score c(x) = |⟨g(x), r⟩|²/‖g(x)‖² (the energy one
   scatterer at x removes from r) on a λ/8 lattice around that; then Newton on c (its
   3 × 3 Hessian by `jax.hessian`), each step clipped to λ/8.
3. **Refine.** Every amplitude by least squares; the new point and those near it each
   re-localised by Newton against the residual of the others, in turn; points closer than
   λ/2 (which no aperture resolves) merged, points that explain nothing dropped. After a
   merge and after the last round, each point is searched for again around itself against
   the residual of the others (a lattice, as in step 2), then a joint Levenberg-Marquardt
   (optimistix) refines every position and amplitude.
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
import scipy.ndimage
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, Complex, Float

from .._geometry import C0, Radar, Viewpoints, every_view_antennas
from .._synthesis import PointScatterers
from .._validation import check_positive, check_positive_int, is_finite_nonnegative
from ._solution import History, Outcome, Solution, Stop

_CANDIDATES = 3  # cells localised per round: the one whose point removes most energy is kept
_COARSE_CELLS = 48  # lattice cells per axis of the box at the first level (at most)
_BEAM = 2000  # cells kept at each level of the detection's coarse-to-fine search
_QUANTILE = 0.2  # the detection score's quantile over the views (`_read`)
_P_FALSE_ALARM = 1e-2  # the noise threshold's false-alarm rate over the whole box


class Law(NamedTuple):
    """What the kernels need to know statically: the ``spreading`` law ("paper",
    "radar-equation" or "far-field"), and whether the wavenumbers are uniform (a
    ``ladder``: e^{j k_f r} = e^{j k_0 r} (e^{j Δk r})^f, two exponentials per distance
    instead of one per frequency)."""

    spreading: str
    ladder: bool


class Geometry(NamedTuple):
    """A dataset's antennas and wavenumbers, host float64: ``tx`` (V, M, 3), ``rx``
    (V, N, 3), ``k`` (F,) = 2πf/c0, and the kernels' `Law`."""

    tx: np.ndarray
    rx: np.ndarray
    k: np.ndarray
    law: Law

    @classmethod
    def of(cls, radar: Radar, viewpoints: Viewpoints) -> Geometry:
        tx, rx = every_view_antennas(radar, viewpoints)  # float64 NumPy
        k = 2 * np.pi * radar.frequencies / C0
        steps = np.diff(k)
        ladder = bool(len(k) > 1 and np.allclose(steps, steps[0], rtol=1e-12, atol=0))
        return cls(tx, rx, k, Law(radar.spreading if radar.near_field else "far-field", ladder))

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


def _amplitude(r_t, r_r, law: Law):
    """The GRT's spreading factor for every pair, (V, M, N)."""
    r_t, r_r = r_t[:, :, None], r_r[:, None, :]
    if law.spreading == "paper":
        return 1.0 / (r_t + r_r) ** 2
    if law.spreading == "radar-equation":
        return 1.0 / (r_t * r_r)
    return jnp.ones(jnp.broadcast_shapes(r_t.shape, r_r.shape))


def _norm(r_t, r_r, k, law: Law):
    """‖g(x)‖² from the point's distances: F · Σ over the pairs and views of A²."""
    return k.shape[0] * jnp.sum(_amplitude(r_t, r_r, law) ** 2)


def _phasors(k, r, law: Law, sign: float = 1.0):
    """e^{±j k_f r} for each distance r (V, A): (V, F, A). On a uniform grid by the
    ladder (`Law`): the powers of e^{j Δk r} by a running product, whose rounding (~F·1e-16)
    is far below what float64 phases carry anyway."""
    if not law.ladder:
        return jnp.exp(sign * 1j * k[None, :, None] * r[:, None, :])
    base = jnp.exp(sign * 1j * k[0] * r)
    step = jnp.exp(sign * 1j * (k[1] - k[0]) * r)
    powers = jnp.concatenate(
        [
            jnp.ones_like(step)[:, None],
            jnp.broadcast_to(step[:, None], (r.shape[0], k.shape[0] - 1, r.shape[1])),
        ],
        axis=1,
    )
    return base[:, None] * jnp.cumprod(powers, axis=1)


def atom(x, tx, rx, k, law: Law) -> Complex[Array, "v f m n"]:
    """g(x): the signals of a unit scatterer at ``x`` (float64 (3,)), complex128."""
    r_t, r_r = _sides(x, tx, rx)
    e_t, e_r = _phasors(k, r_t, law), _phasors(k, r_r, law)  # (V, F, M), (V, F, N)
    return _amplitude(r_t, r_r, law)[:, None] * e_t[..., :, None] * e_r[..., None, :]


def signals(points, amplitudes, tx, rx, k, law: Law) -> Complex[Array, "v f m n"]:
    """Σ_k a_k g(x_k): the signals of point scatterers (float64 positions (K, 3))."""
    g = jax.vmap(atom, (0, None, None, None, None))(points, tx, rx, k, law)
    return jnp.tensordot(amplitudes, g, 1)


def _projection(x, r, tx, rx, k, law: Law):
    """(⟨g(x), r⟩, ‖g(x)‖²) without forming g: the pairs' phasors are separable."""
    r_t, r_r = _sides(x, tx, rx)
    e_t, e_r = _phasors(k, r_t, law, -1.0), _phasors(k, r_r, law, -1.0)
    amp = _amplitude(r_t, r_r, law)
    received = jnp.sum(r * amp[:, None] * e_r[:, :, None, :], axis=-1)  # (V, F, M)
    return jnp.sum(received * e_t), _norm(r_t, r_r, k, law)


def coherent(x, r, tx, rx, k, law: Law) -> Float[Array, ""]:
    """c(x) = |⟨g(x), r⟩|²/‖g(x)‖²: the energy that one scatterer at ``x`` removes from r."""
    inner, norm = _projection(x, r, tx, rx, k, law)
    return jnp.abs(inner) ** 2 / norm


def _pairs(x, r, tx, rx, k, law: Law) -> Float[Array, ""]:
    """Σ_{v,m,n} |Σ_f r e^{−j k_f (r_t + r_r)}|² at ``x``: coherent over frequencies only, each
    pair at its own range (smooth on the range resolution, not on the wavelength)."""
    r_t, r_r = _sides(x, tx, rx)
    e_t, e_r = _phasors(k, r_t, law, -1.0), _phasors(k, r_r, law, -1.0)
    return jnp.sum(jnp.abs(jnp.sum(r * e_r[:, :, None, :] * e_t[..., None], axis=1)) ** 2)


def _score(kind: str, x, r, tx, rx, k, law: Law):
    return coherent(x, r, tx, rx, k, law) if kind == "coherent" else _pairs(x, r, tx, rx, k, law)


_gain = jax.jit(coherent, static_argnames="law")


@functools.partial(jax.jit, static_argnames=("kind", "law"))
def _on_lattice(kind: str, points, r, tx, rx, k, law: Law):
    """`_score` ``kind`` ("coherent" or "pairs") at each of ``points``. The coherent score
    takes the paper's amplitude 1/(r_t + r_r)² as 1/(4 r_t r_r) here (relative error
    (r_t − r_r)²/(4 r_t r_r): ~1e-5 for antennas 3 cm apart at 10 m, `rift_jax.grt`;
    larger for TX and RX far apart), which makes every law separable and
    the score a batched matrix product: the lattice only picks where Newton starts, and
    Newton uses the exact score."""
    if kind == "pairs":
        return jax.lax.map(lambda x: _pairs(x, r, tx, rx, k, law), points, batch_size=16)

    def factors(x):
        r_t, r_r = _sides(x, tx, rx)
        e_t, e_r = _phasors(k, r_t, law, -1.0), _phasors(k, r_r, law, -1.0)
        if law.spreading != "far-field":  # 1/(r_t r_r), and 1/4 of it for the paper's law
            half = 0.5 if law.spreading == "paper" else 1.0
            e_t, e_r = e_t * (half / r_t[:, None]), e_r * (half / r_r[:, None])
        return e_t, e_r, _norm(r_t, r_r, k, law)

    single = r.astype(jnp.complex64)

    def batch(points):
        # the phases in float64, their products in complex64: the score only ranks points
        e_t, e_r, norm = jax.vmap(factors)(points)
        # HIGHEST: on NVIDIA GPUs a complex64 product defaults to TensorFloat-32, which put
        # this score more than 1e-5 off the exact one on an H200 (test_points)
        received = jnp.einsum(
            "vfmn,bvfn->bvfm",
            single,
            e_r.astype(jnp.complex64),
            precision=jax.lax.Precision.HIGHEST,
        )
        inner = jnp.sum(received * e_t.astype(jnp.complex64), axis=(1, 2, 3))
        return jnp.abs(inner.astype(r.dtype)) ** 2 / norm

    size = 32
    pad = -points.shape[0] % size
    padded = jnp.concatenate([points, jnp.broadcast_to(points[:1], (pad, 3))])
    return jax.lax.map(batch, padded.reshape(-1, size, 3)).reshape(-1)[: points.shape[0]]


@functools.partial(jax.jit, static_argnames=("kind", "law", "steps"))
def _newton(kind: str, x, r, tx, rx, k, step_limit, law: Law, steps: int = 16):
    """Newton ascent of `_score` ``kind`` from ``x``: at most ``steps`` steps, each at most
    ``step_limit`` metres (uphill along the gradient where the Hessian is not negative
    definite). A step that does not raise the score is refused, and the limit quartered.
    It stops early once a step would move less than ``step_limit``·1e-7 (0.04 nm for the
    coherent score's λ/8, where its quadratic convergence has long made it exact)."""

    def score(x):
        return _score(kind, x, r, tx, rx, k, law)

    tiny = step_limit * 1e-7

    def body(carry):
        x, limit, i, _ = carry
        value, gradient = jax.value_and_grad(score)(x)
        hessian = jax.hessian(score)(x)
        newton = -jnp.linalg.solve(hessian, gradient)
        uphill = gradient / jnp.maximum(jnp.linalg.norm(gradient), 1e-300) * limit
        step = jnp.where(jnp.all(jnp.linalg.eigvalsh(hessian) < 0), newton, uphill)
        step = step * jnp.minimum(1.0, limit / jnp.maximum(jnp.linalg.norm(step), 1e-300))
        better = score(x + step) > value
        done = jnp.linalg.norm(step) < tiny  # accepted or not: nowhere left to go
        return jnp.where(better, x + step, x), jnp.where(better, limit, limit / 4), i + 1, done

    def going(carry):
        _, limit, i, done = carry
        return (i < steps) & (limit > tiny) & ~done

    start = (x, jnp.asarray(step_limit, x.dtype), 0, jnp.asarray(False))
    return jax.lax.while_loop(going, body, start)[0]


# ---- the range-profile tables for detection -------------------------------------------


class _Tables(NamedTuple):
    start: np.ndarray  # (V,) the first tabulated bistatic range of each view (m)
    step: float  # their spacing (m)
    energy: np.ndarray  # (V, S) the range-profile energy Q_v
    centre_tx: np.ndarray  # (V, 3) each view's array centres
    centre_rx: np.ndarray
    spread: float  # how far a pair's bistatic range may be from the centres' (m)
    periodic: bool  # the tables hold one period (S · step) of Q_v, which repeats


@jax.jit
def _profiles(r, k, ranges):
    """Q_v(R_s) = Σ_{m,n} |Σ_f r_v[f,m,n] e^{−j k_f R_s}|² for each view's ranges (V, S)."""

    def one(args):
        r_v, ranges_v = args
        e = jnp.exp(-1j * ranges_v[:, None] * k[None, :])  # (S, F)
        p = jnp.einsum("sf,fmn->smn", e, r_v)
        return jnp.sum(jnp.abs(p) ** 2, axis=(1, 2))

    return jax.lax.map(one, (r, ranges))


@functools.partial(jax.jit, static_argnames="n")
def _periodic_profiles(r, n: int):
    """`_profiles` at the ranges R_s = s·P/n of one period P = 2π/Δk, for uniform
    wavenumbers k_f = k_0 + f·Δk: Σ_f r_f e^{−j k_f R_s} = e^{−j k_0 R_s} Σ_f r_f e^{−2πj fs/n},
    the length-n FFT of the samples (zero-padded; k_0's factor leaves |·|² unchanged). The
    cost is an FFT per antenna pair, not a sum over the frequencies at every range. Needs
    n ≥ F (``fft`` would truncate the samples, not fold them): `_tables` asks ≥ 16(F − 1)."""

    def one(r_v):
        return jnp.sum(jnp.abs(jnp.fft.fft(r_v, n=n, axis=0)) ** 2, axis=(1, 2))

    return jax.lax.map(one, r)


def _tables(r, geometry: Geometry, extent: float, finest: float) -> _Tables:
    """The range-profile tables of the residual ``r`` (a float64 JAX array), sampled finely
    enough for lattices down to ``finest`` metres. With uniform frequencies Q_v repeats
    every 2π/Δk = c/Δf of bistatic range (e^{−j k_f P} = e^{−j k_0 P} for that P): one
    period is tabulated, by an FFT (`_periodic_profiles`)."""
    centre_tx, centre_rx = geometry.tx.mean(1), geometry.rx.mean(1)
    step = min(geometry.range_resolution, 2 * finest) / 8
    reach = 2 * math.sqrt(3) * extent  # |ΔR| ≤ 2|Δx| anywhere in the box
    middle = np.linalg.norm(centre_tx, axis=1) + np.linalg.norm(centre_rx, axis=1)
    period = 2 * np.pi / (geometry.k[1] - geometry.k[0]) if geometry.law.ladder else math.inf
    periodic = period < 2 * reach
    if periodic:
        n = int(math.ceil(period / step))
        step, start = period / n, np.zeros_like(middle)
        energy = np.asarray(_periodic_profiles(r, n))
    else:
        n = int(math.ceil(2 * reach / step)) + 1
        start = middle - reach
        ranges = jnp.asarray(start[:, None] + step * np.arange(n)[None])
        energy = np.asarray(_profiles(r, jnp.asarray(geometry.k), ranges))
    spread = np.max(np.linalg.norm(geometry.tx - centre_tx[:, None], axis=-1)) + np.max(
        np.linalg.norm(geometry.rx - centre_rx[:, None], axis=-1)
    )
    return _Tables(start, step, energy, centre_tx, centre_rx, float(spread), periodic)


def _filtered(tables: _Tables, cell: float) -> _Tables:
    """The tables max-filtered over the bistatic ranges that a lattice cell of ``cell``
    metres covers (and the array's spread): the lattice point nearest a peak reads it.
    Periodic tables wrap around."""
    half = int(math.ceil((math.sqrt(3) * cell + tables.spread) / tables.step))
    size = 2 * half + 1
    if tables.periodic and size >= tables.energy.shape[1]:
        energy = np.broadcast_to(tables.energy.max(1, keepdims=True), tables.energy.shape)
    else:
        mode = "wrap" if tables.periodic else "nearest"
        energy = scipy.ndimage.maximum_filter1d(tables.energy, size, axis=1, mode=mode)
    return tables._replace(energy=energy)


def _bucketed(points: np.ndarray) -> np.ndarray:
    """``points`` padded (with copies of the first) to the next power of two: lattices
    clipped to the box come in many sizes, and each size would compile its programs."""
    size = 1 << max(len(points) - 1, 1).bit_length()
    return np.concatenate([points, np.repeat(points[:1], size - len(points), 0)])


def _read(tables: _Tables, points: np.ndarray) -> np.ndarray:
    """The detection score at ``points`` (L, 3): a low quantile (`_QUANTILE`) over the
    views of Q_v(R_v(x)), each view's table divided by its mean. A scatterer at x shows in
    every view's profile; elsewhere a view reads energy only where some scatterer's range
    (or its alias, every c/Δf of bistatic range) happens to fall. A sum over the views
    cannot tell the two apart once the scatterers fill the profiles; a low quantile can."""
    energy = tables.energy / np.maximum(tables.energy.mean(1, keepdims=True), 1e-300)
    # float32 is enough here: ranges of ~10 m to a few µm, on tables sampled every ~0.3 mm
    single = [
        np.asarray(a, np.float32)
        for a in (_bucketed(points), energy, tables.start, tables.centre_tx, tables.centre_rx)
    ]
    with jax.enable_x64(False):
        return np.asarray(_read_jit(*single, tables.step, tables.periodic))[: len(points)]


@functools.partial(jax.jit, static_argnames="periodic")
def _read_jit(points, energy, start, centre_tx, centre_rx, step, periodic: bool):
    bistatic = jnp.linalg.norm(points[:, None] - centre_tx, axis=-1) + jnp.linalg.norm(
        points[:, None] - centre_rx, axis=-1
    )  # (L, V)
    n = energy.shape[1]
    if periodic:
        position = jnp.mod((bistatic - start) / step, n)
        low = jnp.minimum(position.astype(jnp.int32), n - 1)
        high = jnp.where(low == n - 1, 0, low + 1)
    else:
        position = jnp.clip((bistatic - start) / step, 0, n - 1.000001)
        low = position.astype(jnp.int32)
        high = low + 1
    frac = position - low
    views = jnp.arange(energy.shape[0])
    values = (1 - frac) * energy[views, low] + frac * energy[views, high]
    return _low_quantile(values, _QUANTILE)


def _low_quantile(values, q: float):
    """``jnp.quantile(values, q, axis=1)`` (linear interpolation), for a low ``q``: the
    few smallest of each row taken out one at a time. XLA's sort of many short rows is
    slow on a CPU (0.56 s for 110,592 rows of 40; 0.02 s taking out the 9 smallest). Each
    pass reads the whole array: beyond a few dozen passes sorting is cheaper again."""
    n = values.shape[1]
    h = (n - 1) * q
    low = int(math.floor(h))
    if low + 2 > 32:
        return jnp.quantile(values, q, axis=1)
    columns = jnp.arange(n)

    def smallest(carry, _):
        rest = carry
        i = jnp.argmin(rest, axis=1)
        value = jnp.take_along_axis(rest, i[:, None], axis=1)[:, 0]
        return jnp.where(columns == i[:, None], jnp.inf, rest), value

    _, ordered = jax.lax.scan(smallest, values, None, length=min(low + 2, n))
    if low + 1 >= n:
        return ordered[low]
    return ordered[low] + (h - low) * (ordered[low + 1] - ordered[low])


def _children(cells: np.ndarray, size: float, extent: float) -> np.ndarray:
    """Each cell (a centre, side ``size``) split into 3³ cells of side size/3."""
    offsets = (size / 3) * np.stack(
        np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1
    ).reshape(-1, 3)
    children = (cells[:, None] + offsets[None]).reshape(-1, 3)
    return children[np.all(np.abs(children) <= extent, axis=1)]


def _lattice(centre: np.ndarray, half_width: float, spacing: float, extent: float) -> np.ndarray:
    """The points of a cubic lattice of ``spacing`` within ``half_width`` of ``centre``
    (moved into the box first: a Newton step may leave it), inside the box ±``extent``:
    never empty, the centre is one of them."""
    n = max(1, int(round(half_width / spacing)))
    axis = spacing * np.arange(-n, n + 1)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    points = np.clip(centre, -extent, extent) + grid
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
    coherent: float  # around that (the coherent score's lattice, Newton's steps): λ/8
    near: float  # the points a new one moves, re-localised with it: 4 range resolutions

    @classmethod
    def of(cls, geometry: Geometry, extent: float) -> _Search:
        resolution = min(geometry.range_resolution, 2 * extent)
        pairs = resolution / 6
        coarse = max(2 * extent / _COARSE_CELLS, pairs)
        finest = coarse
        while finest > resolution / 2:
            finest /= 3
        return cls(coarse, finest, pairs, geometry.wavelength / 8, 4 * resolution)


def _detect(residual, geometry: Geometry, arrays, extent: float, search: _Search):
    """The point that removes the most energy from ``residual`` (float64 JAX array) among
    the best few cells of a coarse-to-fine search, each localised (module docstring, steps
    1-2): (x, c(x))."""
    tx, rx, k = arrays
    tables = _tables(residual, geometry, extent, search.finest)
    size = search.coarse
    cells = _lattice(np.zeros(3), extent, size, extent)
    while True:
        ranked = _read(_filtered(tables, size), cells)
        if size <= search.finest * 1.0001:
            break
        cells = _children(cells[np.argsort(ranked)[::-1][:_BEAM]], size, extent)
        size /= 3
    best, best_gain, climbed = None, -1.0, []
    # the score is flat over the array's spread around a scatterer: candidates closer than
    # that would mostly climb to the same one
    for cell in _local_maxima(cells, ranked, _CANDIDATES, 2 * size + tables.spread):
        # the cell is within ~1 cm of a scatterer (the tables are max-filtered over the
        # array's spread); the pairs' score climbs to within ~1 mm of it (measured)
        x = _peak("pairs", cell, search.pairs, search.pairs, residual, geometry, arrays, extent)
        x = np.asarray(_newton("pairs", x, residual, *arrays, search.pairs / 2, geometry.law))
        if any(np.linalg.norm(x - c) < search.pairs / 2 for c in climbed):
            continue  # the same peak as a candidate already localised
        climbed.append(x)
        x = _localise(x, residual, geometry, arrays, extent, search)
        gain = float(_gain(x, residual, tx, rx, k, geometry.law))  # exact, where it will sit
        if gain > best_gain:
            best, best_gain = np.asarray(x), gain
    return best, best_gain


def _peak(kind: str, centre, radius: float, spacing: float, residual, geometry: Geometry,
          arrays, extent: float):  # fmt: skip
    """The best point for `_score` ``kind`` on the lattice of ``spacing`` within ``radius``
    of ``centre``."""
    around = jnp.asarray(_bucketed(_lattice(np.asarray(centre), radius, spacing, extent)))
    return around[jnp.argmax(_on_lattice(kind, around, residual, *arrays, geometry.law))]


def _localise(centre, residual, geometry: Geometry, arrays, extent: float, search: _Search):
    """The coherent score's peak near ``centre``: its best point on the λ/8 lattice within
    half the pairs' spacing, then Newton (module docstring, step 2)."""
    x = _peak("coherent", centre, search.pairs / 2, search.coherent, residual, geometry,
              arrays, extent)  # fmt: skip
    x = _newton("coherent", x, residual, *arrays, search.coherent, geometry.law)
    return jnp.clip(x, -extent, extent)


# The scatterers found so far live in arrays of a fixed capacity (``max_points``), with a
# mask: every program below then compiles once per run, not once per round.


@functools.partial(jax.jit, static_argnames="law")
def _least_squares(points, live, y, tx, rx, k, law: Law):
    """Least-squares amplitudes of the ``live`` point scatterers at ``points`` (P, 3) for
    data ``y`` (0 for the others), and the residual they leave. By the normal equations:
    the atoms of points at least λ/2 apart (`_prune` merges closer ones) are far from
    parallel (correlation ≲ 0.5), so their P × P Gram matrix is well conditioned, and
    forming it costs
    little beside the SVD that `jnp.linalg.lstsq` would take of the (samples × P) atoms."""
    g = jax.vmap(atom, (0, None, None, None, None))(points, tx, rx, k, law)
    g = jnp.where(live[:, None], g.reshape(points.shape[0], -1), 0)
    gram = jnp.conj(g) @ g.T
    gram = jnp.where(live[:, None] & live[None], gram, jnp.eye(len(live)))
    # a point just detected on top of another (before `_prune` merges them) would make it
    # singular: a ridge far below any other scale keeps the solution finite
    gram = gram + 1e-12 * jnp.max(jnp.abs(jnp.diag(gram))) * jnp.eye(len(live))
    amplitudes = jnp.linalg.solve(gram, jnp.conj(g) @ y.reshape(-1))
    amplitudes = jnp.where(live, amplitudes, 0)
    return amplitudes, y - (amplitudes @ g).reshape(y.shape)


@functools.partial(jax.jit, static_argnames="law")
def _model(points, amplitudes, tx, rx, k, law: Law):
    return signals(points, amplitudes, tx, rx, k, law)


def _fitted(points, live, y, geometry: Geometry, arrays):
    """The ``live`` points' least-squares amplitudes (host), and the residual they leave."""
    amplitudes, residual = _least_squares(jnp.asarray(points), jnp.asarray(live), y, *arrays,
                                          geometry.law)  # fmt: skip
    return np.asarray(amplitudes), residual


@functools.partial(jax.jit, static_argnames="law")
def _restore(residual, x, amplitude, tx, rx, k, law: Law):
    """The residual with the point at ``x`` put back: the data the others leave."""
    return residual + amplitude * atom(x, tx, rx, k, law)


@functools.partial(jax.jit, static_argnames="law")
def _explain(others, x, tx, rx, k, law: Law):
    """The least-squares amplitude of a point at ``x`` for ``others``, and what it leaves."""
    g = atom(x, tx, rx, k, law)
    amplitude = jnp.vdot(g, others) / jnp.vdot(g, g).real
    return amplitude, others - amplitude * g


def _revisit(which, points, amplitudes, residual, geometry: Geometry, arrays, extent: float,
             search: _Search, *, lattice: bool):  # fmt: skip
    """Each point of ``which`` (indices), in turn, moved to where it best explains the
    data the others leave (Newton, from a lattice search around it when ``lattice``), and
    its amplitude re-fitted: one cycle. The residual is updated as the points move, one
    atom each, not re-synthesised."""
    points, amplitudes = points.copy(), amplitudes.copy()
    for j in which:
        others = _restore(residual, jnp.asarray(points[j]), amplitudes[j], *arrays, geometry.law)
        if lattice:  # a point placed while others were unexplained may sit on a sidelobe
            x = _localise(points[j], others, geometry, arrays, extent, search)
        else:
            x = _newton("coherent", jnp.asarray(points[j]), others, *arrays, search.coherent,
                        geometry.law)  # fmt: skip
            x = jnp.clip(x, -extent, extent)
        amplitude, residual = _explain(others, x, *arrays, geometry.law)
        points[j], amplitudes[j] = np.asarray(x), complex(amplitude)
    return points, amplitudes, residual


@functools.partial(jax.jit, static_argnames="law")
def _energies(points, amplitudes, tx, rx, k, law: Law):
    """|a_k|² ‖g(x_k)‖²: the energy each point contributes on its own."""

    def norm(x):
        return _norm(*_sides(x, tx, rx), k, law)

    return jnp.abs(amplitudes) ** 2 * jax.vmap(norm)(points)


def _prune(points, amplitudes, live, geometry: Geometry, arrays, threshold: float):
    """The live mask, less the points closer than λ/2 to a stronger one (merged into it:
    the amplitudes are re-fitted afterwards) and those that contribute less than
    ``threshold`` of energy."""
    energy = np.asarray(_energies(jnp.asarray(points), jnp.asarray(amplitudes), *arrays,
                                  geometry.law))  # fmt: skip
    keep = np.zeros_like(live)
    for i in np.argsort(energy)[::-1]:
        if not live[i] or energy[i] < threshold:
            continue
        close = np.linalg.norm(points[keep] - points[i], axis=1) < geometry.wavelength / 2
        keep[i] = not np.any(close)
    return keep


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
    - `max_points`: at most this many rounds, each adding one scatterer (or none, when
      it merges into one already found): at most this many scatterers.
    - `noise`: the standard deviation of the data's complex noise per sample, if known:
      points that remove less energy than the largest that noise alone would give over the
      box (at a false-alarm rate of 1 %) are not added.
    - `tol`: stop once the relative residual ‖y − Σ a g‖/‖y‖ is below this.
    - `floor`: nor are points that remove less than this fraction of the data's energy.
    - `refine_steps`: the final joint Levenberg-Marquardt's step budget (0: none).

    **Returns:** a `Solution` whose ``field`` is the `PointScatterers` (amplitudes in the
    units of ``signal``), ``rho`` their amplitudes, and ``history`` one entry per round
    (the relative residual once the round's point is added and refined) and one for the
    final refinement.
    """
    check_positive("points: `extent`", extent)
    check_positive_int("points: `max_points`", max_points)
    for name, value in (("tol", tol), ("floor", floor)):
        if not (isinstance(value, int | float) and 0 <= value < 1):
            raise ValueError(f"points: `{name}` must be a number in [0, 1), got {value!r}.")
    if noise is not None and not is_finite_nonnegative(noise):
        raise ValueError(f"points: `noise` must be a finite number ≥ 0 or None, got {noise!r}.")
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
    points = np.zeros((max_points, 3))
    amplitudes = np.zeros(max_points, np.complex128)
    live = np.zeros(max_points, bool)
    residuals, seconds = [], []
    outcome = Outcome.BUDGET
    with jax.enable_x64(True):
        arrays = geometry.arrays()
        y = jnp.asarray(y_host)
        residual = y
        for _ in range(max_points):
            if energy == 0:
                outcome = Outcome.ZERO_SIGNAL
                break
            if float(jnp.linalg.norm(residual)) <= tol * math.sqrt(energy):
                outcome = Outcome.CONVERGED
                break
            x, gain = _detect(residual, geometry, arrays, extent, search)
            if gain < threshold:
                outcome = Outcome.CONVERGED
                break
            slot = int(np.flatnonzero(~live)[0])
            points[slot], live[slot] = x, True
            amplitudes, residual = _fitted(points, live, y, geometry, arrays)
            # the new point, then those near it (whose best positions it moves most):
            # the others are searched for again after a merge and at the end
            distance = np.linalg.norm(points - x, axis=1)
            near = [slot] + [j for j in np.argsort(distance)
                             if live[j] and j != slot and distance[j] < search.near]  # fmt: skip
            points, amplitudes, residual = _revisit(
                near, points, amplitudes, residual, geometry, arrays, extent, search,
                lattice=False,
            )  # fmt: skip
            before = live.sum()
            live = _prune(points, amplitudes, live, geometry, arrays, threshold)
            if live.sum() < before:  # merged or dropped: a point was likely on a sidelobe
                amplitudes, residual = _fitted(points, live, y, geometry, arrays)
                points, amplitudes, residual = _revisit(
                    np.flatnonzero(live), points, amplitudes, residual, geometry, arrays,
                    extent, search, lattice=True,
                )  # fmt: skip
            amplitudes, residual = _fitted(points, live, y, geometry, arrays)
            residuals.append(float(jnp.linalg.norm(residual)) / math.sqrt(energy))
            seconds.append(time.perf_counter() - started)
        if live.sum() > 1:  # each point looked for again around itself, the others known
            points, amplitudes, residual = _revisit(
                np.flatnonzero(live), points, amplitudes, residual, geometry, arrays, extent,
                search, lattice=True,
            )  # fmt: skip
            amplitudes, residual = _fitted(points, live, y, geometry, arrays)
        points, amplitudes = points[live], np.asarray(amplitudes)[live]
        if len(points) and refine_steps:
            points, amplitudes = _joint(points, amplitudes, y, geometry, arrays, refine_steps)
            points = np.clip(points, -extent, extent)
            # the joint refinement may shrink a point to nothing, or bring two together
            kept = _prune(points, amplitudes, np.ones(len(points), bool), geometry, arrays,
                          threshold)  # fmt: skip
            if kept.any() and not kept.all():
                points = points[kept]
                amplitudes, residual = _fitted(points, np.ones(len(points), bool), y, geometry,
                                               arrays)  # fmt: skip
            else:
                residual = y - _model(jnp.asarray(points), jnp.asarray(amplitudes), *arrays,
                                      geometry.law)  # fmt: skip
            residuals.append(float(jnp.linalg.norm(residual)) / math.sqrt(energy))
            seconds.append(time.perf_counter() - started)
    if residuals and residuals[-1] <= tol:  # the last round or the refinement got there
        outcome = Outcome.CONVERGED
    history = History(np.asarray(residuals), np.asarray(seconds))
    scatterers = None
    if len(points):
        scatterers = PointScatterers(points, amplitudes.astype(np.complex64), extent)
    stats = {"points": len(points), "threshold": threshold / energy if energy else 0.0}
    return Solution(
        jnp.asarray(amplitudes, jnp.complex64), history, Stop(outcome, len(history)), stats,
        field=scatterers,
    )  # fmt: skip


@functools.partial(jax.custom_jvp, nondiff_argnums=(5,))
def _sparse_signals(points, amplitudes, tx, rx, k, law: Law):
    """`signals`, whose derivatives know that each point moves only its own atom: a
    Jacobian by forward mode then costs the K atoms' own 3 slopes and a product, not
    K atoms per unknown (5K of them), which made the joint refinement of 40 points take
    8 minutes. Differentiable in ``points`` and ``amplitudes`` only: the antennas and the
    wavenumbers are data."""
    return signals(points, amplitudes, tx, rx, k, law)


def _sparse_signals_jvp(law: Law, primals, tangents):
    points, amplitudes, tx, rx, k = primals
    if not all(isinstance(t, SymbolicZero) for t in tangents[2:]):
        raise NotImplementedError(
            "points: the joint refinement's model is differentiable in the positions and "
            "amplitudes only; differentiate `signals` for the antennas or wavenumbers."
        )
    d_points, d_amplitudes = (
        jnp.zeros(t.shape, t.dtype) if isinstance(t, SymbolicZero) else t for t in tangents[:2]
    )

    def atom_of(x):
        return atom(x, tx, rx, k, law)

    atoms = jax.vmap(atom_of)(points)  # (K, V, F, M, N)
    slopes = jax.vmap(jax.jacfwd(atom_of))(points)  # (K, V, F, M, N, 3)
    model = jnp.tensordot(amplitudes, atoms, 1)
    moved = jnp.einsum("k,kj,k...j->...", amplitudes, d_points.astype(slopes.dtype), slopes)
    return model, jnp.tensordot(d_amplitudes, atoms, 1) + moved


_sparse_signals.defjvp(_sparse_signals_jvp, symbolic_zeros=True)


def _joint_residual(params, args):
    """The real residual y − Σ a g(x) of `_joint`'s unknowns (module level, taking its data
    as ``args``: optimistix then compiles once per point count)."""
    (offsets, re, im), (origin, unit, y, tx, rx, k, law) = params, args
    model = _sparse_signals(origin + unit * offsets, re + 1j * im, tx, rx, k, law)
    difference = (y - model).reshape(-1)
    return jnp.concatenate([difference.real, difference.imag])


def _joint(points, amplitudes, y, geometry: Geometry, arrays, steps: int):
    """Every position and amplitude refined together by Levenberg-Marquardt (optimistix),
    positions as offsets in units of λ/8 (so that both kinds of unknowns are O(1)). Kept
    only if it lowers the residual."""
    origin = jnp.asarray(points)
    args = (origin, geometry.wavelength / 8, y, *arrays, geometry.law)
    start = (jnp.zeros_like(origin), jnp.asarray(amplitudes.real), jnp.asarray(amplitudes.imag))
    solver = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-10)
    solution = optx.least_squares(
        _joint_residual, solver, start, args, max_steps=steps, throw=False
    )
    before = float(jnp.linalg.norm(_joint_residual(start, args)))
    after = float(jnp.linalg.norm(_joint_residual(solution.value, args)))
    if not after <= before:
        return points, amplitudes
    offsets, re, im = solution.value
    return np.asarray(origin + args[1] * offsets), np.asarray(re + 1j * im)
