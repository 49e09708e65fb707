"""Radar data: synthesising the signals a scene returns at given viewpoints."""

from __future__ import annotations

import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from ._geometry import Radar, Viewpoints
from ._operator import grt_operator
from ._padding import ladder_size
from ._scenes import Scene, grid_axis
from ._sharding import gathered
from ._validation import as_finite_array, check_instance, check_positive


class RadarData(eqx.Module):
    """Signals of a set of viewpoints, normalised so that max |signal| = 1 over the dataset
    (paper Section 3.1); ``signal * scale`` is the raw GRT output.

    **Fields:**

    - `signal`: complex64 (n_views, n_freq, n_tx, n_rx).
    - `scale`: ``signal * scale`` is the raw (noisy, if noise was added) GRT output.
    - `viewpoints`, `radar`: where and how it was measured.
    - `snr_db`: the SNR of the added noise, or None for clean data.
    """

    signal: Complex[Array, "n_views n_freq n_tx n_rx"]
    scale: float = eqx.field(static=True)
    viewpoints: Viewpoints = eqx.field(static=True)
    radar: Radar = eqx.field(static=True)
    snr_db: float | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        expected = (len(self.viewpoints), *self.radar.signal_shape)
        if self.signal.shape != expected:
            raise ValueError(
                f"RadarData: `signal` must have shape {expected} (n_views, n_freq, n_tx, n_rx) "
                f"for {len(self.viewpoints)} viewpoints and this radar, got {self.signal.shape}."
            )


class PointScatterers(eqx.Module):
    """Point scatterers anywhere in the cube ``±extent``: a truth that no grid holds.

    A `Scene` puts its scatterers on grid points; these sit wherever ``points`` says, so
    `synthesize` (and `fit`, `FitResult.evaluate`) sum the GRT over them exactly, and only
    `resample` puts them on a grid, for the image metrics.

    **Fields:**

    - `points`: float64 (k, 3) positions (m), each inside ``±extent``; kept on the host in
      float64, as the GRT needs (a phase k·R of 10⁴ rad is wrong by 10⁻³ rad in float32).
    - `reflectivity`: complex64 (k,) amplitudes.
    - `extent`: half-width of the box (m): the grid a reconstruction uses spans it.
    """

    points: Float[np.ndarray, "k 3"]
    reflectivity: Complex[Array, " k"]
    extent: float = eqx.field(static=True)

    def __init__(self, points, reflectivity, extent: float):
        check_positive("PointScatterers: `extent`", extent)
        points = as_finite_array(points, "PointScatterers: `points`", np.float64)
        rho = as_finite_array(reflectivity, "PointScatterers: `reflectivity`", np.complex64)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
            raise ValueError(
                f"PointScatterers: `points` must have shape (k, 3) with k ≥ 1, got {points.shape}."
            )
        if rho.shape != (len(points),):
            raise ValueError(
                f"PointScatterers: `reflectivity` must have shape ({len(points)},), one value "
                f"per point, got {rho.shape}."
            )
        if (outside := np.abs(points).max()) > extent * (1 + 1e-9):
            raise ValueError(
                f"PointScatterers: every point must lie inside ±`extent` ({extent} m); one "
                f"lies {outside:.4g} m from the centre along an axis."
            )
        self.points, self.reflectivity, self.extent = points, jnp.asarray(rho), float(extent)

    def occupied(self) -> tuple[Float[np.ndarray, "k 3"], Complex[np.ndarray, " k"]]:
        """Points and reflectivity of the non-zero scatterers (as `Scene.occupied`)."""
        rho = np.asarray(self.reflectivity)
        keep = np.flatnonzero(rho)
        return self.points[keep], rho[keep]

    def resample(self, granularity: float) -> Scene:
        """The scatterers on the grid of ``granularity`` over ``±extent``, for the image
        metrics: each amplitude is spread trilinearly onto the 8 grid points around it
        (weights ∏(1 − |x − xᵢ|/g) over the axes, summing to 1; a point on a grid point
        lands on it alone). This is the adjoint of trilinear interpolation, so the total
        reflectivity is kept and the result moves continuously with the points. A point
        beyond the outermost grid plane (when 2·extent is no multiple of ``granularity``)
        is spread as if it lay on it."""
        axis = grid_axis(self.extent, granularity)
        n = len(axis)
        position = np.clip((self.points - axis[0]) / granularity, 0, n - 1)
        low = np.minimum(np.floor(position).astype(np.int64), n - 2)
        frac = position - low
        frac = np.where(np.abs(frac) < 1e-9, 0.0, np.where(np.abs(frac - 1) < 1e-9, 1.0, frac))
        rho = np.zeros((n, n, n), np.complex128)
        amplitude = np.asarray(self.reflectivity, np.complex128)
        for corner in itertools.product((0, 1), repeat=3):
            weight = np.prod(np.where(corner, frac, 1 - frac), axis=1)
            np.add.at(rho, tuple((low + corner).T), weight * amplitude)
        return Scene(jnp.asarray(rho, jnp.complex64), self.extent, float(granularity))


SYNTHESIS_SIZES_PER_OCTAVE = 8  # at most 1/8 more points than the scene occupies


def synthesize(
    scene: Scene | PointScatterers,
    viewpoints: Viewpoints,
    radar: Radar | None = None,
    *,
    snr_db: float | None = None,
    seed: int = 0,
) -> RadarData:
    """The signals ``scene`` returns at ``viewpoints``, normalised to max |S| = 1.

    Only the scene's non-zero voxels enter the sum: empty space contributes nothing, and a
    paper scene occupies 1-10 % of its grid. With ``snr_db``, circular complex Gaussian noise
    of power ``mean|S|² / 10^(snr_db/10)`` is added (seeded by ``seed``) before normalising.

    **Arguments:**

    - `scene`: a `Scene` (its grid is the forward grid), or `PointScatterers` (the GRT
      summed over their exact positions).
    - `viewpoints`: a `Viewpoints`.
    - `radar`: a `Radar`; default `Radar()` (the paper's).
    - `snr_db`: signal-to-noise ratio in dB, or None for clean data.
    - `seed`: noise seed.

    **Returns:** a `RadarData`.
    """
    radar = Radar() if radar is None else radar
    if not isinstance(scene, Scene | PointScatterers):
        raise ValueError(
            "synthesize: `scene` must be a rift_jax.Scene or rift_jax.PointScatterers, got "
            f"{type(scene).__name__}."
        )
    check_instance("synthesize: `radar`", radar, Radar, "a rift_jax.Radar")
    check_instance("synthesize: `viewpoints`", viewpoints, Viewpoints, "rift_jax.Viewpoints")
    if snr_db is not None and not (
        isinstance(snr_db, int | float | np.integer | np.floating) and np.isfinite(snr_db)
    ):
        raise ValueError(f"synthesize: `snr_db` must be a finite number or None, got {snr_db!r}.")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):  # JAX's keys take any int
        raise ValueError(f"synthesize: `seed` must be an integer, got {seed!r}.")
    points, rho = scene.occupied()
    if rho.size == 0:
        raise ValueError(
            "synthesize: `scene` has no non-zero voxels or scatterers, so its signal is zero."
        )
    # every scene (and every reconstruction `FitResult.predict` renders) occupies its own
    # number of points: padded with ρ = 0 to a shared size, scenes of about the same size
    # share one compiled forward (the sum is the same, up to float32 rounding)
    size = ladder_size(len(rho), SYNTHESIS_SIZES_PER_OCTAVE)
    operator = grt_operator(radar, viewpoints, points, pad_to=size)
    rho = np.pad(np.asarray(rho, np.complex64), (0, size - len(rho)))
    # jitted (compiles once per shape); gathered here when the views span several processes
    raw = gathered(operator.mv(jnp.asarray(rho)))
    scale = float(jnp.max(jnp.abs(raw)))
    signal = raw / scale
    if snr_db is not None:
        power = jnp.mean(jnp.abs(signal) ** 2) / 10 ** (snr_db / 10)
        key_re, key_im = jax.random.split(jax.random.key(seed))
        noise = jax.random.normal(key_re, signal.shape) + 1j * jax.random.normal(
            key_im, signal.shape
        )
        noisy = signal + jnp.sqrt(power / 2) * noise.astype(jnp.complex64)
        peak = float(jnp.max(jnp.abs(noisy)))
        signal, scale = noisy / peak, scale * peak
    return RadarData(signal.astype(jnp.complex64), scale, viewpoints, radar, snr_db)
