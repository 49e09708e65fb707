"""Support: the grid points a reconstruction may use; ρ = 0 everywhere else.

The paper's scenes fill 1-4 % of their box, yet every GRT call pays for every voxel. On a
support, the operator is simply `grt_operator` on fewer points (there is no second kernel),
so every solver's cost falls with the occupied volume. On exact data from the grid itself, a
support that contains the scene changes no least-squares answer (tested). Otherwise it is a
prior, and a strong one: on the paper's two-grid protocol it lifts LSMR's m-SSIM on the cube
from 0.28 to 0.97 (benchmarks/support.py). A support that misses part of the scene cannot
explain that part's data; `fit` reports how much the residual backprojects outside it.

`estimate_support` finds one from the data (``fit(..., support="auto")``): a thresholded,
dilated backprojection, sampled finer than the grid. Why finer: a voxel is ~100 wavelengths
wide, so the backprojection's peaks are millimetres wide, and sampled only at the voxel
centres it misses every scatterer that sits between them (the paper's forward points at odd
indices: its parking lot's poles all do). See `estimate_support` for what it was measured
to keep and when it can fail.

Why it costs seconds: the exact backprojection onto the fine points is most of a fit's
fixed cost (~60 s at the paper's scale). A fast approximate one (`rift_jax._backprojection`,
~40x cheaper, ~5 % error) screens the fine points first, and the exact one runs only where
the screen comes within ``SCREEN_MARGIN`` of the threshold: 2-14 % of the points on the
paper's scenes. Points the screen drops sit far below the threshold, so the mask is the
exact one's (tested against ``exact=True``).
"""

from __future__ import annotations

import dataclasses
import itertools

import jax.numpy as jnp
import numpy as np
import scipy.ndimage

from ._backprojection import fast_backprojection
from ._geometry import Radar, Viewpoints, spread
from ._operator import grt_operator
from ._padding import ladder_size
from ._scenes import Scene
from ._sharding import gathered
from ._validation import (
    check_finite,
    check_instance,
    check_nonnegative_int,
    check_numeric,
    check_positive,
    check_positive_int,
)

# Where the exact backprojection runs: at fine points whose fast one reaches this fraction of
# the threshold (relative to its own peak). The fast one's error is ~5 %; on the paper's
# scenes every point at or above the threshold screened at ≥ 0.93 of it (cube, sphere,
# parking lot: `python -m benchmarks.support --target` prints the cube's), so 0.6 leaves a
# wide margin for radars and scenes not measured.
SCREEN_MARGIN = 0.6


def as_mask(support, grid: Scene) -> np.ndarray:
    """A user's support (a boolean array of the grid's shape, or a `Scene` on the same grid
    whose non-zero voxels are the support) as a boolean (n, n, n) array."""
    if isinstance(support, str):
        raise ValueError(
            f'fit: `support` must be None, "auto", a boolean mask or a Scene, got {support!r}.'
        )
    if isinstance(support, Scene):
        if (support.extent, support.granularity) != (grid.extent, grid.granularity):
            raise ValueError(
                f"fit: the `support` Scene is on the grid ±{support.extent} m at "
                f"{support.granularity} m, but the reconstruction grid is ±{grid.extent} m at "
                f"{grid.granularity} m."
            )
        mask = np.asarray(support.reflectivity) != 0
    else:
        mask = np.asarray(support)
        if mask.dtype != bool:
            raise ValueError(
                "fit: `support` must be None, a boolean mask or a Scene, got an array of "
                f"dtype {mask.dtype}."
            )
        if mask.shape != grid.shape:
            raise ValueError(
                f"fit: the `support` mask must have the reconstruction grid's shape "
                f"{grid.shape} (±{grid.extent} m at {grid.granularity} m), got {mask.shape}."
            )
    if not mask.any():
        raise ValueError("fit: `support` holds no points; it must keep at least one.")
    mask = mask.copy()  # the result's own: a later change to the caller's array cannot move it
    mask.setflags(write=False)
    return mask


# Sizes per octave that a support's point count is padded to (`Support`): ≤ 12.5 % more
# arithmetic per iteration (6 % on average), against compiling every program of a method
# again for each new count, which at the stress grid's scale is most of a run
# (`rift_jax._padding`). Four per octave would halve the sizes, for twice the padding.
SUPPORT_SIZES_PER_OCTAVE = 8


@dataclasses.dataclass(frozen=True, eq=False)  # an array field: no value equality
class Support:
    """Where a reconstruction lives: the grid points a mask keeps, as an operator sees them.

    The operator runs on the support's points padded to `size` (`grt_operator`'s
    ``pad_to``: copies that hold ρ = 0: `GRT.live`), so that supports of about the same size share
    compiled programs; `restrict` and `embed` move values between the whole grid and the
    operator's points, and `leak` reads what a residual backprojects outside."""

    mask: np.ndarray  # boolean, the grid's shape, read-only (`as_mask`)
    size: int  # the operator's points: the support's, padded

    @classmethod
    def padded(cls, mask: np.ndarray) -> Support:
        """The support of ``mask``, padded to `ladder_size` (at most the whole grid)."""
        n = int(mask.sum())
        return cls(mask, min(ladder_size(n, SUPPORT_SIZES_PER_OCTAVE), mask.size))

    @property
    def n_points(self) -> int:
        """The support's own points (without padding)."""
        return int(self.mask.sum())

    def operator(self, radar: Radar, viewpoints: Viewpoints, grid_points: np.ndarray):
        """`grt_operator` on the support's points of ``grid_points`` (the grid's, flat)."""
        points = np.asarray(grid_points)[self.mask.ravel()]
        return grt_operator(radar, viewpoints, points, pad_to=self.size)

    def restrict(self, values) -> np.ndarray:
        """Values on the whole grid (any shape of its size) → the operator's points, zero
        on the padding."""
        kept = np.asarray(values).reshape(-1)[self.mask.ravel()]
        return np.pad(kept, (0, self.size - len(kept)))

    def embed(self, values) -> np.ndarray:
        """Values on the operator's points → the whole grid (flat), zero outside the
        support; the padding's are dropped."""
        values = np.asarray(values)
        grid = np.zeros(self.mask.size, values.dtype)
        grid[self.mask.ravel()] = values[: self.n_points]
        return grid

    def leak(self, residual, viewpoints: Viewpoints, grid_points, radar: Radar) -> float:
        """max over the grid's points outside the support of |Aᴴ r| for the data residual
        ``residual`` at ``viewpoints`` (`largest_backprojection`)."""
        outside = ~self.mask.ravel()
        if not outside.any():
            return 0.0
        return largest_backprojection(residual, viewpoints, grid_points, radar, where=outside)


def mask_at(mask: np.ndarray, grid: Scene, points: np.ndarray) -> np.ndarray:
    """Whether each of ``points`` (metres) lies in a support voxel of ``grid``: a voxel
    whose centre is nearest to it (for a point halfway between voxels, any of them), so a
    support carries over to any other grid's points. Voxel i sits at
    (i − (n − 1)/2)·granularity."""
    keep = np.zeros(len(points), bool)
    for index, inside in nearest_voxels(grid, points):
        keep[inside] |= mask[tuple(index[inside].T)]
    return keep


def nearest_voxels(grid: Scene, points: np.ndarray):
    """For each of the 8 ways to break ties: (the (k, 3) voxel index of each of ``points``
    nearest to it, whether it is on the grid). A point halfway between voxels (as the odd
    points of a grid twice as fine are) gets each of them once: either may hold it."""
    n = grid.shape[0]
    position = np.asarray(points, np.float64) / grid.granularity + (n - 1) / 2
    for offsets in itertools.product((-1e-6, 1e-6), repeat=3):
        index = np.floor(position + 0.5 + np.asarray(offsets)).astype(np.int64)
        yield index, np.all((index >= 0) & (index < n), axis=1)


def voxels_holding(grid: Scene, points: np.ndarray) -> np.ndarray:
    """The boolean mask of ``grid``'s voxels nearest to one of ``points`` (all of them, for
    a point halfway between voxels)."""
    mask = np.zeros(grid.shape, bool)
    for index, inside in nearest_voxels(grid, points):
        mask[tuple(index[inside].T)] = True
    return mask


def finer_points(grid: Scene, oversample: int) -> np.ndarray:
    """The (m, 3) points of the grid ``oversample`` times finer than ``grid`` whose points
    include the grid's own (nested, whatever the grid's point count)."""
    n = grid.shape[0]
    m = oversample * (n - 1) + 1
    axis = (np.arange(m) - (m - 1) / 2) * (grid.granularity / oversample)
    return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)


def estimate_support(
    signal,
    viewpoints: Viewpoints,
    grid: Scene,
    *,
    radar: Radar | None = None,
    threshold: float = 0.15,
    dilation: int = 1,
    oversample: int = 2,
    max_views: int = 100,
    floor_factor: float | None = None,
    exact: bool = False,
) -> np.ndarray:
    """A conservative support for ``grid`` from the data: where the backprojection is
    bright, grown by a margin.

    1. Backproject |Aᴴ y| from at most ``max_views`` of the viewpoints (evenly spaced in
       their order) onto the grid ``oversample`` times finer than ``grid`` whose points
       include the grid's (`finer_points`).
    2. Give each voxel the largest value among the fine points nearest to it (a point
       halfway between voxels counts for each), and divide by the largest value overall.
    3. Keep the voxels at or above ``threshold`` (with ``floor_factor``, also at or above
       that many times the median voxel: the backprojection's floor), dilated ``dilation``
       times by their six face neighbours.

    **Measured** (100 views of the paper's radar, its grids 0.2 / 0.4 m over ±5 m): with the
    defaults it kept every true voxel of the cube, sphere, pyramid, parking lot and highway
    and of random box scenes (ρ from 0.25 to 1), using 2-17 % of the grid (the sphere 48 %;
    `python -m benchmarks.support --coverage`). The faintest true
    voxel stood at 0.18 of the peak; solid objects' sidelobes reach 0.2-0.3, which is why a
    higher threshold drops scatterers a quarter as bright as the brightest.

    **When it can fail:** a scatterer fainter than ``threshold`` of the brightest one (lower
    it, at the cost of more points); fewer than ~50 viewpoints (the backprojection's
    sidelobes rise: with 25 views a sidelobe was the peak); scatterers off the fine samples
    by more than a fraction of a wavelength (3 mm here), which no grid reconstruction can
    explain either: raise ``oversample``. After a fit on it, ``stats["support_leak"]``
    reports how much of the residual backprojects outside.

    **A floor that rises with the scene** (``floor_factor``): the sidelobes of many
    scatterers sum to a speckle floor whose level, relative to the peak, grows with the
    scene's total reflectivity and with a narrower aperture. Where it reaches
    ``threshold`` a fixed fraction of the peak keeps most of the box: the weak target's
    36° aperture, from 500 views, has its median voxel at 0.12-0.17 of the peak (the
    brighter the weaker bar, the higher), and 0.15 kept 55-89 % of the grid. A voxel must
    then also reach ``floor_factor`` times the median voxel (a detection threshold set on
    the floor, as a CFAR detector sets it on the clutter), which selects only where the
    floor stands near ``threshold``. The median is the floor while the scene and its
    sidelobes fill less than half the grid; with ``exact=False`` it is read from the
    screened backprojection, exact while the screen drops under half the voxels (it drops
    only voxels below its own level), and 0 otherwise (the factor then keeps what
    ``threshold`` keeps). None (the default): ``threshold`` alone.

    **Arguments:** `signal` (n_views, n_freq, n_tx, n_rx), rows at `viewpoints`; `grid`: the
    reconstruction grid (a `Scene`, its values unused); `radar` (default the paper's);
    `floor_factor`: None or a positive number (above). `exact`: backproject every fine
    point exactly instead of screening them first with the fast approximate backprojection
    (same mask, measured; ~10-40x slower at the paper's scale).

    **Returns:** a read-only boolean mask of ``grid.shape``.
    """
    radar = Radar() if radar is None else radar
    for name, value, kind in (
        ("viewpoints", viewpoints, Viewpoints),
        ("grid", grid, Scene),
        ("radar", radar, Radar),
    ):
        check_instance(f"estimate_support: `{name}`", value, kind, f"a rift_jax.{kind.__name__}")
    if not (isinstance(threshold, int | float | np.floating) and 0 < threshold < 1):
        raise ValueError(f"estimate_support: `threshold` must be in (0, 1), got {threshold!r}.")
    check_nonnegative_int("estimate_support: `dilation`", dilation)
    check_positive_int("estimate_support: `oversample`", oversample)
    check_positive_int("estimate_support: `max_views`", max_views)
    if floor_factor is not None:
        check_positive("estimate_support: `floor_factor`", floor_factor)
    if not isinstance(exact, bool | np.bool_):
        raise ValueError(f"estimate_support: `exact` must be True or False, got {exact!r}.")
    signal = np.asarray(signal)
    check_numeric(signal, "estimate_support: `signal`")
    if signal.shape != (len(viewpoints), *radar.signal_shape):
        raise ValueError(
            f"estimate_support: `signal` must have shape {(len(viewpoints), *radar.signal_shape)}"
            f" for {len(viewpoints)} viewpoints, got {signal.shape}."
        )
    check_finite(signal, "estimate_support: `signal`")
    screen = None if exact else SCREEN_MARGIN * threshold
    pooled = pooled_backprojection(
        signal, viewpoints, grid, radar, oversample, max_views, screen=screen
    )
    peak = pooled.max()
    if peak == 0:
        raise ValueError("estimate_support: `signal` is zero; there is nothing to find.")
    level = threshold * peak
    if floor_factor is not None:
        floor = float(np.median(pooled))
        level = max(level, floor_factor * floor)
        if level > peak:  # the median voxel within a factor of the peak: the floor is all
            raise ValueError(
                f"estimate_support: `floor_factor` {floor_factor!r} asks for "
                f"{level / peak:.3g} times the backprojection's peak (its median voxel is "
                f"{floor / peak:.3g} of it): no voxel would be kept. Lower it, or "
                "pass None where the scene fills most of the grid."
            )
    mask = pooled >= level
    if dilation:
        mask = scipy.ndimage.binary_dilation(mask, iterations=dilation)
    mask.setflags(write=False)
    return mask


def pooled_backprojection(
    signal, viewpoints, grid, radar, oversample, max_views, *, screen: float | None = None
) -> np.ndarray:
    """Steps 1-2 of `estimate_support` (inputs checked there): |Aᴴ y| from at most
    ``max_views`` viewpoints on `finer_points`, each voxel of ``grid`` given the largest value
    among the fine points nearest to it. Float64, of ``grid.shape``, not normalised.

    ``screen``: backproject exactly only the fine points where `fast_backprojection` reaches
    this fraction of its peak (the others count as 0); None: every point exactly."""
    rows = spread(len(viewpoints), max_views)
    points = finer_points(grid, oversample)
    signal, viewpoints = np.asarray(signal)[rows], viewpoints[rows]
    back = np.zeros(len(points), np.float64)
    if screen is None:
        candidates = np.arange(len(points))
    else:
        candidates = screened(signal, viewpoints, points, radar, screen)
    back[candidates] = exact_backprojection(
        signal, viewpoints, points[candidates], radar, pad=screen is not None
    )
    pooled = np.zeros(grid.shape, np.float64)
    for index, inside in nearest_voxels(grid, points):
        np.maximum.at(pooled, tuple(index[inside].T), back[inside])
    return pooled


def exact_backprojection(
    signal, viewpoints, points, radar, *, pad: bool, at_least: int = 0
) -> np.ndarray:
    """|Aᴴ y| at ``points``; with ``pad``, the point count padded up to `ladder_size` (or
    ``at_least``, if more; `grt_operator`'s ``pad_to``) so that screens keeping similar
    counts share one compiled adjoint."""
    n = len(points)
    size = max(ladder_size(n), at_least) if pad else None
    operator = grt_operator(radar, viewpoints, points, pad_to=size)
    return np.abs(np.asarray(gathered(operator.fn.adjoint(jnp.asarray(signal)))))[:n]


def screened(signal, viewpoints, points, radar, fraction: float, where=None) -> np.ndarray:
    """Indices of ``points`` (among those ``where`` marks, default all), brightest first,
    where `fast_backprojection` reaches ``fraction`` of its own maximum over them: those the
    exact adjoint must visit. Every such point, in order, if the screen has nothing to say
    (all zero, or not finite: the exact path then meets the same input and says what is
    wrong with it) or cannot read this radar (the fast backprojection is written for the
    paper's L with uniform frequencies, `Radar.is_paper_array`)."""
    if where is not None and not np.any(where):
        raise ValueError("screened: `where` marks no point to screen.")
    every = np.arange(len(points)) if where is None else np.flatnonzero(where)
    if not radar.is_paper_array:
        return every
    fast = np.abs(np.asarray(fast_backprojection(signal, viewpoints, points, radar)))
    if where is not None:
        fast = np.where(where, fast, 0)
    if not (np.all(np.isfinite(fast)) and fast.max() > 0):
        return every
    candidates = np.flatnonzero(fast >= fraction * fast.max())
    return candidates[np.argsort(fast[candidates], kind="stable")[::-1]]


# The leak check needs one maximum, not a mask: the brightest screened points hold it unless
# hundreds come within the screen's ~5 % of each other, and 256 exact points cost ~0.1 s at
# the paper's scale (a few % of the screen itself).
_LARGEST_CANDIDATES = 256


def largest_backprojection(signal, viewpoints, points, radar, where=None) -> float:
    """max over ``points`` (those ``where`` marks, default all) of |Aᴴ y| for a fraction of
    the cost: the exact adjoint runs only at the points where `fast_backprojection` reaches
    ``SCREEN_MARGIN`` of its own maximum, at most the `_LARGEST_CANDIDATES` brightest of
    them. (``where`` rather than a subset of points: the screen then runs on one point set,
    a whole grid, compiled once for every support on it.) Exact wherever the maximum stands
    out of the backprojection (tested); where hundreds of points come within ~5 % of it (a
    residual like noise), it is the largest of the brightest ones screened, within the
    screen's error of the maximum."""
    candidates = screened(signal, viewpoints, points, radar, SCREEN_MARGIN, where)
    if not radar.is_paper_array:  # not screened, so not ordered: every point, exactly
        return float(
            exact_backprojection(signal, viewpoints, points[candidates], radar, pad=True).max()
        )
    candidates = candidates[:_LARGEST_CANDIDATES]
    exact = exact_backprojection(  # one size: compiled once, whatever the screen keeps
        signal, viewpoints, points[candidates], radar, pad=True, at_least=_LARGEST_CANDIDATES
    )
    return float(exact.max())
