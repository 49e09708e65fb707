"""A fast, approximate backprojection |Aᴴy| for screening: per-view polar tables.

The exact adjoint (`GRT.adjoint`) costs n_freq · n_tx · n_rx complex multiply-adds per
point and view (25,600 for the paper's radar). Standard SAR practice makes the frequencies
nearly free by range compression, and a small array makes its antenna pairs nearly free by
beamforming; together, each view's backprojection becomes a table that every point reads
in O(1).

**The expansion.** Each arm of the paper's L-array is a line of elements at offsets s_m
(metres) along a unit vector u from the arm's centre c. For a point x at r₀ = |x − c| with
direction d̂ = (x − c)/r₀,

    r_m = |x − c − s_m u| = r₀ − s_m α + O(s_m² / 2r₀),       α = u · d̂,

and likewise r_n = r₀' − s_n β on the RX arm. With k_f = k_c + κ_f (k_c a middle
frequency's wavenumber) and R₀ = r₀ + r₀', one view's backprojection is

    Σ_{f,m,n} S[f,m,n] A e^{−j k_f (r_m + r_n)}
        ≈ A(x) · e^{−j k_c R₀} · E(R₀, α, β),
    E(R, α, β) = Σ_f e^{−j κ_f R} · Σ_{m,n} e^{+j k_f s_m α} S[f,m,n] e^{+j k_f s_n β},

with A = 1/(4 r₀ r₀') in the near field (1 in the far field). E holds no carrier: it is
smooth on the scale of the range resolution (c/B, 3 cm of R₀ for the paper's radar) and of
the array's beam (~0.13 in α and β), and periodic in R with period 2π/Δk (the frequency
step's unambiguous range). So it is tabulated once per view, on [0, 2π/Δk) × [−1, 1]²,
oversampled ``OVERSAMPLE`` times beyond Nyquist in each axis: the inner double sum is two
small matrix products per frequency, the outer sum one FFT per (α, β) bin. Each point then
reads E by trilinear interpolation (8 samples) and multiplies by the exact carrier, whose
phase k_c R₀ ~ 10⁴ rad is formed in float64 as in the exact kernel (`rift_jax.grt`).

**Cost and error** (`python -m benchmarks.support --target` prints both for the cube; the
paper's radar, 100 views, 51³ points): ~1.5 s against ~60 s for the exact adjoint, at a
relative (vector) error of ~5 %, mostly the trilinear interpolation's loss at peaks. (The
dropped O(s²/2r₀) term is ≤ 0.012 rad of phase at 10 m and ≤ 0.1 rad at the 10 m scene's
corner nearest an antenna.) That is too coarse to reconstruct with, and ample to *screen*:
`estimate_support` evaluates the exact adjoint only where this one comes within a margin of
the threshold.

Applies to the paper's L with uniform frequencies (`Radar.is_paper_array`), at any poses;
other radars are screened by the exact adjoint (`rift_jax._support`).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from ._geometry import C0, Radar, Viewpoints, antennas_at
from ._grt import EXACT, _cis, _distances, _zeros
from ._precision import split, to_float64
from ._sharding import gathered, over_views

OVERSAMPLE = 4  # samples per Nyquist interval, each axis: ~5 % error, measured (see above)
_CHUNK = 8192  # points per lookup step: the step's temporaries stay ~1 MB per array


def _tables(radar: Radar) -> tuple[int, int]:
    """(range samples, direction-cosine samples) of a view's table."""
    k_max = 2 * math.pi * radar.f_max / C0
    half_arm = 0.5 * radar.spacing * (max(radar.n_tx, radar.n_rx) - 1)
    # E's spectrum in α reaches k_max · (largest offset): Nyquist step π / that over [−1, 1]
    n_angles = math.ceil(2 * k_max * half_arm * OVERSAMPLE / math.pi) + 1
    return OVERSAMPLE * radar.n_frequencies, max(n_angles, 2)


def fast_backprojection(
    signal: Complex[Array, "n_views n_freq n_tx n_rx"],
    viewpoints: Viewpoints,
    points: Float[Array, "n_points 3"],
    radar: Radar,
) -> Complex[Array, " n_points"]:
    """Σ over ``viewpoints`` of the backprojection of ``signal`` onto ``points``, ≈ Aᴴy
    within ~5 % (see the module's docstring), in ~1/40 of the exact adjoint's time at the
    paper's scale. For screening, not reconstruction.

    **Arguments:** `signal` (n_views, n_freq, n_tx, n_rx), `viewpoints` (its rows),
    `points` (n, 3) metres, `radar` (its frequencies uniform; inputs checked by the caller).

    **Returns:** complex64 (n,), in the exact adjoint's units.
    """
    if not radar.is_paper_array:
        raise ValueError(
            "fast_backprojection: `radar` must be the paper's L with uniform frequencies "
            "(Radar.is_paper_array); screen other radars with the exact adjoint."
        )
    n_range, n_angles = _tables(radar)
    f = radar.frequencies
    k = 2 * math.pi * f / C0
    centre = (len(f) - 1) // 2
    dk = k[1] - k[0] if len(f) > 1 else 0.0
    # host constants, float64 then cast: per-frequency steering over each arm
    offsets = [radar.spacing * (np.arange(n) + 0.5 - n / 2) for n in (radar.n_tx, radar.n_rx)]
    cosines = np.linspace(-1.0, 1.0, n_angles)
    steer = [
        np.exp(1j * k[:, None, None] * cosines[None, :, None] * s[None, None, :]) for s in offsets
    ]
    # e^{−j κ_f R} at R_j = j·period/n_range is e^{+j 2π·centre·j/n} times the FFT's kernel
    j = np.arange(n_range)
    recentre = np.exp(2j * math.pi * ((centre * j) % n_range) / n_range)
    constants = tuple(jnp.asarray(c, jnp.complex64) for c in (*steer, recentre))
    n = len(points)
    padded = -(-n // _CHUNK) * _CHUNK
    out = _backproject(
        *(split(x) for x in viewpoints.poses(radar)),
        jnp.asarray(signal, jnp.complex64),
        split(np.pad(np.asarray(points, np.float64), ((0, padded - n), (0, 0)))),
        constants,
        radar=radar,
        n_range=n_range,
        n_angles=n_angles,
        wavenumbers=(float(k[centre]), float(dk)),
    )
    return gathered(out)[:n]


@functools.partial(jax.jit, static_argnames=("radar", "n_range", "n_angles", "wavenumbers"))
def _backproject(
    positions, orientations, signal, points, constants, *, radar, n_range, n_angles, wavenumbers
):
    steer_t, steer_r, recentre = constants
    k_c, dk = wavenumbers
    # R₀ in table samples: one period 2π/Δk spans the n_range samples (no range axis at F = 1)
    per_metre = n_range * dk / (2 * math.pi)
    chunks = jax.tree.map(lambda a: a.reshape(-1, _CHUNK, 3), points)

    def table(s):
        g = jnp.einsum("fam,fmn,fbn->fab", steer_t, s, steer_r, precision=EXACT)
        e = jnp.fft.fft(g, n=n_range, axis=0) * recentre[:, None, None]
        return jnp.concatenate([e, e[:1]]).reshape(-1)  # a wrapped row: i + 1 never wraps

    def arm(antennas):
        """(centre, unit direction) of a linear arm, float64. One element has no direction
        (zeros: α = 0, where its one-element steering is 1 anyway)."""
        middle = jnp.mean(antennas, axis=0)
        if antennas.shape[0] == 1:
            return middle, jnp.zeros(3, antennas.dtype)
        along = antennas[-1] - antennas[0]
        return middle, along / jnp.linalg.norm(along)

    def lookup(values, chunk, arms):
        (c_t, u_t), (c_r, u_r) = arms
        with jax.enable_x64(True):
            x = to_float64(chunk)
            r_t, r_r = _distances(chunk, c_t[None])[0], _distances(chunk, c_r[None])[0]
            # elementwise, as `_distances`: a size-3 contraction is no matrix product
            alpha = jnp.sum((x - c_t) * u_t, axis=1) / r_t
            beta = jnp.sum((x - c_r) * u_r, axis=1) / r_r
            along = jnp.mod((r_t + r_r) * per_metre, n_range).astype(jnp.float32)
            carrier = _cis(k_c, r_t + r_r, jnp.float32)
            amplitude = 1.0
            if radar.near_field:  # the kernels' one-term amplitude (`rift_jax.grt`)
                scale = 0.25 if radar.spreading == "paper" else 1.0
                amplitude = (scale / (r_t * r_r)).astype(jnp.float32)
            scale = 0.5 * (n_angles - 1)
            a, b = (((c + 1) * scale).astype(jnp.float32) for c in (alpha, beta))
        corners = []
        for u, top in ((along, n_range - 1), (a, n_angles - 2), (b, n_angles - 2)):
            low = jnp.clip(jnp.floor(u), 0, top)
            corners.append((low.astype(jnp.int32), u - low))
        (i, ti), (ia, ta), (ib, tb) = corners
        total = jnp.zeros(i.shape, jnp.complex64)
        for di in (0, 1):
            for da in (0, 1):
                for db in (0, 1):
                    w = (ti if di else 1 - ti) * (ta if da else 1 - ta) * (tb if db else 1 - tb)
                    total += values[((i + di) * n_angles + ia + da) * n_angles + ib + db] * w
        return total * jax.lax.complex(carrier[0], -carrier[1]) * amplitude

    def local(positions, orientations, signal):
        def one_view(total, view):
            position, orientation, s = view
            with jax.enable_x64(True):
                antennas = antennas_at(radar, to_float64(position), to_float64(orientation))
                arms = tuple(map(arm, antennas))
            values = table(s)
            image = jax.lax.map(lambda chunk: lookup(values, chunk, arms), chunks)
            return total + image.reshape(-1), None

        zero = _zeros((chunks.hi.shape[0] * _CHUNK,), jnp.complex64, positions.hi, signal)
        return jax.lax.scan(one_view, zero, (positions, orientations, signal))[0]

    return over_views(local, positions, orientations, signal, reduce=True)
