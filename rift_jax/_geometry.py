"""Radar geometry: the radar's configuration, the viewpoints it looks from, and where its
antennas are (paper Appendix "Radar Setup", resolved as in docs/conventions.md, 'Geometry').

Angles: the paper calls the polar angle (from +z) "azimuth" and the azimuth "elevation";
here they are named for what they are, ``polar`` ∈ [0, π] and ``azimuth`` ∈ [-2π, 2π].
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._validation import as_finite_array, check_positive, check_positive_int, is_concrete

C0 = 299_792_458.0
"""Speed of light in vacuum (m/s)."""


@dataclasses.dataclass(frozen=True)
class Radar:
    """A bistatic MIMO radar: an L-shaped array of ``n_tx`` transmitters and ``n_rx``
    receivers, ``n_frequencies`` uniform frequencies on ``[f_min, f_max]`` (endpoints
    included), the array centre at ``distance`` metres from the scene centre.

    **Arguments:**

    - `n_frequencies`, `f_min`, `f_max`: the frequency grid (Hz).
    - `n_tx`, `n_rx`: antennas on each arm of the L.
    - `spacing`: element spacing (m); `None` gives c0 / (2 f_max) = 1.4276 mm, the paper's
      value and the authors' code's (the paper's formula, from f_min, would give 1.578 mm;
      docs/conventions.md, 'Geometry').
    - `distance`: radius of the sphere of viewpoints (m); 10 m in the paper, 50 m in the
      weak-target study.
    - `near_field`: keep the 1/R_b² spreading factor (paper F_NF) or drop it (F_FF).
    """

    n_frequencies: int = 100
    f_min: float = 95e9
    f_max: float = 105e9
    n_tx: int = 16
    n_rx: int = 16
    spacing: float | None = None
    distance: float = 10.0
    near_field: bool = True

    def __post_init__(self):
        for name in ("n_frequencies", "n_tx", "n_rx"):
            check_positive_int(f"Radar: `{name}`", getattr(self, name))
        check_positive("Radar: `f_min`", self.f_min)
        check_positive("Radar: `f_max`", self.f_max)
        if self.f_max < self.f_min or (self.n_frequencies > 1 and self.f_max == self.f_min):
            raise ValueError(
                f"Radar: need `f_max` > `f_min` for {self.n_frequencies} frequencies, got "
                f"f_min={self.f_min!r}, f_max={self.f_max!r}."
            )
        check_positive("Radar: `distance`", self.distance)
        if not isinstance(self.near_field, bool | np.bool_):  # a string would read as True
            raise ValueError(f"Radar: `near_field` must be True or False, got {self.near_field!r}.")
        spacing = C0 / (2.0 * self.f_max) if self.spacing is None else self.spacing
        check_positive("Radar: `spacing`", spacing)
        object.__setattr__(self, "spacing", float(spacing))

    @property
    def frequencies(self) -> np.ndarray:
        """The frequencies (Hz), float64, uniform with endpoints included."""
        return np.linspace(self.f_min, self.f_max, self.n_frequencies)

    @property
    def signal_shape(self) -> tuple[int, int, int]:
        """Shape of one viewpoint's signal: ``(n_frequencies, n_tx, n_rx)``."""
        return (self.n_frequencies, self.n_tx, self.n_rx)


def _check_angles(azimuth: np.ndarray, polar: np.ndarray, where: str) -> None:
    tol = 1e-9
    if np.any(np.abs(azimuth) > 2 * np.pi + tol):
        raise ValueError(
            f"{where}: `azimuth` must be in radians within [-2π, 2π]; got values up to "
            f"{np.abs(azimuth).max():.4g} (degrees?)."
        )
    if np.any(polar < -tol) or np.any(polar > np.pi + tol):
        raise ValueError(
            f"{where}: `polar` (angle from +z) must be in radians within [0, π]; got "
            f"[{polar.min():.4g}, {polar.max():.4g}]."
        )


@dataclasses.dataclass(frozen=True, eq=False)
class Viewpoints:
    """Where the radar looks from: array centres at ``Radar.distance`` from the origin, in
    the directions ``(azimuth, polar)`` (radians, float64, host arrays).

    Index or slice like a sequence (``vps[3]``, ``vps[:10]``, ``vps.subset(idx)``).
    """

    azimuth: np.ndarray
    polar: np.ndarray

    def __post_init__(self):
        azimuth = as_finite_array(self.azimuth, "Viewpoints: `azimuth`", np.float64)
        polar = as_finite_array(self.polar, "Viewpoints: `polar`", np.float64)
        azimuth, polar = np.atleast_1d(azimuth), np.atleast_1d(polar)
        if azimuth.ndim != 1 or azimuth.shape != polar.shape:
            raise ValueError(
                "Viewpoints: `azimuth` and `polar` must be 1-D arrays of the same length, got "
                f"shapes {azimuth.shape} and {polar.shape}."
            )
        if azimuth.size == 0:
            raise ValueError(
                "Viewpoints: `azimuth` and `polar` must hold at least one viewpoint, got none."
            )
        _check_angles(azimuth, polar, "Viewpoints")
        azimuth.setflags(write=False)
        polar.setflags(write=False)
        object.__setattr__(self, "azimuth", azimuth)
        object.__setattr__(self, "polar", polar)

    @classmethod
    def grid(
        cls,
        n_azimuth: int = 51,
        n_polar: int = 51,
        azimuth_range: tuple[float, float] = (0.0, 2 * math.pi),
        polar_range: tuple[float, float] = (0.0, math.pi),
    ) -> Viewpoints:
        """The paper's viewpoint grid: ``n_azimuth × n_polar`` uniform samples (endpoints
        included, as ``np.linspace``), azimuth-major. Defaults give the paper's 2,601."""
        for name, n in (("n_azimuth", n_azimuth), ("n_polar", n_polar)):
            check_positive_int(f"Viewpoints.grid: `{name}`", n)
        for name, pair in (("azimuth_range", azimuth_range), ("polar_range", polar_range)):
            if as_finite_array(pair, f"Viewpoints.grid: `{name}`").shape != (2,):
                raise ValueError(f"Viewpoints.grid: `{name}` must be (first, last), got {pair!r}.")
        az = np.linspace(*azimuth_range, n_azimuth)
        pol = np.linspace(*polar_range, n_polar)
        az, pol = np.meshgrid(az, pol, indexing="ij")
        return cls(az.ravel(), pol.ravel())

    def __len__(self) -> int:
        return self.azimuth.shape[0]

    def __getitem__(self, index) -> Viewpoints:
        return Viewpoints(np.atleast_1d(self.azimuth[index]), np.atleast_1d(self.polar[index]))

    def subset(self, index: Sequence[int] | np.ndarray) -> Viewpoints:
        """The viewpoints at integer positions (or a boolean mask) ``index``."""
        index = np.asarray(index)
        if index.size == 0 or not (index.dtype == bool or np.issubdtype(index.dtype, np.integer)):
            raise ValueError(
                "Viewpoints.subset: `index` must be integer positions or a boolean mask that "
                f"selects at least one viewpoint, got {index.size} value(s) of dtype {index.dtype}."
            )
        if (
            index.dtype != bool
            and index.size
            and (index.min() < -len(self) or index.max() >= len(self))
        ):
            raise ValueError(f"Viewpoints.subset: `index` out of range for {len(self)} viewpoints.")
        return self[index]

    def split(self, n_train: int, n_test: int, seed: int = 0) -> tuple[Viewpoints, Viewpoints]:
        """A seeded random draw of ``n_train`` training and ``n_test`` disjoint test
        viewpoints from these (sampling without replacement)."""
        for name, n in (("n_train", n_train), ("n_test", n_test)):
            # a Viewpoints holds at least one viewpoint, so neither draw may be empty
            check_positive_int(f"Viewpoints.split: `{name}`", n)
        if n_train + n_test > len(self):
            raise ValueError(
                f"Viewpoints.split: `n_train` + `n_test` = {n_train + n_test} exceeds the "
                f"{len(self)} viewpoints available."
            )
        order = np.random.default_rng(seed).permutation(len(self))
        return self.subset(np.sort(order[:n_train])), self.subset(
            np.sort(order[n_train : n_train + n_test])
        )

    def __repr__(self) -> str:
        return f"Viewpoints(n={len(self)})"


def spread(n: int, k: int) -> np.ndarray:
    """The sorted indices of ``min(k, n)`` viewpoints spread evenly over ``range(n)`` (their
    order): a sample of views that covers the angles the whole set covers."""
    return np.unique(np.linspace(0, n - 1, min(k, n)).round()).astype(np.int64)


def antenna_positions(
    radar: Radar, azimuth: float | Float[Array, ""], polar: float | Float[Array, ""]
) -> tuple[Float[Array, "n_tx 3"], Float[Array, "n_rx 3"]]:
    """Positions (metres, float64) of the TX and RX elements for one viewpoint.

    The array centre is ``c = r [sin p cos a, sin p sin a, cos p]`` (p polar, a azimuth);
    TX element m sits at ``c + s (m + 1/2) u_t`` with ``u_t = [-cos p cos a, -cos p sin a,
    sin p]``, RX element n at ``c + s (n + 1/2) u_r`` with ``u_r = [-sin a, cos a, 0]``:
    a one-sided L starting at c, both arms perpendicular to c (paper Eqs. 9-11).

    Computed in float64 (phases k·R reach 10⁴-10⁵ rad, so positions must be exact to well
    below a micrometre). Concrete angles give NumPy float64 arrays (usable whether or not
    x64 is on); traced angles (jit, vmap) give float64 JAX values inside the trace.
    """
    if is_concrete((azimuth, polar)):
        return _antenna_positions(radar, np.float64(azimuth), np.float64(polar), np)
    with jax.enable_x64(True):
        azimuth, polar = jnp.asarray(azimuth, jnp.float64), jnp.asarray(polar, jnp.float64)
        return _antenna_positions(radar, azimuth, polar, jnp)


def _antenna_positions(radar: Radar, a, p, xp):
    """The geometry once, for NumPy (host) or jax.numpy (traced, inside x64) as ``xp``."""
    sa, ca, sp, cp = xp.sin(a), xp.cos(a), xp.sin(p), xp.cos(p)
    centre = radar.distance * xp.stack([sp * ca, sp * sa, cp])
    u_t = xp.stack([-cp * ca, -cp * sa, sp])
    u_r = xp.stack([-sa, ca, xp.zeros_like(a)])
    m = radar.spacing * (xp.arange(radar.n_tx, dtype=xp.float64) + 0.5)
    n = radar.spacing * (xp.arange(radar.n_rx, dtype=xp.float64) + 0.5)
    return centre + m[:, None] * u_t, centre + n[:, None] * u_r
