"""Pure GRT kernels for one viewpoint (paper Eq. 1 and Appendix Eqs. 12-13).

    S[f, m, n] = Σ_v ρ_v · exp(+j k_f R_v,mn) · A_v,mn,    R_v,mn = |x_v - tx_m| + |x_v - rx_n|,

with k_f = 2π f / c0, A = 1/R² in the near field and A = 1 in the far field.

Why it is computed the way it is (NOTES.md, "Numbers measured"):

- **float64 geometry.** k·R reaches 10⁴-10⁵ rad, so a float32 distance (ulp ≈ 1e-6 m at
  10 m) puts 10⁻³ rad of phase error on every term. Distances and phases are computed in
  float64 (only (n_tx + n_rx)·V distances and ~20 phases each per view), reduced mod 2π, and
  only then cast to float32: all the heavy work stays complex64 and accurate to ~1e-6.
- **Separable exponential.** exp(j k (r_t + r_r)) = exp(j k r_t) · exp(j k r_r), so for each
  frequency S_f = X_f · Y_fᵀ with X_f[m, v] = ρ_v a_vm exp(j k_f r_vm): a batch of small complex
  matrix products, 100·n_tx·n_rx·V multiply-adds per view.
- **Separable amplitude.** 1/(r_t + r_r)² = 1/(4 r_t r_r) · 1/(1 + q), q = (r_t - r_r)²/(4 r_t r_r).
  The array spans 2.3 cm, so q ≤ 2.7e-6 for a voxel 10 m away (1.5e-4 at the 10 m scene's
  nearest corner, 1.3 m from the array); measured relative error of S for random scenes is
  ~1e-6. The kernel uses 1/(4 r_t r_r) = (1/2r_t)(1/2r_r).
- **Frequency ladder.** On a uniform grid f = f_0 + (aB + b)Δf, so exp(j k_f r) =
  exp(j k_{aB} r) · exp(j b Δk r): B + ⌈F/B⌉ ≈ 2√F phase evaluations per distance instead of F.
  Each factor is exact to float32 rounding; their product to ~2 ulp. Non-uniform frequency
  grids (or frequencies that are traced) take the direct path: F phases per distance.
- **Voxel chunks.** Voxels are processed ``chunk_size`` at a time in a ``lax.scan``, so memory
  is O(F·(n_tx + n_rx)·chunk) whatever V is.

``adjoint`` is the exact conjugate transpose of ``forward``: the same phasors, conjugated,
contracted in the other order. Autodiff through ``forward`` gives the same numbers (tested).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from ._geometry import C0
from ._validation import check_finite, is_concrete

_TWO_PI = 2.0 * math.pi
DEFAULT_CHUNK = 2048
"""Voxels per scan step: large enough to amortise each small matrix product's overhead, small
enough that one chunk's phasors (2·F·16·chunk complex64 ≈ 50 MB at 2048) stay in L3."""


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


def _cis(wavenumber, r: Array, real_dtype) -> Array:
    """exp(j k r) with the phase k·r formed and reduced mod 2π in float64 (floor-based: XLA's
    fmod is a scalar libm call, ~5x slower), then evaluated in ``real_dtype``."""
    phase = jnp.asarray(wavenumber, jnp.float64) * r
    phase = phase - _TWO_PI * jnp.floor(phase * (1.0 / _TWO_PI))
    phase = phase.astype(real_dtype)
    return jax.lax.complex(jnp.cos(phase), jnp.sin(phase))


def _ladder_sizes(n: int) -> tuple[int, int]:
    """(n_coarse, n_fine) with n_coarse · n_fine ≥ n and n_coarse + n_fine smallest (≈ 2√n)."""
    n_fine = math.isqrt(n - 1) + 1 if n > 1 else 1
    return -(-n // n_fine), n_fine


def _phasor_factors(
    r: Float[Array, "a v"], amplitude: Array, plan: FrequencyPlan, frequencies, real_dtype
) -> tuple[Complex[Array, "c a v"], Complex[Array, "b a v"]]:
    """Two factors whose outer product over their leading axes gives, for frequency
    f = i·B + j, ``amplitude · exp(j k_f r) = coarse[i] · fine[j]``. ``r`` is float64.

    Uniform grid: three float64-reduced phasors per distance, exp(j k_0 r), exp(j Δk r) and
    exp(j B Δk r); the fine powers exp(j b Δk r), b < B, and the coarse steps exp(j k_{aB} r)
    are running products of these (≤ B - 1 and ≤ A - 1 complex roundings: worst case ~2√F ulp
    of phase error, 1.2e-6 rad for F = 100). Otherwise: coarse holds every frequency, fine is 1.
    """
    if not plan.uniform:
        k = _TWO_PI / C0 * jnp.asarray(frequencies, jnp.float64)
        coarse = _cis(k.reshape((-1,) + (1,) * r.ndim), r, real_dtype) * amplitude
        return coarse, jnp.ones((1,) + r.shape, coarse.dtype)
    n_coarse, n_fine = _ladder_sizes(plan.n)
    k0 = _TWO_PI / C0 * plan.f0
    dk = _TWO_PI / C0 * plan.df
    base = _cis(k0, r, real_dtype) * amplitude  # the amplitude rides on the short factor
    step = _cis(dk, r, real_dtype)
    big_step = _cis(dk * n_fine, r, real_dtype)
    # Materialise each stage: left to itself, XLA fuses the running products (and the sines
    # and cosines under them) into every element of the outer product and recomputes them.
    base, step, big_step = jax.lax.optimization_barrier((base, step, big_step))
    fine = [jnp.ones_like(step)]
    for _ in range(n_fine - 1):
        fine.append(fine[-1] * step)
    coarse = [base]
    for _ in range(n_coarse - 1):
        coarse.append(coarse[-1] * big_step)
    return jax.lax.optimization_barrier((jnp.stack(coarse), jnp.stack(fine)))


def _ladder(coarse: Array, fine: Array, n: int) -> Complex[Array, "f a v"]:
    """All frequencies from the two factors: [coarse[i] · fine[j] for i, j] (first ``n``)."""
    out = coarse[:, None] * fine[None, :]
    return out.reshape((-1,) + coarse.shape[1:])[:n]


def _distances(points: Array, antennas: Array) -> Float[Array, "a v"]:
    """|x_v - antenna_a| in float64 (call inside ``jax.enable_x64``)."""
    d = points.astype(jnp.float64)[None, :, :] - antennas.astype(jnp.float64)[:, None, :]
    return jnp.sqrt(jnp.sum(d * d, axis=-1))


def _factors(points, tx, rx, plan, frequencies, near_field, dtype):
    """Phasor factors for one voxel chunk, TX side and RX side; they do not depend on ρ."""
    real_dtype = jnp.finfo(dtype).dtype
    with jax.enable_x64(True):
        r_t = _distances(points, tx)
        r_r = _distances(points, rx)
        if near_field:  # 1/R_b² ≈ (1/2r_t)(1/2r_r), see the module docstring
            a_t = (0.5 / r_t).astype(real_dtype).astype(dtype)
            a_r = (0.5 / r_r).astype(real_dtype).astype(dtype)
        else:
            a_t = a_r = jnp.ones((), dtype)
        tx_side = _phasor_factors(r_t, a_t, plan, frequencies, real_dtype)
        rx_side = _phasor_factors(r_r, a_r, plan, frequencies, real_dtype)
    return tuple(x.astype(dtype) for x in tx_side), tuple(y.astype(dtype) for y in rx_side)


def _chunked(x: Array, chunk: int) -> Array:
    """Split the leading (voxel) axis into chunks of ``chunk``, zero-padding the last one
    (padded points sit at the origin and carry ρ = 0)."""
    n_chunks = -(-x.shape[0] // chunk)
    x = jnp.pad(x, ((0, n_chunks * chunk - x.shape[0]),) + ((0, 0),) * (x.ndim - 1))
    return x.reshape((n_chunks, chunk) + x.shape[1:])


def chunk_length(n_points: int, chunk_size: int) -> int:
    """The chunk actually used: at most ``chunk_size``, with the points spread evenly over the
    chunks (rounded up to a multiple of 8), so padding stays small: 4,169 voxels at
    chunk_size 2,048 give 3 chunks of 1,392, not 3 of 2,048."""
    n_chunks = -(-n_points // chunk_size)
    per_chunk = -(-n_points // n_chunks)
    return min(chunk_size, -(-per_chunk // 8) * 8)


def _forward_kernel(points, tx, rx, frequencies, rho, *, plan, near_field, chunk):
    """S for one viewpoint: a scan over voxel chunks, each a batch of F small products.

    Plain JAX, so every transformation (jit, vmap, grad, linear_transpose) applies; the body
    is rematerialised (`jax.checkpoint`), so reverse mode and transposition recompute the
    phasors chunk by chunk instead of storing F·(n_tx + n_rx)·V of them.
    """
    dtype = rho.dtype
    chunk = chunk_length(points.shape[0], chunk)

    @jax.checkpoint
    def step(p, r):
        (ct, ft), (cr, fr) = _factors(p, tx, rx, plan, frequencies, near_field, dtype)
        x = _ladder(ct * r, ft, plan.n)  # ρ enters linearly, after the barriers
        y = _ladder(cr, fr, plan.n)
        return jnp.einsum("fmv,fnv->fmn", x, y)

    # Per-chunk results are summed after the scan (no carry): the kernel then maps cleanly
    # over devices in `shard_map` and over viewpoints in `vmap`.
    parts = jax.lax.map(lambda pr: step(*pr), (_chunked(points, chunk), _chunked(rho, chunk)))
    return jnp.sum(parts, axis=0)


def _adjoint_kernel(points, tx, rx, frequencies, signal, *, plan, near_field, chunk):
    """ρ̂ = Σ_{f,m,n} conj(X[f,m,v] Y[f,n,v]) S[f,m,n], chunk by chunk: first the RX side
    as a batch of small products, then the TX side as a reduction."""
    dtype = signal.dtype
    n = points.shape[0]
    chunk = chunk_length(n, chunk)

    def step(p):
        (ct, ft), (cr, fr) = _factors(p, tx, rx, plan, frequencies, near_field, dtype)
        t = jnp.einsum("fmn,fnv->fmv", signal, jnp.conj(_ladder(cr, fr, plan.n)))
        return jnp.sum(jnp.conj(_ladder(ct, ft, plan.n)) * t, axis=(0, 1))

    return jax.lax.map(step, _chunked(points, chunk)).reshape(-1)[:n]


def _complex_dtype(x) -> np.dtype:
    return jnp.result_type(x, jnp.complex64)


def _check_geometry(points, tx, rx) -> None:
    for name, arr in (("points", points), ("tx", tx), ("rx", rx)):
        shape = jnp.shape(arr)
        if len(shape) != 2 or shape[1] != 3 or shape[0] == 0:
            raise ValueError(f"`{name}` must have shape (n, 3) with n ≥ 1 (metres), got {shape}.")
        check_finite(arr, f"`{name}`")


def _host_float64(x):
    """Host values (NumPy, lists) stay float64 (converted inside the x64 block); traced or
    device arrays keep their dtype. Positions and frequencies need every bit: k·R ~ 10⁵ rad."""
    if isinstance(x, np.ndarray | list | tuple):
        with jax.enable_x64(True):
            return jnp.asarray(x, jnp.float64)
    return jnp.asarray(x)


def _prepare(points, tx, rx, frequencies, chunk_size):
    _check_geometry(points, tx, rx)
    plan = frequency_plan(frequencies)
    if not isinstance(chunk_size, int) or chunk_size < 1:
        raise ValueError(f"`chunk_size` must be a positive integer, got {chunk_size!r}.")
    freqs = None if plan.uniform else _host_float64(frequencies)
    return (_host_float64(points), _host_float64(tx), _host_float64(rx), freqs), plan


def forward(
    points: Float[Array, "n_points 3"],
    reflectivity: Complex[Array, " n_points"],
    tx: Float[Array, "n_tx 3"],
    rx: Float[Array, "n_rx 3"],
    frequencies: Float[Array, " n_freq"],
    *,
    near_field: bool = True,
    chunk_size: int = DEFAULT_CHUNK,
) -> Complex[Array, "n_freq n_tx n_rx"]:
    """The raw (un-normalised) GRT of one viewpoint:
    ``S[f, m, n] = Σ_v ρ_v exp(+j k_f R_b) / R_b²`` (``near_field=False``: no 1/R_b²).

    **Arguments:**

    - `points`: voxel positions (metres), shape (V, 3).
    - `reflectivity`: complex ρ at those points, shape (V,). Its precision sets the work's:
      complex64 by default (complex128 when x64 is enabled and ρ is complex128).
    - `tx`, `rx`: antenna positions (metres), e.g. from `antenna_positions`. NumPy float64
      inputs are used at full precision; geometry is always evaluated in float64.
    - `frequencies`: Hz, 1-D. A uniform grid known at trace time takes the fast ladder.
    - `near_field`: include the 1/R_b² spreading factor.
    - `chunk_size`: voxels per scan step (memory/speed trade-off; results do not depend on it).

    **Returns:** complex S of shape (n_freq, n_tx, n_rx).

    Linear in ρ and plain JAX: jit, vmap, grad and `jax.linear_transpose` all apply (the
    transpose equals `adjoint`, conjugated). Not meant to be differentiated in the geometry.
    """
    (points, tx, rx, freqs), plan = _prepare(points, tx, rx, frequencies, chunk_size)
    reflectivity = jnp.asarray(reflectivity)
    if reflectivity.shape != (points.shape[0],):
        raise ValueError(
            f"`reflectivity` must have shape ({points.shape[0]},) to match `points`, got "
            f"{reflectivity.shape}."
        )
    check_finite(reflectivity, "`reflectivity`")
    reflectivity = reflectivity.astype(_complex_dtype(reflectivity))
    return _forward_kernel(
        points, tx, rx, freqs, reflectivity, plan=plan, near_field=near_field, chunk=chunk_size
    )


def adjoint(
    points: Float[Array, "n_points 3"],
    signal: Complex[Array, "n_freq n_tx n_rx"],
    tx: Float[Array, "n_tx 3"],
    rx: Float[Array, "n_rx 3"],
    frequencies: Float[Array, " n_freq"],
    *,
    near_field: bool = True,
    chunk_size: int = DEFAULT_CHUNK,
) -> Complex[Array, " n_points"]:
    """Backprojection: the exact conjugate transpose of `forward` in ρ,
    ``ρ̂_v = Σ_{f,m,n} conj(exp(j k_f R_b) A) S[f, m, n]``, so that
    ``<forward(ρ), S> = <ρ, adjoint(S)>``. Arguments as for `forward`."""
    (points, tx, rx, freqs), plan = _prepare(points, tx, rx, frequencies, chunk_size)
    signal = jnp.asarray(signal)
    expected = (plan.n, tx.shape[0], rx.shape[0])
    if signal.shape != expected:
        raise ValueError(
            f"`signal` must have shape {expected} (n_freq, n_tx, n_rx), got {signal.shape}."
        )
    check_finite(signal, "`signal`")
    signal = signal.astype(_complex_dtype(signal))
    return _adjoint_kernel(
        points, tx, rx, freqs, signal, plan=plan, near_field=near_field, chunk=chunk_size
    )
