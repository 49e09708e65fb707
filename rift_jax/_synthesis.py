"""Radar data: synthesising the signals a scene returns at given viewpoints."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex

from ._geometry import Radar, Viewpoints
from ._operator import grt_operator
from ._scenes import Scene
from ._sharding import gathered


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


def synthesize(
    scene: Scene,
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

    - `scene`: a `Scene` (its grid is the forward grid).
    - `viewpoints`: a `Viewpoints`.
    - `radar`: a `Radar`; default `Radar()` (the paper's).
    - `snr_db`: signal-to-noise ratio in dB, or None for clean data.
    - `seed`: noise seed.

    **Returns:** a `RadarData`.
    """
    radar = Radar() if radar is None else radar
    if not isinstance(scene, Scene):
        raise ValueError(
            f"synthesize: `scene` must be a rift_jax.Scene, got {type(scene).__name__}."
        )
    if not isinstance(radar, Radar):
        raise ValueError(
            f"synthesize: `radar` must be a rift_jax.Radar, got {type(radar).__name__}."
        )
    if not isinstance(viewpoints, Viewpoints):
        raise ValueError(
            "synthesize: `viewpoints` must be rift_jax.Viewpoints, got "
            f"{type(viewpoints).__name__}."
        )
    if snr_db is not None and not (
        isinstance(snr_db, int | float | np.integer | np.floating) and np.isfinite(snr_db)
    ):
        raise ValueError(f"synthesize: `snr_db` must be a finite number or None, got {snr_db!r}.")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):  # JAX's keys take any int
        raise ValueError(f"synthesize: `seed` must be an integer, got {seed!r}.")
    points, rho = scene.occupied()
    if rho.size == 0:
        raise ValueError("synthesize: `scene` has no non-zero voxels, so its signal is zero.")
    operator = grt_operator(radar, viewpoints, points)
    # jitted (compiles once per shape); gathered here when the views span several processes
    raw = gathered(operator.mv(jnp.asarray(rho, jnp.complex64)))
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
