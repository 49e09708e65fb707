"""Pure GRT kernels for one viewpoint (paper Eq. 1 and Appendix Eqs. 12-13).

    S[f, m, n] = Σ_v ρ_v · exp(+j k_f R_v,mn) · A_v,mn,    R_v,mn = |x_v - tx_m| + |x_v - rx_n|,

with k_f = 2π f / c0, A = 1/R² in the near field and A = 1 in the far field.

Why it is computed the way it is (measured numbers in docs/conventions.md, "Precision"):

- **float64 geometry.** k·R reaches 10⁴-10⁵ rad, so a float32 distance (ulp ≈ 1e-6 m at
  10 m) puts 10⁻³ rad of phase error on every term. Distances and the few phases per distance
  are computed in float64 and reduced there (to a quadrant and a remainder |t| ≤ π/4); only the
  remainder is cast to float32. All heavy work is float32 and accurate to ~1e-6.
- **Separable exponential.** exp(j k (r_t + r_r)) = exp(j k r_t) · exp(j k r_r), so for each
  frequency S_f = X_f · Y_fᵀ with X_f[m, v] = ρ_v a_vm exp(j k_f r_vm): a batch of small matrix
  products, 100·n_tx·n_rx·V complex multiply-adds per view.
- **Separable amplitude.** 1/(r_t + r_r)² = 1/(4 r_t r_r) · 1/(1 + q), q = (r_t - r_r)²/(4 r_t r_r),
  and 1/(1 + q) = Σ_k (-q)^k. Expanded to order n, the amplitude is a sum of 2n + 1 separable
  terms c_i · r_t^(i-1) · r_r^(-i-1), i = -n..n (`spreading_terms`), with relative error
  ≤ q^(n+1) for every term of the sum. q ≤ D²/(4 r_min²) for antennas at most D apart and r_min
  from the nearest point (`amplitude_bound`), and the smallest order that keeps this below
  `AMPLITUDE_TOLERANCE` is used: the paper's array (D ≈ 3 cm) 8-10 m from its scene needs
  order 0, one product 1/(4 r_t r_r); TX and RX apart (a bistatic pair, a sparse MIMO array)
  need more terms, each one more contraction over the voxels. The bistatic radar equation's
  1/(r_t r_r) is one exact term.
- **Frequency ladder.** On a uniform grid f = f_0 + (iB + j)Δf, so exp(j k_f r) =
  [exp(j k_0 r) · exp(j B Δk r)^i] · exp(j Δk r)^j: three phasors per distance, powers by
  doubling, and one product per frequency. Non-uniform grids (or traced frequencies) take the
  direct path: F phasors per distance.
- **Voxel chunks.** Voxels are processed ``chunk_size`` at a time in a ``lax.scan``, so memory
  is O(F·(n_tx + n_rx)·chunk) whatever V is.
- **Split real arithmetic.** XLA:CPU vectorises float32 far better than complex64, and its
  real batched matrix products are ~2x faster than complex ones: phasors are (re, im) pairs,
  and each frequency's product is one real (2·n_tx × K)·(K × 2·n_rx) product.
- **Materialised stages** (CPU): see `_materialise`.
- **Exact products on every backend.** Every matrix product requests
  ``Precision.HIGHEST``: XLA's default float32 product on NVIDIA GPUs is TensorFloat-32
  (10-bit mantissa), which put the GRT at 2.7e-4 relative error on an H100 against ~1e-6 here
  (docs/benchmarks.md). `tests/test_precision.py` reads every product from the jaxprs.
- **One compilation per configuration, every core.** `forward` and `adjoint` are jitted
  (static: frequency plan, near field, chunk), so a plain call with host arrays hits the
  cache; one view's voxels are split over the devices (`rift_jax._sharding.over_voxels`).

``adjoint`` is the exact conjugate transpose of ``forward``: the same phasors, conjugated,
contracted in the other order. Autodiff through ``forward`` gives the same numbers (tested).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from ._geometry import C0
from ._precision import Float64Pair, as_geometry, host_float64, leading, to_float64
from ._sharding import over_voxels, pad_leading, pinned, split_voxels
from ._validation import check_finite, check_positive_int, is_concrete

_TWO_PI = 2.0 * math.pi
# The largest relative error that the separable amplitude may put on any one term of the sum
# (see "Separable amplitude" above): the GRT's accuracy bar (float32 within 1e-5 of the
# float64 reference), held term by term, so that no scene (a lone scatterer next to the
# array) can see more.
AMPLITUDE_TOLERANCE = 1e-5
# The largest order of the amplitude's expansion: beyond q ≈ 0.28 (TX and RX about as far
# apart as the nearest point) it converges too slowly to be worth its 2n + 1 contractions.
_MAX_ORDER = 8
# Every product's precision, whatever the backend's or JAX's global default (see above).
EXACT = jax.lax.Precision.HIGHEST


class FrequencyPlan(NamedTuple):
    """How phasors over the frequencies are built: a ladder (uniform grid, concrete values) or
    directly from the (possibly traced) frequencies."""

    n: int
    f0: float | None = None  # uniform grid only
    df: float | None = None  # uniform grid only

    @property
    def uniform(self) -> bool:
        return self.f0 is not None


def frequency_plan(frequencies) -> FrequencyPlan:
    """Check ``frequencies`` (1-D, positive, finite) and choose how to build its phasors."""
    shape = jnp.shape(frequencies)
    if len(shape) != 1 or shape[0] == 0:
        raise ValueError(f"`frequencies` must be a non-empty 1-D array (Hz), got shape {shape}.")
    if not is_concrete(frequencies):
        return FrequencyPlan(shape[0])
    f = np.asarray(frequencies, np.float64)
    if not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise ValueError("`frequencies` must be positive and finite (Hz).")
    if f.size == 1:
        return FrequencyPlan(1, float(f[0]), 0.0)
    df = (f[-1] - f[0]) / (f.size - 1)
    grid = f[0] + df * np.arange(f.size)
    if df > 0 and np.max(np.abs(grid - f)) <= 1e-12 * f.max():
        return FrequencyPlan(f.size, float(f[0]), float(df))
    return FrequencyPlan(f.size)


_QUARTER_TURN = 0.5 * math.pi


def _cis(wavenumber, r: Array, real_dtype) -> tuple[Array, Array]:
    """(cos, sin) of k·r. The phase is formed in float64 and reduced there to a quadrant q and
    a remainder |t| ≤ π/4; only t is cast. In float32, short Taylor polynomials (truncation
    < 2e-9) replace XLA's sin/cos, which cost ~10 ns per element on CPU against ~0.7 ns."""
    phase = jnp.asarray(wavenumber, jnp.float64) * r
    q = jnp.round(phase * (1.0 / _QUARTER_TURN))
    t = (phase - q * _QUARTER_TURN).astype(real_dtype)
    quadrant = (q - 4.0 * jnp.floor(q * 0.25)).astype(jnp.int32)
    if real_dtype == jnp.float64:
        c, s = jnp.cos(t), jnp.sin(t)
    else:
        t2 = t * t
        s = t * (1 + t2 * (-1 / 6 + t2 * (1 / 120 + t2 * (-1 / 5040 + t2 / 362880))))
        c = 1 + t2 * (-1 / 2 + t2 * (1 / 24 + t2 * (-1 / 720 + t2 * (1 / 40320 - t2 / 3628800))))
    odd = (quadrant & 1) == 1  # cos(qπ/2 + t), sin(qπ/2 + t) from cos t, sin t
    c, s = jnp.where(odd, -s, c), jnp.where(odd, c, s)
    negate = quadrant >= 2
    return jnp.where(negate, -c, c), jnp.where(negate, -s, s)


def _cmul(a: tuple[Array, Array], b: tuple[Array, Array]) -> tuple[Array, Array]:
    """Complex product on (real, imaginary) pairs: XLA:CPU vectorises split float32 arithmetic
    far better than complex64."""
    return a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0]


def _powers(step: tuple[Array, Array], n: int) -> tuple[Array, Array]:
    """step^j for j < n, stacked on a new leading axis, by doubling: each power carries at most
    log2(n) complex roundings (a running product would carry up to n)."""
    re = jnp.stack([jnp.ones_like(step[0]), step[0]])
    im = jnp.stack([jnp.zeros_like(step[1]), step[1]])
    square = step
    while re.shape[0] < n:
        square = _cmul(square, square)
        more = _cmul((re, im), (square[0][None], square[1][None]))
        re, im = jnp.concatenate([re, more[0]]), jnp.concatenate([im, more[1]])
    return re[:n], im[:n]


def _ladder_sizes(n: int) -> tuple[int, int]:
    """(n_coarse, n_fine) with n_coarse · n_fine ≥ n and n_coarse + n_fine smallest (≈ 2√n)."""
    n_fine = math.isqrt(n - 1) + 1 if n > 1 else 1
    return -(-n // n_fine), n_fine


Spreading = tuple[tuple[float, int], ...] | None
"""The amplitude as separable terms ``(c, i)``: c · r_t^(i-1) · r_r^(-i-1); None: 1 (far
field). Static (hashable) in the kernels."""


def amplitude_bound(separation: float, nearest: float) -> float:
    """An upper bound on q = (r_t - r_r)²/(4 r_t r_r) for antennas at most ``separation``
    metres apart, none nearer a point than ``nearest`` (|r_t - r_r| ≤ |tx - rx|)."""
    if nearest <= 0:
        return math.inf
    return separation**2 / (4.0 * nearest**2)


def _q_bound(r_t, r_r, xp):
    """The largest q = (r_t - r_r)²/(4 r_t r_r) over all antenna pairs, bounded from the
    distances (antennas, points) of each side to the points: per point, from its nearest
    and farthest antenna of each side. NumPy (host) or jax.numpy as ``xp``."""
    lo_t, hi_t, lo_r, hi_r = r_t.min(0), r_t.max(0), r_r.min(0), r_r.max(0)
    spread = xp.maximum(hi_t - lo_r, hi_r - lo_t)
    return xp.max(spread * spread / (4.0 * lo_t * lo_r))


def largest_q(points: np.ndarray, antennas) -> float:
    """`_q_bound` over ``points`` (host, float64, (n, 3)) and each of ``antennas``' (tx, rx)
    pairs of arrays, as `_needs_near_terms` reads each chunk: O(points · antennas) per pair
    of arrays."""
    largest = 0.0
    for tx, rx in antennas:
        for start in range(0, len(points), 4096):
            block = points[None, start : start + 4096]
            r_t = np.linalg.norm(block - tx[:, None], axis=-1)
            r_r = np.linalg.norm(block - rx[:, None], axis=-1)
            with np.errstate(divide="ignore"):  # a point on an antenna: q = inf, refused
                largest = max(largest, float(_q_bound(r_t, r_r, np)))
    return largest


def spreading_terms(law: str, bound: float = 0.0) -> Spreading:
    """The kernels' amplitude for a spreading ``law``: "far-field" (none), "radar-equation"
    (1/(r_t r_r), one exact term) or "paper" (1/(r_t + r_r)², expanded to the smallest
    order n whose error ``bound``^(n+1) is at most `AMPLITUDE_TOLERANCE`; ``bound`` from
    `amplitude_bound`). Order n has the 2n + 1 terms c_i r_t^(i-1) r_r^(-i-1),
    c_i = (-1)^i Σ_{k=|i|..n} C(2k, k+i) / 4^(k+1): the binomial expansion of
    Σ_k (-q)^k / (4 r_t r_r)."""
    if law == "far-field":
        return None
    if law == "radar-equation":
        return ((1.0, 0),)
    if law != "paper":
        raise ValueError(f"`spreading` must be 'paper' or 'radar-equation', got {law!r}.")
    order = 0
    while bound ** (order + 1) > AMPLITUDE_TOLERANCE:
        order += 1
        if order > _MAX_ORDER:
            raise ValueError(
                f"The GRT's 1/(r_t + r_r)² cannot be separated to {AMPLITUDE_TOLERANCE:g} "
                f"here: its expansion parameter reaches {bound:.3g} (transmitters and "
                "receivers nearly as far apart as the nearest point is from them). Move the "
                "scene away from the antennas, or use spreading='radar-equation' (1/(r_t r_r))."
            )
    return tuple(
        (
            (-1) ** abs(i)
            * sum(math.comb(2 * k, k + i) / 4 ** (k + 1) for k in range(abs(i), order + 1)),
            i,
        )
        for i in range(-order, order + 1)
    )


class Amplitude(NamedTuple):
    """The kernels' amplitude (static): the separable ``terms`` in every voxel chunk; with
    ``near``, a chunk whose largest q exceeds `AMPLITUDE_TOLERANCE` (read from its own
    distances) takes the ``near`` terms instead. On CPU that is a conditional per chunk, and
    only chunks close to the antennas pay for more terms; accelerators, which would run both
    arms, take ``near`` everywhere."""

    terms: Spreading = None
    near: Spreading = None

    @classmethod
    def of(cls, law: str, bound: float = 0.0, largest=None) -> Amplitude:
        """The amplitude for ``law`` (see `spreading_terms`) where q ≤ ``bound``, a cheap
        bound (`amplitude_bound`). Where it would call for more than three terms, the
        callable ``largest`` (if given) reads the geometry's own largest q
        (`largest_q`: slower, and up to ~10^2 tighter for TX and RX apart), so that a
        geometry is refused, or given many terms, on what it needs."""
        terms = spreading_terms(law)
        if law != "paper" or bound <= AMPLITUDE_TOLERANCE:
            return cls(terms)
        if largest is not None and bound**2 > AMPLITUDE_TOLERANCE:
            bound = min(bound, largest())
            if bound <= AMPLITUDE_TOLERANCE:
                return cls(terms)
        return cls(terms, spreading_terms(law, bound))

    @classmethod
    def unread(cls, law: str) -> Amplitude:
        """The amplitude for geometry that cannot be read (traced): q ≤ `_TRACED_BOUND`
        assumed, its terms in every chunk (no conditional, which a vmap inside the voxel
        split cannot carry)."""
        return cls(spreading_terms(law, _TRACED_BOUND if law == "paper" else 0.0))

    def everywhere(self) -> Spreading:
        """The terms used where no conditional runs: ``near`` if any, else ``terms``."""
        if self.near is not None and jax.default_backend() != "cpu":
            return self.near
        return self.terms


def _needs_near_terms(points, tx, rx) -> Array:
    """Whether this chunk's largest q = (r_t - r_r)²/(4 r_t r_r) exceeds the tolerance: a
    bound over its antenna pairs from each point's nearest and farthest antennas. (A bound
    from two distances per point, to each side's centroid, costs less but is ~3x looser on
    the paper's array: 7-10 % of the chunks of a ±5 m scene took three terms, against none
    here, measured.)"""
    with jax.enable_x64(True):
        q = _q_bound(_distances(points, tx), _distances(points, rx), jnp)
        return q > AMPLITUDE_TOLERANCE


def _by_chunk(amplitude: Amplitude, work, points, tx, rx, *operands):
    """``work(terms, points, tx, rx, *operands)`` for one chunk, with the terms its points
    need (see `Amplitude`). The operands are passed to the conditional, not closed over:
    inside a `shard_map` their device-dependence must reach both arms as it is."""
    terms = amplitude.everywhere()
    if amplitude.near is None or terms is amplitude.near:
        return work(terms, points, tx, rx, *operands)
    return jax.lax.cond(
        _needs_near_terms(points, tx, rx),
        functools.partial(work, amplitude.near),
        functools.partial(work, amplitude.terms),
        points,
        tx,
        rx,
        *operands,
    )


def _side_amplitudes(terms: tuple[tuple[float, int], ...], r, transmit: bool, real_dtype):
    """Each term's factor on one side, (n_terms, a, K) (float64 in, ``real_dtype`` out):
    c·r_t^(i-1) on the TX side, r_r^(-i-1) on the RX side. One term splits its coefficient
    as √|c| on each side (the paper's 0.5/r each), so its two factors are alike in size."""
    inverse = 1.0 / r
    out = []
    for c, i in terms:
        power = i - 1 if transmit else -i - 1
        scale = math.sqrt(abs(c)) if len(terms) == 1 else (abs(c) if transmit else 1.0)
        sign = -1.0 if (c < 0 and transmit) else 1.0
        out.append((sign * scale) * (r**power if power > 0 else inverse ** (-power)))
    return jnp.stack(out).astype(real_dtype)


def _distances(points, antennas) -> Float[Array, "a v"]:
    """|x_v - antenna_a| in float64 (call inside ``jax.enable_x64``). Written elementwise: XLA
    turns a reduction over the size-3 axis into a slow library call."""
    p, a = to_float64(points), to_float64(antennas)
    d = [p[None, :, i] - a[:, None, i] for i in range(3)]
    return jnp.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])


def _materialise(fn, flag, *args):
    """``fn(*args)`` evaluated into buffers of its own. XLA:CPU drops ``optimization_barrier``
    and would fuse the phasor ladder (sines, cosines, products) into every element of the
    outer product, recomputing it 100-fold; it never fuses across a conditional. ``flag`` is
    always true but computed from per-chunk data, so the compiler cannot fold it away (the
    untaken branch, zeros, exists only to give the conditional a second arm).
    Accelerators recompute cheaply and pay for conditionals: there, ``fn`` runs inline."""
    if jax.default_backend() != "cpu":
        return fn(*args)

    def zeros(*args):  # the branch never taken. Zeros shaped from fn's own outputs carry
        # exactly their shard_map types (varying or not); fn's work there is dead code.
        return jax.tree.map(lambda y: _zeros(y.shape, y.dtype, y), fn(*args))

    return jax.lax.cond(flag, fn, zeros, *args)


def _factors(
    points, tx, rx, plan: FrequencyPlan, frequencies, terms: Spreading, real_dtype, rho=None
):
    """Phasor factors of one voxel chunk for each side: (coarse, fine), each a (re, im) pair,
    such that for frequency f = i·B + j, Σ_t coarse[i, :, t·K + v] · fine[j, :, t·K + v] =
    w_v · a_v · exp(j k_f r) summed over the amplitude's separable ``terms`` t (`Spreading`;
    one term: K columns, as many voxels), with the weight w = ρ on the TX side when ``rho``
    is given (else 1). ρ enters inside the first materialised stage, linearly: multiplied in
    later, XLA fuses it into the outer product and the forward runs 2x slower (measured).

    Uniform grid: three float64-reduced phasors per distance, exp(j k_0 r), exp(j Δk r) and
    exp(j B Δk r); fine[j] = exp(j Δk r)^j and coarse[i] = exp(j k_0 r) · exp(j B Δk r)^i by
    doubling (≤ 2 log2 √F complex roundings: ~1e-6 rad). Otherwise coarse holds every
    frequency and fine is 1. Several amplitude terms scale coarse once the ladder is built
    (one ladder per distance, whatever the number of terms).
    """
    first = jax.tree.leaves(points)[0][0, 0]
    flag = (first == first) | jnp.isnan(first)  # true even for NaN: never silently drop a chunk
    n_coarse, n_fine = _ladder_sizes(plan.n)
    n_terms = 1 if terms is None else len(terms)

    def phasors(points, tx, rx, rho):
        out = []
        with jax.enable_x64(True):
            for transmit, antennas, weight in ((True, tx, rho), (False, rx, None)):
                r = _distances(points, antennas)
                factors = None
                if terms is not None:
                    factors = _side_amplitudes(terms, r, transmit, real_dtype)
                if plan.uniform:
                    k0, dk = _TWO_PI / C0 * plan.f0, _TWO_PI / C0 * plan.df
                    base = _cis(k0, r, real_dtype)
                    steps = (_cis(dk, r, real_dtype), _cis(dk * n_fine, r, real_dtype))
                else:
                    k = _TWO_PI / C0 * to_float64(frequencies)
                    base, steps = _cis(k[:, None, None], r, real_dtype), None
                if n_terms == 1 and factors is not None:
                    base, factors = (base[0] * factors[0], base[1] * factors[0]), None
                if weight is not None:
                    base = _cmul(base, (jnp.real(weight), jnp.imag(weight)))
                out.append((base, steps, factors))
        return out

    def ladders(sides):
        out = []
        for base, steps, factors in sides:
            if steps is None:  # direct path: all frequencies are in `base` already
                one = jnp.ones_like(base[0][:1])  # varies over shard_map axes as `base` does
                coarse, fine = base, (one, jnp.zeros_like(one))
            else:
                coarse = _cmul(_powers(steps[1], n_coarse), (base[0][None], base[1][None]))
                fine = _powers(steps[0], n_fine)
            if factors is not None:  # each term's columns: coarse scaled, fine repeated
                coarse = tuple(
                    jnp.concatenate([c * f[None] for f in factors], axis=-1) for c in coarse
                )
                fine = tuple(jnp.concatenate([f] * n_terms, axis=-1) for f in fine)
            out.append((coarse, fine))
        return out

    sides = _materialise(phasors, flag, points, tx, rx, rho)
    return _materialise(ladders, flag, sides)


def _stack_frequencies(coarse, fine, n: int) -> Float[Array, "f 2a k"]:
    """All frequencies from the ladder, as real blocks [re; im] per frequency: (F, 2a, K)."""
    cr, ci = coarse[0][:, None], coarse[1][:, None]
    fr, fi = fine[0][None], fine[1][None]
    x = jnp.concatenate([cr * fr - ci * fi, cr * fi + ci * fr], axis=2)
    return x.reshape((-1,) + x.shape[2:])[:n]


def _chunked(x, chunk: int, mode: str = "edge"):
    """Split the leading (voxel) axis of an array or pair into chunks of ``chunk``, padding
    the last one: points repeat the last point ("edge": a padded point at the origin would
    sit on an antenna placed there, and its 1/r would put inf·0 = NaN in every sample), ρ
    is padded with zeros ("constant"), so padded points contribute nothing."""

    n_chunks = -(-leading(x) // chunk)
    x = pad_leading(x, n_chunks * chunk - leading(x), mode)
    return jax.tree.map(lambda a: a.reshape((n_chunks, chunk) + a.shape[1:]), x)


def default_chunk(adjoint: bool = False) -> int:
    """Voxels per scan step. On CPU, 64 (forward) and 128 (adjoint) keep one chunk's
    per-frequency operands (100 × 32 × 64 float32 = 0.8 MB) near L2 and gave the best medians
    (benchmarks/grt.py); accelerators want large steps."""
    if jax.default_backend() != "cpu":
        return 4096
    return 128 if adjoint else 64


def _per_term(chunk: int, amplitude: Amplitude) -> int:
    """Voxels per chunk when each carries one column per amplitude term (in every chunk:
    `Amplitude.everywhere`): the contraction stays ``chunk`` long, so a chunk's operands stay
    as large as with one term (3 terms with 3x the voxels per chunk: 5x slower, measured)."""
    terms = amplitude.everywhere()
    return max(8, chunk // (1 if terms is None else len(terms)))


def chunk_length(n_points: int, chunk_size: int) -> int:
    """The chunk actually used: at most ``chunk_size``, with the points spread evenly over the
    chunks (rounded up to a multiple of 8), so padding stays small."""
    n_chunks = -(-n_points // chunk_size)
    per_chunk = -(-n_points // n_chunks)
    return min(chunk_size, -(-per_chunk // 8) * 8)


def _zeros(shape, dtype, *like: Array) -> Array:
    """Zeros that vary over the same ``shard_map`` axes as the arrays ``like`` (a broadcast of
    their zeros, which carries that type): a scan carry or a never-taken branch must match the
    device-dependence of what the loop or the other branch produces."""
    seed = sum((jnp.zeros_like(jnp.ravel(x)[0], dtype=dtype) for x in like), jnp.zeros((), dtype))
    return jnp.broadcast_to(seed, shape)


def _forward_kernel(points, tx, rx, frequencies, rho, *, plan, amplitude, chunk):
    """S for one viewpoint: a scan over voxel chunks, each one real batched product
    [Xr; Xi]·[Yr; Yi]ᵀ per frequency ((F, 2M, K)·(F, 2N, K) → (F, 2M, 2N)), from whose blocks
    S = (XrYr - XiYi) + j(XrYi + XiYr).

    Plain JAX, so every transformation (jit, vmap, grad, linear_transpose) applies. The body is
    rematerialised (`jax.checkpoint`), so reverse mode and transposition recompute the phasors
    chunk by chunk instead of storing F·(n_tx + n_rx)·V of them.
    """
    real_dtype = jnp.finfo(rho.dtype).dtype
    chunk = chunk_length(leading(points), _per_term(chunk or default_chunk(), amplitude))
    n_tx, n_rx = tx.shape[0], rx.shape[0]

    def work(terms, p, tx, rx, frequencies, r):
        (coarse_t, fine_t), (coarse_r, fine_r) = _factors(
            p, tx, rx, plan, frequencies, terms, real_dtype, r
        )
        x = _stack_frequencies(coarse_t, fine_t, plan.n)
        y = _stack_frequencies(coarse_r, fine_r, plan.n)
        return jnp.einsum("fmk,fnk->fmn", x, y, precision=EXACT)

    @jax.checkpoint
    def partial_sum(p, r):
        return _by_chunk(amplitude, work, p, tx, rx, frequencies, r)

    def step(total, xs):
        return total + partial_sum(*xs), None

    zero = _zeros((plan.n, 2 * n_tx, 2 * n_rx), real_dtype, *jax.tree.leaves((tx, rx, rho)))
    total, _ = jax.lax.scan(step, zero, (_chunked(points, chunk), _chunked(rho, chunk, "constant")))
    re = total[:, :n_tx, :n_rx] - total[:, n_tx:, n_rx:]
    im = total[:, :n_tx, n_rx:] + total[:, n_tx:, :n_rx]
    return jax.lax.complex(re, im)


def _adjoint_kernel(points, tx, rx, frequencies, signal, *, plan, amplitude, chunk):
    """ρ̂_v = Σ_{f,m,n} conj(X[f,m,v] Y[f,n,v]) S[f,m,n], chunk by chunk: T = S·conj(Y) as
    one real batched product [[Sr, Si], [Si, -Sr]]·[Yr; Yi] = [Tr; Ti], then Σ_{f,m} conj(X)·T."""
    real_dtype = jnp.finfo(signal.dtype).dtype
    n = leading(points)
    chunk = chunk_length(n, _per_term(chunk or default_chunk(adjoint=True), amplitude))
    n_tx = tx.shape[0]
    sr, si = jnp.real(signal), jnp.imag(signal)
    mix = jnp.concatenate([jnp.concatenate([sr, si], 2), jnp.concatenate([si, -sr], 2)], 1)

    def work(terms, p, tx, rx, frequencies, mix):
        (coarse_t, fine_t), (coarse_r, fine_r) = _factors(
            p, tx, rx, plan, frequencies, terms, real_dtype
        )
        x = _stack_frequencies(coarse_t, fine_t, plan.n)
        y = _stack_frequencies(coarse_r, fine_r, plan.n)
        t = jnp.einsum("fij,fjk->fik", mix, y, precision=EXACT)
        xr, xi, tr, ti = x[:, :n_tx], x[:, n_tx:], t[:, :n_tx], t[:, n_tx:]
        re = jnp.sum(xr * tr + xi * ti, axis=(0, 1))
        im = jnp.sum(xr * ti - xi * tr, axis=(0, 1))
        n_terms = 1 if terms is None else len(terms)
        if n_terms > 1:  # each voxel's column per amplitude term (see `_factors`)
            re, im = re.reshape(n_terms, -1).sum(0), im.reshape(n_terms, -1).sum(0)
        return jax.lax.complex(re, im)

    def step(p):
        return _by_chunk(amplitude, work, p, tx, rx, frequencies, mix)

    return jax.lax.map(step, _chunked(points, chunk)).reshape(-1)[:n]


def forward_view(points, tx, rx, frequencies, rho, *, plan, amplitude, chunk, split=True):
    """`_forward_kernel` with the voxels split over the devices when that pays
    (`rift_jax._sharding.split_voxels`; never with ``split=False``)."""
    chunk = chunk or default_chunk()

    def local(points, rho, shared):
        return _forward_kernel(points, *shared, rho, plan=plan, amplitude=amplitude, chunk=chunk)

    shared = (tx, rx, frequencies)
    if not (split and split_voxels(leading(points), chunk, points, rho, shared)):
        return local(points, rho, shared)
    return over_voxels(local, points, rho, shared, reduce=True)


def adjoint_view(points, tx, rx, frequencies, signal, *, plan, amplitude, chunk, split=True):
    """`_adjoint_kernel` with the voxels split over the devices when that pays."""
    chunk = chunk or default_chunk(adjoint=True)

    def local(points, _, shared):
        return _adjoint_kernel(points, *shared, plan=plan, amplitude=amplitude, chunk=chunk)

    shared = (tx, rx, frequencies, signal)
    if not (split and split_voxels(leading(points), chunk, points, shared)):
        return local(points, None, shared)
    return over_voxels(local, points, None, shared, reduce=False)


# The public entry points, compiled once per shape and configuration: without this, a plain
# call traces and compiles the whole scan again every time (0.8 s against 0.04 s, measured).
# `split` is decided outside the jit (`_call`).
_STATIC = ("plan", "amplitude", "chunk", "split")
_forward_jit = jax.jit(forward_view, static_argnames=_STATIC)
_adjoint_jit = jax.jit(adjoint_view, static_argnames=_STATIC)


def _call(jitted, points, tx, rx, freqs, data, plan, amplitude, chunk):
    """A jitted entry point, with the voxel split decided here, outside the jit, where an
    input pinned to one device can still be seen (`rift_jax._sharding.pinned`)."""
    split = not pinned((points, tx, rx, freqs, data))
    return jitted(
        points, tx, rx, freqs, data, plan=plan, amplitude=amplitude, chunk=chunk, split=split
    )


def _complex_dtype(x) -> np.dtype:
    return jnp.result_type(x, jnp.complex64)


def _check_geometry(points, tx, rx) -> None:
    for name, arr in (("points", points), ("tx", tx), ("rx", rx)):
        shape = arr.shape if isinstance(arr, Float64Pair) else jnp.shape(arr)
        if len(shape) != 2 or shape[1] != 3 or shape[0] == 0:
            raise ValueError(f"`{name}` must have shape (n, 3) with n ≥ 1 (metres), got {shape}.")
        check_finite(arr, f"`{name}`")


# The bound assumed for geometry that cannot be read (traced): q ≤ 3e-3, antennas within
# ~0.1 of the nearest point's distance of each other (order 1: error ≤ 9e-6).
_TRACED_BOUND = 3e-3


def _amplitude(points, tx, rx, near_field, spreading) -> Amplitude:
    """The kernels' `Amplitude` for one view's geometry (host values, `Float64Pair`s or
    arrays), read from the antennas' largest separation and a lower bound on their
    distance to the points: from the antennas' centroid, less their spread around it
    (O(points + antennas) on the host, ~1 ms for the paper's radar on 26³ points)."""
    if not near_field:
        return Amplitude.of("far-field")
    if spreading != "paper":
        return Amplitude.of(spreading)
    if not is_concrete((points, tx, rx)):
        return Amplitude.unread(spreading)
    p, t, r = (host_float64(x) for x in (points, tx, rx))
    separation = float(np.max(np.linalg.norm(t[:, None] - r[None], axis=-1)))
    antennas = np.concatenate([t, r])
    centroid = antennas.mean(0)
    spread = float(np.max(np.linalg.norm(antennas - centroid, axis=1)))
    nearest = float(np.min(np.linalg.norm(p - centroid, axis=1))) - spread
    bound = amplitude_bound(separation, nearest)
    return Amplitude.of(spreading, bound, lambda: largest_q(p, [(t, r)]))


def _prepare(points, tx, rx, frequencies, chunk_size):
    _check_geometry(points, tx, rx)
    plan = frequency_plan(frequencies)
    if chunk_size is not None:
        check_positive_int("`chunk_size`", chunk_size)
    freqs = None if plan.uniform else as_geometry(frequencies)
    return (as_geometry(points), as_geometry(tx), as_geometry(rx), freqs), plan


def forward(
    points: Float[Array, "n_points 3"],
    reflectivity: Complex[Array, " n_points"],
    tx: Float[Array, "n_tx 3"],
    rx: Float[Array, "n_rx 3"],
    frequencies: Float[Array, " n_freq"],
    *,
    near_field: bool = True,
    spreading: str = "paper",
    chunk_size: int | None = None,
) -> Complex[Array, "n_freq n_tx n_rx"]:
    """The raw (un-normalised) GRT of one viewpoint:
    ``S[f, m, n] = Σ_v ρ_v exp(+j k_f R_b) / R_b²`` (``near_field=False``: no 1/R_b²).

    **Arguments:**

    - `points`: voxel positions (metres), shape (V, 3).
    - `reflectivity`: complex ρ at those points, shape (V,). Its precision sets the work's:
      complex64 by default (complex128 when x64 is enabled and ρ is complex128).
    - `tx`, `rx`: antenna positions (metres), e.g. from `antenna_positions`. Host (NumPy)
      inputs keep full float64 precision whether or not x64 is on; float32 device arrays and
      traced values are taken as they are. Geometry is always evaluated in float64.
    - `frequencies`: Hz, 1-D. A uniform grid known at trace time takes the fast ladder.
    - `near_field`: include the spreading factor (``False``: amplitude 1, the far field).
    - `spreading`: the near field's law: "paper", 1/R_b² with R_b = r_t + r_r (the paper's
      F_NF), or "radar-equation", 1/(r_t r_r). The paper's law is separated into as many
      terms as this geometry needs for `AMPLITUDE_TOLERANCE` (one for antennas a few
      centimetres apart, ~10 m away). Traced geometry cannot be read: it gets three terms,
      exact to 1e-5 while the antennas stay within ~0.1 of the nearest point's distance of
      each other.
    - `chunk_size`: voxels per scan step (memory/speed trade-off; results do not depend on it).

    **Returns:** complex S of shape (n_freq, n_tx, n_rx).

    Linear in ρ and plain JAX: jit, vmap, grad and `jax.linear_transpose` all apply (the
    transpose equals `adjoint`, conjugated). Not meant to be differentiated in the geometry.
    """
    geometry, plan = _prepare(points, tx, rx, frequencies, chunk_size)
    amplitude = _amplitude(points, tx, rx, near_field, spreading)  # read before any staging
    (points, tx, rx, freqs) = geometry
    reflectivity = jnp.asarray(reflectivity)
    if reflectivity.shape != (leading(points),):
        raise ValueError(
            f"`reflectivity` must have shape ({leading(points)},) to match `points`, got "
            f"{reflectivity.shape}."
        )
    check_finite(reflectivity, "`reflectivity`")
    reflectivity = reflectivity.astype(_complex_dtype(reflectivity))
    return _call(_forward_jit, points, tx, rx, freqs, reflectivity, plan, amplitude, chunk_size)


def adjoint(
    points: Float[Array, "n_points 3"],
    signal: Complex[Array, "n_freq n_tx n_rx"],
    tx: Float[Array, "n_tx 3"],
    rx: Float[Array, "n_rx 3"],
    frequencies: Float[Array, " n_freq"],
    *,
    near_field: bool = True,
    spreading: str = "paper",
    chunk_size: int | None = None,
) -> Complex[Array, " n_points"]:
    """Backprojection: the exact conjugate transpose of `forward` in ρ,
    ``ρ̂_v = Σ_{f,m,n} conj(exp(j k_f R_b) A) S[f, m, n]``, so that
    ``<forward(ρ), S> = <ρ, adjoint(S)>``. Arguments as for `forward`."""
    geometry, plan = _prepare(points, tx, rx, frequencies, chunk_size)
    amplitude = _amplitude(points, tx, rx, near_field, spreading)  # read before any staging
    (points, tx, rx, freqs) = geometry
    signal = jnp.asarray(signal)
    expected = (plan.n, tx.shape[0], rx.shape[0])
    if signal.shape != expected:
        raise ValueError(
            f"`signal` must have shape {expected} (n_freq, n_tx, n_rx), got {signal.shape}."
        )
    check_finite(signal, "`signal`")
    signal = signal.astype(_complex_dtype(signal))
    return _call(_adjoint_jit, points, tx, rx, freqs, signal, plan, amplitude, chunk_size)
