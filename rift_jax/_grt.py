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

``forward`` and ``adjoint`` are exact transposes of each other (the adjoint uses the same
phasors, conjugated); each is registered as the other's transpose, so ``jax.grad`` and
``jax.linear_transpose`` through either use the hand-written kernel.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import linear_call
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


def _weighted_phasors(
    r: Float[Array, "a v"], weight: Array, plan: FrequencyPlan, frequencies, real_dtype
) -> Complex[Array, "f a v"]:
    """weight[a, v] · exp(j k_f r[a, v]) for every frequency; ``r`` is float64.

    Uniform grid: three float64-reduced phasors per distance, exp(j k_0 r), exp(j Δk r) and
    exp(j B Δk r); the fine powers exp(j b Δk r), b < B, and coarse steps exp(j k_{aB} r) are
    running products of these (≤ B - 1 and ≤ A - 1 complex roundings: worst case ~2√F ulp of
    phase error, 1.2e-6 rad for F = 100), and each frequency is one coarse × fine product.
    """
    if not plan.uniform:
        k = _TWO_PI / C0 * jnp.asarray(frequencies, jnp.float64)
        return _cis(k.reshape((-1,) + (1,) * r.ndim), r, real_dtype) * weight
    n_coarse, n_fine = _ladder_sizes(plan.n)
    k0 = _TWO_PI / C0 * plan.f0
    dk = _TWO_PI / C0 * plan.df
    base = _cis(k0, r, real_dtype) * weight  # the weight rides on the short factor
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
    coarse, fine = jax.lax.optimization_barrier((jnp.stack(coarse), jnp.stack(fine)))
    ladder = coarse[:, None] * fine[None, :]
    return ladder.reshape((n_coarse * n_fine,) + r.shape)[: plan.n]


def _distances(points: Array, antennas: Array) -> Float[Array, "a v"]:
    """|x_v - antenna_a| in float64 (call inside ``jax.enable_x64``)."""
    d = points.astype(jnp.float64)[None, :, :] - antennas.astype(jnp.float64)[:, None, :]
    return jnp.sqrt(jnp.sum(d * d, axis=-1))


def _fields(points, tx, rx, rho_weight, plan, frequencies, near_field, dtype):
    """The two factors of S for one voxel chunk: X[f, m, v] (carrying ``rho_weight`` if given)
    and Y[f, n, v], so that S_f = Σ_v X[f, :, v] Y[f, :, v]ᵀ."""
    real_dtype = jnp.finfo(dtype).dtype
    with jax.enable_x64(True):
        r_t = _distances(points, tx)
        r_r = _distances(points, rx)
        if near_field:  # 1/R_b² ≈ (1/2r_t)(1/2r_r), see the module docstring
            w_t = (0.5 / r_t).astype(real_dtype)
            w_r = (0.5 / r_r).astype(real_dtype)
        else:
            w_t = jnp.ones(r_t.shape, real_dtype)
            w_r = jnp.ones(r_r.shape, real_dtype)
        if rho_weight is not None:
            w_t = w_t * rho_weight[None, :]
        x = _weighted_phasors(r_t, w_t.astype(dtype), plan, frequencies, real_dtype)
        y = _weighted_phasors(r_r, w_r.astype(dtype), plan, frequencies, real_dtype)
    return x.astype(dtype), y.astype(dtype)


def _chunked(points: Array, chunk: int) -> tuple[Array, int]:
    """Pad the voxel axis to a multiple of ``chunk`` (padding at the origin, weight zero)."""
    n = points.shape[0]
    n_chunks = max(1, -(-n // chunk))
    pad = n_chunks * chunk - n
    return jnp.pad(points, ((0, pad),) + ((0, 0),) * (points.ndim - 1)), n_chunks


def _forward_kernel(points, tx, rx, frequencies, rho, *, plan, near_field, chunk):
    dtype = rho.dtype
    n = points.shape[0]
    chunk = min(chunk, n)
    pts, n_chunks = _chunked(points, chunk)
    rho_c, _ = _chunked(rho, chunk)
    pts = pts.reshape(n_chunks, chunk, 3)
    rho_c = rho_c.reshape(n_chunks, chunk)

    def step(acc, xs):
        p, r = xs
        x, y = _fields(p, tx, rx, r, plan, frequencies, near_field, dtype)
        return acc + jnp.einsum("fmv,fnv->fmn", x, y), None

    zero = jnp.zeros((plan.n, tx.shape[0], rx.shape[0]), dtype)
    out, _ = jax.lax.scan(step, zero, (pts, rho_c))
    return out


def _adjoint_kernel(points, tx, rx, frequencies, signal, *, plan, near_field, chunk):
    dtype = signal.dtype
    n = points.shape[0]
    chunk = min(chunk, n)
    pts, n_chunks = _chunked(points, chunk)
    pts = pts.reshape(n_chunks, chunk, 3)

    def step(_, p):
        x, y = _fields(p, tx, rx, None, plan, frequencies, near_field, dtype)
        t = jnp.einsum("fmn,fnv->fmv", signal, jnp.conj(y))
        return None, jnp.sum(jnp.conj(x) * t, axis=(0, 1))

    _, out = jax.lax.scan(step, None, pts)
    return out.reshape(-1)[:n]


def _complex_dtype(x) -> np.dtype:
    return jnp.result_type(x, jnp.complex64)


def _check_geometry(points, tx, rx) -> None:
    for name, arr in (("points", points), ("tx", tx), ("rx", rx)):
        shape = jnp.shape(arr)
        if len(shape) != 2 or shape[1] != 3 or shape[0] == 0:
            raise ValueError(f"`{name}` must have shape (n, 3) with n ≥ 1 (metres), got {shape}.")
        check_finite(arr, f"`{name}`")


def _as_position(x):
    """Keep float64 host positions at full precision (converted inside the x64 block)."""
    if isinstance(x, np.ndarray | list | tuple):
        with jax.enable_x64(True):
            return jnp.asarray(x, jnp.float64)
    return jnp.asarray(x)


def _prepare(points, tx, rx, frequencies, chunk_size):
    _check_geometry(points, tx, rx)
    plan = frequency_plan(frequencies)
    if not isinstance(chunk_size, int) or chunk_size < 1:
        raise ValueError(f"`chunk_size` must be a positive integer, got {chunk_size!r}.")
    freqs = None if plan.uniform else jnp.asarray(frequencies)
    return (_as_position(points), _as_position(tx), _as_position(rx), freqs), plan


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

    Linear in ρ; `jax.grad`/`jax.linear_transpose` use `adjoint`. Not differentiable with
    respect to the geometry.
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
    kw = dict(plan=plan, near_field=near_field, chunk=chunk_size)

    def fwd(res, rho):
        return _forward_kernel(*res, rho, **kw)

    def transpose(res, cotangent):  # Aᵀ y = conj(Aᴴ conj(y))
        return jnp.conj(_adjoint_kernel(*res, jnp.conj(cotangent), **kw))

    return linear_call(fwd, transpose, (points, tx, rx, freqs), reflectivity)


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
        raise ValueError(f"`signal` must have shape {expected} (n_freq, n_tx, n_rx), got {signal.shape}.")
    check_finite(signal, "`signal`")
    signal = signal.astype(_complex_dtype(signal))
    kw = dict(plan=plan, near_field=near_field, chunk=chunk_size)

    def adj(res, s):
        return _adjoint_kernel(*res, s, **kw)

    def transpose(res, cotangent):  # (Aᴴ)ᵀ y = conj(A conj(y))
        return jnp.conj(_forward_kernel(*res, jnp.conj(cotangent), **kw))

    return linear_call(adj, transpose, (points, tx, rx, freqs), signal)
