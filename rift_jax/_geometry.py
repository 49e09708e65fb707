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

SPREADING_LAWS = ("paper", "radar-equation")


def _antenna_layout(positions, where: str) -> tuple[tuple[float, float, float], ...]:
    """(n, 3) antenna positions (metres, finite, n ≥ 1) as a tuple of triples: a `Radar` is
    static in compiled programs, so what it holds must be hashable."""
    array = as_finite_array(positions, where, np.float64)
    if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] == 0:
        raise ValueError(f"{where} must have shape (n, 3) with n ≥ 1 (metres), got {array.shape}.")
    return tuple(tuple(float(v) for v in row) for row in array)


@dataclasses.dataclass(frozen=True)
class Radar:
    """A MIMO radar: its antennas in the radar's own frame and its frequencies.

    By default the paper's: an L-shaped array of ``n_tx`` transmitters and ``n_rx``
    receivers, ``n_frequencies`` uniform frequencies on ``[f_min, f_max]`` (endpoints
    included). Any other radar (an irregular MIMO layout, one antenna for a monostatic SAR,
    non-uniform frequencies) comes from `Radar.from_antennas`.

    **The radar's frame.** Its origin is the viewpoint (the array's reference point), its z
    axis looks at the scene, its x axis is the paper's TX arm (the world's +z, projected
    across the line of sight) and y = z × x its RX arm. The paper's TX element m sits at
    ``s (m + 1/2)`` on x, RX element n at ``s (n + 1/2)`` on y (paper Eqs. 9-11).

    **Arguments:**

    - `n_frequencies`, `f_min`, `f_max`: the frequency grid (Hz).
    - `n_tx`, `n_rx`: antennas on each arm of the L.
    - `spacing`: element spacing (m); `None` gives c0 / (2 f_max) = 1.4276 mm, the paper's
      value and the authors' code's (the paper's formula, from f_min, would give 1.578 mm;
      docs/conventions.md, 'Geometry').
    - `distance`: radius of the sphere of viewpoints given by angles (m); 10 m in the paper,
      50 m in the weak-target study. Viewpoints given as poses (`Viewpoints.from_poses`)
      carry their own positions.
    - `near_field`: keep the spreading factor (paper F_NF) or drop it (F_FF).
    - `spreading`: the near field's spreading factor: "paper", 1/(r_t + r_r)², or
      "radar-equation", the bistatic radar equation's 1/(r_t r_r).
    - `tx_offsets`, `rx_offsets`, `frequency_list`: set by `Radar.from_antennas` (None:
      the paper's L and uniform grid).
    """

    n_frequencies: int = 100
    f_min: float = 95e9
    f_max: float = 105e9
    n_tx: int = 16
    n_rx: int = 16
    spacing: float | None = None
    distance: float = 10.0
    near_field: bool = True
    spreading: str = "paper"
    tx_offsets: tuple[tuple[float, float, float], ...] | None = None
    rx_offsets: tuple[tuple[float, float, float], ...] | None = None
    frequency_list: tuple[float, ...] | None = None

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
        if self.spreading not in SPREADING_LAWS:
            raise ValueError(
                f"Radar: `spreading` must be one of {SPREADING_LAWS}, got {self.spreading!r}."
            )
        spacing = C0 / (2.0 * self.f_max) if self.spacing is None else self.spacing
        check_positive("Radar: `spacing`", spacing)
        object.__setattr__(self, "spacing", float(spacing))
        for name, count in (("tx_offsets", self.n_tx), ("rx_offsets", self.n_rx)):
            offsets = getattr(self, name)
            if offsets is not None:
                offsets = _antenna_layout(offsets, f"Radar: `{name}`")
                if len(offsets) != count:
                    raise ValueError(
                        f"Radar: `{name}` holds {len(offsets)} antennas, but "
                        f"`{name[:2]}` count is {count}."
                    )
                object.__setattr__(self, name, offsets)
        if self.frequency_list is not None:
            f = as_finite_array(self.frequency_list, "Radar: `frequency_list`", np.float64)
            if f.shape != (self.n_frequencies,) or np.any(f <= 0):
                raise ValueError(
                    f"Radar: `frequency_list` must hold {self.n_frequencies} positive "
                    f"frequencies (Hz), got shape {f.shape}."
                )
            if not np.isclose(f.min(), self.f_min) or not np.isclose(f.max(), self.f_max):
                raise ValueError("Radar: `f_min` and `f_max` must be `frequency_list`'s range.")
            object.__setattr__(self, "frequency_list", tuple(float(x) for x in f))

    @classmethod
    def from_antennas(
        cls,
        tx,
        rx,
        frequencies,
        *,
        distance: float = 10.0,
        near_field: bool = True,
        spreading: str = "paper",
    ) -> Radar:
        """Any radar: antenna positions in the radar's frame (see `Radar`) and frequencies.

        **Arguments:**

        - `tx`, `rx`: (n_tx, 3) and (n_rx, 3) positions (metres) in the radar's frame, any
          layout: TX and RX may coincide (monostatic) or stand apart (bistatic).
        - `frequencies`: Hz, 1-D, any order and spacing (a uniform grid takes the GRT's
          fast frequency ladder, others one phasor per frequency).
        - `distance`, `near_field`, `spreading`: as for `Radar`.

        **Returns:** a `Radar` whose `tx_offsets`, `rx_offsets` and `frequencies` are these.
        """
        tx = _antenna_layout(tx, "Radar.from_antennas: `tx`")
        rx = _antenna_layout(rx, "Radar.from_antennas: `rx`")
        f = as_finite_array(frequencies, "Radar.from_antennas: `frequencies`", np.float64)
        if f.ndim != 1 or f.size == 0 or np.any(f <= 0):
            raise ValueError(
                "Radar.from_antennas: `frequencies` must be a non-empty 1-D array of positive "
                f"frequencies (Hz), got shape {f.shape}."
            )
        f_min, f_max = float(f.min()), float(f.max())
        if f.size > 1 and f_max == f_min:
            raise ValueError("Radar.from_antennas: `frequencies` must not all be equal.")
        return cls(
            n_frequencies=f.size,
            f_min=f_min,
            f_max=f_max,
            n_tx=len(tx),
            n_rx=len(rx),
            distance=distance,
            near_field=near_field,
            spreading=spreading,
            tx_offsets=tx,
            rx_offsets=rx,
            frequency_list=tuple(float(x) for x in f),
        )

    def __repr__(self) -> str:
        if self.is_paper_array:  # the dataclass's own form, without the empty layout
            names = [f.name for f in dataclasses.fields(self)][:9]
            return f"Radar({', '.join(f'{n}={getattr(self, n)!r}' for n in names)})"
        f = self.frequencies
        return (
            f"Radar.from_antennas({self.n_tx} TX, {self.n_rx} RX, {self.n_frequencies} "
            f"frequencies on [{f.min():g}, {f.max():g}] Hz, distance={self.distance!r}, "
            f"near_field={self.near_field!r}, spreading={self.spreading!r})"
        )

    @property
    def is_paper_array(self) -> bool:
        """Whether this is the paper's L with uniform frequencies (the layout that the fast
        support screen, `rift_jax._backprojection`, is written for)."""
        return self.tx_offsets is None and self.rx_offsets is None and self.frequency_list is None

    @property
    def offsets(self) -> tuple[np.ndarray, np.ndarray]:
        """TX and RX positions in the radar's frame, (n_tx, 3) and (n_rx, 3) metres."""
        out = []
        for given, count, axis in (
            (self.tx_offsets, self.n_tx, 0),
            (self.rx_offsets, self.n_rx, 1),
        ):
            if given is not None:
                out.append(np.asarray(given, np.float64))
                continue
            arm = np.zeros((count, 3))
            arm[:, axis] = self.spacing * (np.arange(count, dtype=np.float64) + 0.5)
            out.append(arm)
        return out[0], out[1]

    @property
    def separation(self) -> float:
        """The largest distance between a TX and an RX antenna (m): with the nearest
        point's distance, it bounds how far the GRT's amplitude is from separable."""
        tx, rx = self.offsets
        return float(np.max(np.linalg.norm(tx[:, None] - rx[None], axis=-1)))

    @property
    def frequencies(self) -> np.ndarray:
        """The frequencies (Hz), float64: `frequency_list`, or uniform with endpoints
        included."""
        if self.frequency_list is not None:
            return np.asarray(self.frequency_list, np.float64)
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
    """Where the radar looks from, one pose (a position and an orientation) per viewpoint.

    The paper's: array centres at ``Radar.distance`` from the origin in the directions
    ``(azimuth, polar)`` (radians, float64, host arrays), looking at the origin
    (`Viewpoints.grid`, or the angles themselves). Any other poses (a SAR track, a radar on
    a moving platform, a radar looking elsewhere than the origin) come from
    `Viewpoints.from_poses`; their ``azimuth`` and ``polar`` are then the positions'
    directions from the origin.

    Index or slice like a sequence (``vps[3]``, ``vps[:10]``, ``vps.subset(idx)``).
    """

    azimuth: np.ndarray
    polar: np.ndarray
    positions: np.ndarray | None = None
    orientations: np.ndarray | None = None

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
        if (self.positions is None) != (self.orientations is None):
            raise ValueError("Viewpoints: give both `positions` and `orientations`, or neither.")
        if self.positions is not None:
            n = azimuth.size
            positions = as_finite_array(self.positions, "Viewpoints: `positions`", np.float64)
            frames = as_finite_array(self.orientations, "Viewpoints: `orientations`", np.float64)
            if positions.shape != (n, 3) or frames.shape != (n, 3, 3):
                raise ValueError(
                    f"Viewpoints: `positions` and `orientations` must have shapes ({n}, 3) and "
                    f"({n}, 3, 3), got {positions.shape} and {frames.shape}."
                )
            _check_rotations(frames, "Viewpoints: `orientations`")
            for name, array in (("positions", positions), ("orientations", frames)):
                array.setflags(write=False)
                object.__setattr__(self, name, array)
        azimuth.setflags(write=False)
        polar.setflags(write=False)
        object.__setattr__(self, "azimuth", azimuth)
        object.__setattr__(self, "polar", polar)

    @classmethod
    def from_poses(
        cls, positions, *, look_at=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), orientations=None
    ):
        """Viewpoints at any ``positions`` (n, 3) metres: a SAR track, a platform's path.

        **Arguments:**

        - `positions`: (n, 3) where the radar's frame has its origin (see `Radar`), metres.
        - `look_at`: the point (3,) or points (n, 3) each viewpoint looks at (its z axis);
          the scene's centre, the origin, by default.
        - `up`: the world direction (3,) that the radar's x axis leans to (its projection
          across the line of sight). The paper's sphere of viewpoints is the default's.
        - `orientations`: (n, 3, 3) rotations whose columns are the radar's x, y and z axes
          in the world; given, `look_at` and `up` are not used.

        **Returns:** `Viewpoints` with these poses.
        """
        where = "Viewpoints.from_poses"
        positions = np.atleast_2d(as_finite_array(positions, f"{where}: `positions`", np.float64))
        if positions.ndim != 2 or positions.shape[1] != 3 or positions.shape[0] == 0:
            raise ValueError(
                f"{where}: `positions` must have shape (n, 3) with n ≥ 1, got {positions.shape}."
            )
        radius = np.linalg.norm(positions, axis=1)
        if np.any(radius == 0):
            raise ValueError(
                f"{where}: `positions` must not sit at the scene's centre, the origin."
            )
        if orientations is None:
            orientations = _look_at(positions, look_at, up, where)
        polar = np.arccos(np.clip(positions[:, 2] / radius, -1.0, 1.0))
        azimuth = np.arctan2(positions[:, 1], positions[:, 0])
        return cls(azimuth, polar, positions, orientations)

    def poses(self, radar: Radar) -> tuple[np.ndarray, np.ndarray]:
        """Each viewpoint's position (n, 3) and orientation (n, 3, 3; columns: the radar's
        x, y and z axes in the world), float64: as given, or on the sphere of radius
        ``radar.distance``, looking at the origin."""
        if self.positions is not None:
            return np.asarray(self.positions), np.asarray(self.orientations)
        return _sphere_poses(radar.distance, self.azimuth, self.polar, np)

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
        if self.positions is None:
            return Viewpoints(np.atleast_1d(self.azimuth[index]), np.atleast_1d(self.polar[index]))
        return Viewpoints(
            np.atleast_1d(self.azimuth[index]),
            np.atleast_1d(self.polar[index]),
            self.positions[index].reshape(-1, 3),
            self.orientations[index].reshape(-1, 3, 3),
        )

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
        kind = "" if self.positions is None else ", poses"
        return f"Viewpoints(n={len(self)}{kind})"


def spread(n: int, k: int) -> np.ndarray:
    """The sorted indices of ``min(k, n)`` viewpoints spread evenly over ``range(n)`` (their
    order): a sample of views that covers the angles the whole set covers."""
    return np.unique(np.linspace(0, n - 1, min(k, n)).round()).astype(np.int64)


def antenna_positions(
    radar: Radar, azimuth: float | Float[Array, ""], polar: float | Float[Array, ""]
) -> tuple[Float[Array, "n_tx 3"], Float[Array, "n_rx 3"]]:
    """Positions (metres, float64) of the TX and RX elements for one viewpoint on the
    sphere of radius ``radar.distance``.

    The array centre is ``c = r [sin p cos a, sin p sin a, cos p]`` (p polar, a azimuth);
    the radar's x axis is ``u_t = [-cos p cos a, -cos p sin a, sin p]``, its y axis
    ``u_r = [-sin a, cos a, 0]``, its z axis u_t × u_r = -c/r: with the paper's L, TX element
    m sits at ``c + s (m + 1/2) u_t`` and RX element n at ``c + s (n + 1/2) u_r``, a one-sided
    L starting at c, both arms perpendicular to c (paper Eqs. 9-11).

    Computed in float64 (phases k·R reach 10⁴-10⁵ rad, so positions must be exact to well
    below a micrometre). Concrete angles give NumPy float64 arrays (usable whether or not
    x64 is on); traced angles (jit, vmap) give float64 JAX values inside the trace.
    """
    if is_concrete((azimuth, polar)):
        position, frame = _sphere_poses(radar.distance, np.float64(azimuth), np.float64(polar), np)
        return antennas_at(radar, position, frame)
    with jax.enable_x64(True):
        azimuth, polar = jnp.asarray(azimuth, jnp.float64), jnp.asarray(polar, jnp.float64)
        position, frame = _sphere_poses(radar.distance, azimuth, polar, jnp)
        return antennas_at(radar, position, frame)


def antennas_at(radar: Radar, position, orientation):
    """TX and RX positions (metres, float64) for one pose: ``position + R · offset`` for
    each of the radar's antennas (`Radar.offsets`), R = ``orientation`` (columns: the
    radar's axes). NumPy arrays give NumPy; JAX arrays (float64, inside
    ``jax.enable_x64``) give JAX.

    Written elementwise over the three axes, skipping those on which no antenna sits: the
    paper's arms lie on one axis each, so its positions are c + s (m + 1/2) u exactly, and
    XLA gets no size-3 contraction (see `rift_jax.grt`)."""
    xp = np if isinstance(orientation, np.ndarray) else jnp
    out = []
    for offsets in radar.offsets:
        total = position
        for k in range(3):
            if np.any(offsets[:, k]):
                total = total + offsets[:, k, None] * orientation[..., :, k]
        out.append(xp.broadcast_to(total, offsets.shape))
    return out[0], out[1]


def every_view_antennas(radar: Radar, viewpoints: Viewpoints) -> tuple[np.ndarray, np.ndarray]:
    """Every view's TX and RX positions, (n_views, n_tx | n_rx, 3) metres, float64 NumPy
    (`antennas_at` for each of ``viewpoints.poses``)."""
    pairs = [antennas_at(radar, *pose) for pose in zip(*viewpoints.poses(radar), strict=True)]
    return np.stack([tx for tx, _ in pairs]), np.stack([rx for _, rx in pairs])


def _sphere_poses(distance: float, a, p, xp):
    """Position(s) and orientation(s) on the sphere, looking at the origin, for NumPy (host)
    or jax.numpy (traced, inside x64) as ``xp``; scalar or 1-D angles."""
    sa, ca, sp, cp = xp.sin(a), xp.cos(a), xp.sin(p), xp.cos(p)
    centre = distance * xp.stack([sp * ca, sp * sa, cp], axis=-1)
    u_t = xp.stack([-cp * ca, -cp * sa, sp], axis=-1)
    u_r = xp.stack([-sa, ca, xp.zeros_like(a)], axis=-1)
    return centre, xp.stack([u_t, u_r, xp.cross(u_t, u_r)], axis=-1)


def _look_at(positions: np.ndarray, look_at, up, where: str) -> np.ndarray:
    """Orientations (n, 3, 3) whose z axes point from ``positions`` to ``look_at`` and whose
    x axes lean to ``up``."""
    target = as_finite_array(look_at, f"{where}: `look_at`", np.float64)
    up = as_finite_array(up, f"{where}: `up`", np.float64)
    if target.shape not in ((3,), positions.shape) or up.shape != (3,):
        raise ValueError(
            f"{where}: `look_at` must have shape (3,) or {positions.shape}, and `up` (3,); got "
            f"{target.shape} and {up.shape}."
        )
    z = target - positions
    length = np.linalg.norm(z, axis=1, keepdims=True)
    if np.any(length == 0):
        raise ValueError(f"{where}: a viewpoint looks at its own position (`look_at`).")
    z = z / length
    x = up - (z @ up)[:, None] * z
    norm = np.linalg.norm(x, axis=1, keepdims=True)
    if np.any(norm < 1e-9 * np.linalg.norm(up)) or not np.any(up):
        raise ValueError(
            f"{where}: `up` {tuple(up)} is along the line of sight of viewpoint(s) "
            f"{np.flatnonzero(norm[:, 0] < 1e-9 * np.linalg.norm(up))[:5].tolist()}: give "
            "another `up`, or `orientations`."
        )
    x = x / norm
    return np.stack([x, np.cross(z, x), z], axis=-1)


def _check_rotations(frames: np.ndarray, where: str) -> None:
    gram = np.einsum("nij,nik->njk", frames, frames)
    if not np.allclose(gram, np.eye(3), atol=1e-9) or np.any(np.linalg.det(frames) < 0):
        raise ValueError(
            f"{where} must be rotations (orthonormal columns, determinant +1), within 1e-9."
        )
