"""Scenes: complex reflectivity sampled on a regular grid centred at the origin, and the
paper's synthetic scenes (Section 4, Appendix "Additional Results").

Grid convention: points at ``(i - (n - 1)/2) · granularity`` for i < n, with n the most that
fit within ``±extent``, endpoints included when ``2·extent`` is a multiple of the granularity.
Such grids nest: the 0.4 m grid over ±5 m (26 points per axis) is every other point of the
0.2 m grid (51 points). docs/conventions.md ("Two-grid protocol") explains why nesting
matters: data synthesised on one grid is only explainable on a grid whose points it shares.

Each voxel is a point scatterer at its grid point; a builder marks a voxel occupied when its
point lies inside the object (boundaries inclusive, to 1e-6 m).
"""

from __future__ import annotations

import math
import os
import sys
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from ._validation import as_finite_array, check_finite, check_nonnegative_int, check_positive

_TOL = 1e-6  # metres: points on an object's boundary count as inside


def grid_size(extent: float, granularity: float, where: str = "grid_size") -> int:
    """Points per axis of the grid with this ``granularity`` within ``±extent`` (errors name
    ``where``, the public function that was called)."""
    check_positive(f"{where}: `extent`", extent)
    check_positive(f"{where}: `granularity`", granularity)
    if granularity > extent:
        raise ValueError(
            f"{where}: `granularity` ({granularity} m) must not exceed `extent` ({extent} m, the "
            "half-width): the grid would have a single point."
        )
    return int(math.floor(2 * extent / granularity + 1e-6)) + 1


class GridWarning(UserWarning):
    """A grid that does not reach its extent, or an inverse grid that shares few points with
    the grid the data came from."""


def warn_unless_spanned(extent: float, granularity: float, where: str) -> int:
    """`grid_size` (its errors naming ``where``), warning (`GridWarning`) when the grid's
    points stop short of ±``extent`` by more than a thousandth of a voxel: the scene's
    `extent` would then promise a region that no point samples."""
    n = grid_size(extent, granularity, where)
    reach = (n - 1) * granularity / 2
    if reach < extent - granularity / 1000:
        divides = 2 * extent / math.ceil(2 * extent / granularity)
        digits = 10 ** (8 - math.floor(math.log10(divides)))  # 9 significant, rounded down:
        divides = math.floor(divides * digits) / digits  # rounded up, it would lose a point
        warnings.warn(
            f"A grid of `granularity` {granularity:g} m over `extent` ±{extent:g} m reaches "
            f"only ±{reach:.6g} m ({n} points per axis): nothing beyond is sampled. Choose a "
            f"granularity that divides 2·extent, e.g. {divides:.9g} m.",
            GridWarning,
            stacklevel=_caller_outside_rift_jax(),
        )
    return n


def _caller_outside_rift_jax() -> int:
    """The `warnings.warn` stacklevel of the first caller outside rift_jax (and the equinox
    and JAX wrappers between), so that a warning names the user's line, whichever public
    function (`Scene.empty`, a builder, `fit`, ...) made the grid."""
    package = os.path.dirname(os.path.abspath(__file__))
    wrappers = (package, os.path.dirname(eqx.__file__), os.path.dirname(jax.__file__))
    frame, level = sys._getframe(2), 2  # warn_unless_spanned's caller: stacklevel 2
    while frame is not None and frame.f_code.co_filename.startswith(wrappers):
        frame, level = frame.f_back, level + 1
    return level


def grid_axis(extent: float, granularity: float, where: str = "grid_axis") -> np.ndarray:
    """The grid's coordinates along one axis (metres, float64, centred at 0)."""
    n = grid_size(extent, granularity, where)
    return (np.arange(n) - (n - 1) / 2) * granularity


def grid_points(
    extent: float, granularity: float, where: str = "grid_points"
) -> Float[np.ndarray, "n_points 3"]:
    """All points of the cubic grid, x-major (the order of ``reflectivity.ravel()``)."""
    axis = grid_axis(extent, granularity, where)
    return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)


def shared_fraction(coarse: tuple[float, float], fine: tuple[float, float]) -> float:
    """The fraction of the points of grid ``coarse`` = (extent, granularity) that are also
    points of grid ``fine``: 1 when the grids nest, 0 when they share none (e.g. a 20-point
    axis and its 2× coarser one: centred grids of even size sit at half-integer multiples
    of their spacing)."""
    axis, within = grid_axis(*coarse), grid_axis(*fine)
    tol = 1e-6 * min(coarse[1], fine[1])
    shared = np.min(np.abs(axis[:, None] - within[None, :]), axis=1) <= tol
    return float(shared.mean() ** 3)


def nesting_granularities(extent: float, granularity: float, most: int = 8) -> list[float]:
    """The granularities c · ``granularity``, c = 2 .. ``most``, whose grids over ±``extent``
    nest in the grid of ``granularity``: the inverse grids to offer when data comes from it."""
    return [
        c * granularity
        for c in range(2, most + 1)
        if c * granularity <= extent
        and shared_fraction((extent, c * granularity), (extent, granularity)) == 1.0
    ]


class Scene(eqx.Module):
    """Complex reflectivity ρ on a cubic grid centred at the origin.

    **Fields:**

    - `reflectivity`: complex array (n, n, n), axes x, y, z.
    - `extent`: half-width of the scene (m).
    - `granularity`: distance between neighbouring points (m).
    """

    reflectivity: Complex[Array, "nx ny nz"]
    extent: float = eqx.field(static=True)
    granularity: float = eqx.field(static=True)

    def __check_init__(self):
        if not hasattr(self.reflectivity, "shape"):
            raise ValueError("Scene: `reflectivity` must be an array (nx, ny, nz).")
        check_finite(self.reflectivity, "Scene: `reflectivity`")
        shape = self.reflectivity.shape
        n = grid_size(self.extent, self.granularity, "Scene")
        if shape != (n, n, n):
            raise ValueError(
                f"Scene: `reflectivity` must have shape {(n, n, n)} for extent {self.extent} m "
                f"and granularity {self.granularity} m, got {shape}."
            )

    @classmethod
    def from_array(cls, array, extent: float) -> Scene:
        """A scene from a user's (n, n, n) array of reflectivity spanning ``±extent`` (its
        first and last points on the faces), so ``granularity = 2·extent/(n - 1)``."""
        check_positive("Scene.from_array: `extent`", extent)
        arr = as_finite_array(array, "Scene.from_array: `array`")
        if arr.ndim != 3 or len(set(arr.shape)) != 1 or arr.shape[0] < 2:
            raise ValueError(
                f"Scene.from_array: `array` must be a cube (n, n, n) with n ≥ 2, got {arr.shape}."
            )
        granularity = 2 * extent / (arr.shape[0] - 1)
        return cls(jnp.asarray(arr, jnp.complex64), float(extent), float(granularity))

    @classmethod
    def empty(cls, extent: float, granularity: float) -> Scene:
        """An all-zero scene (e.g. a reconstruction grid)."""
        n = warn_unless_spanned(extent, granularity, "Scene.empty")
        return cls(jnp.zeros((n, n, n), jnp.complex64), float(extent), float(granularity))

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.reflectivity.shape

    def axis(self) -> np.ndarray:
        """Coordinates of the grid along each axis (metres)."""
        return grid_axis(self.extent, self.granularity)

    def points(self) -> Float[np.ndarray, "n_points 3"]:
        """The voxel centres, (V, 3) metres, in the order of ``reflectivity.ravel()``."""
        return grid_points(self.extent, self.granularity)

    def occupied(self) -> tuple[Float[np.ndarray, "k 3"], Complex[np.ndarray, " k"]]:
        """Points and reflectivity of the non-zero voxels only (empty space carries no
        signal, so synthesis skips it)."""
        rho = np.asarray(self.reflectivity).ravel()
        keep = np.flatnonzero(rho)
        return self.points()[keep], rho[keep]

    def resample(self, granularity: float, *, order: int = 1, anti_aliasing: bool = True) -> Scene:
        """This scene on the grid of another ``granularity`` over the same extent.

        Interpolates real and imaginary parts with scikit-image (``skimage.transform.warp``,
        spline ``order``), sampling at the new grid's exact physical points: ``resize`` maps
        pixel edges to pixel edges, which for grids with endpoints would shift points by up to
        half a voxel. When coarsening, ``anti_aliasing`` first applies the Gaussian that
        ``skimage.transform.resize`` would (σ = (factor - 1)/2 voxels).
        """
        from skimage.filters import gaussian
        from skimage.transform import warp

        n_new = warn_unless_spanned(self.extent, granularity, "Scene.resample")
        factor = granularity / self.granularity
        coords = (grid_axis(self.extent, granularity) / self.granularity) + (self.shape[0] - 1) / 2
        mesh = np.stack(np.meshgrid(coords, coords, coords, indexing="ij"))
        rho = np.asarray(self.reflectivity)

        def one(part: np.ndarray) -> np.ndarray:
            if anti_aliasing and factor > 1:
                part = gaussian(part, sigma=max(0.0, (factor - 1) / 2), mode="nearest")
            return warp(
                part, mesh, order=order, mode="constant", cval=0.0, clip=False, preserve_range=True
            )

        out = one(rho.real.astype(np.float64)) + 1j * one(rho.imag.astype(np.float64))
        assert out.shape == (n_new,) * 3
        return Scene(jnp.asarray(out, jnp.complex64), self.extent, float(granularity))


# --- The paper's scenes -----------------------------------------------------------------


def _coordinates(extent: float, granularity: float, where: str = "scene") -> tuple[np.ndarray, ...]:
    """(x, y, z) of every grid point, each (n, n, n); errors name the builder ``where``."""
    warn_unless_spanned(extent, granularity, where)
    return np.meshgrid(*(grid_axis(extent, granularity, where),) * 3, indexing="ij")


def _box(xyz, centre, size) -> np.ndarray:
    """The grid points inside the axis-aligned box (boundaries inclusive)."""
    inside = np.ones(xyz[0].shape, bool)
    for coord, c, s in zip(xyz, centre, size, strict=True):
        inside &= np.abs(coord - c) <= s / 2 + _TOL
    return inside


def _ball(xyz, centre, radius: float) -> np.ndarray:
    """The grid points inside the ball (boundary inclusive)."""
    squares = sum((coord - c) ** 2 for coord, c in zip(xyz, centre, strict=True))
    return squares <= (radius + _TOL) ** 2


def _scene_from_boxes(boxes, extent: float, granularity: float, where: str = "scene") -> Scene:
    """Union of axis-aligned boxes ``(centre, size, value)``; later boxes overwrite earlier."""
    xyz = _coordinates(extent, granularity, where)
    rho = np.zeros(xyz[0].shape, np.complex64)
    for centre, size, value in boxes:
        rho[_box(xyz, centre, size)] = value
    return Scene(jnp.asarray(rho), float(extent), float(granularity))


def sphere(granularity: float = 0.2, *, extent: float = 5.0, radius: float = 2.0) -> Scene:
    """Solid sphere of ``radius`` (paper: 2 m) centred at the origin, ρ = 1.
    At 0.2 m: 4,169 occupied voxels."""
    check_positive("sphere: `radius`", radius)  # NaN or ≤ 0 would give an empty scene
    rho = _ball(_coordinates(extent, granularity, "sphere"), (0, 0, 0), radius).astype(np.complex64)
    return Scene(jnp.asarray(rho), float(extent), float(granularity))


def cube(granularity: float = 0.2, *, extent: float = 5.0, edge: float = 2.0) -> Scene:
    """Solid axis-aligned cube of ``edge`` (paper: 2 m) centred at the origin, ρ = 1."""
    check_positive("cube: `edge`", edge)  # NaN or ≤ 0 would give an empty scene
    return _scene_from_boxes([((0, 0, 0), (edge, edge, edge), 1.0)], extent, granularity, "cube")


def pyramid(
    granularity: float = 0.2, *, extent: float = 5.0, base: float = 2.0, height: float = 2.0
) -> Scene:
    """Solid square pyramid (the paper's "tetrahedron"): ``base × base`` square at
    z = -height/2, apex at z = +height/2 (bounding box centred at the origin; the paper
    does not place it), ρ = 1."""
    check_positive("pyramid: `base`", base)  # NaN or ≤ 0 would give an empty scene
    check_positive("pyramid: `height`", height)
    x, y, z = _coordinates(extent, granularity, "pyramid")
    half = (base / 2) * (height / 2 - z) / height  # half-width of the cross-section at z
    inside = (np.abs(z) <= height / 2 + _TOL) & (np.maximum(np.abs(x), np.abs(y)) <= half + _TOL)
    return Scene(jnp.asarray(inside.astype(np.complex64)), float(extent), float(granularity))


GROUND = -1.0
"""z (m) on which the complex scenes' objects stand. The paper gives their sizes, not their
vertical placement; standing them on z = -1 keeps every object inside the 10 m cube."""


def parking_lot(granularity: float = 0.2, *, extent: float = 5.0) -> Scene:
    """The "mini parking lot" (Section 4.1.2): a road along y; ten street lights 2.2 m tall
    (0.2 × 0.2 m poles) in two rows of five at x = ±1.8 m, y ∈ {-4, -2, 0, 2, 4}; a car
    0.8 × 0.6 × 0.6 m (x × y × z) at x = -0.9, y = -1 and a car 1.0 × 0.4 × 0.4 m at
    x = +0.9, y = 1.5, on opposite sides of the road; all on the ground z = -1, ρ = 1.
    Positions the paper leaves open are chosen here and kept fixed."""
    boxes = []
    for x in (-1.8, 1.8):
        for y in (-4.0, -2.0, 0.0, 2.0, 4.0):
            boxes.append(((x, y, GROUND + 1.1), (0.2, 0.2, 2.2), 1.0))
    boxes.append(((-0.9, -1.0, GROUND + 0.3), (0.8, 0.6, 0.6), 1.0))
    boxes.append(((0.9, 1.5, GROUND + 0.2), (1.0, 0.4, 0.4), 1.0))
    return _scene_from_boxes(boxes, extent, granularity, "parking_lot")


def highway(granularity: float = 0.2, *, extent: float = 5.0) -> Scene:
    """The "mini highway" (Appendix): street lights 1.8 m tall (0.2 × 0.2 m poles) at
    x = ±4.4 m spaced 3.2 m along y (y ∈ {-4.8, -1.6, 1.6, 4.8}); fences 2.0 m tall and
    0.2 m thick along the whole y extent at x = -4, 0 and +4; a car 0.8 × 2.4 × 1.6 m
    (x × y × z) centred at x = 2, y = 3.2 (3.8 m from the origin), all on z = -1, ρ = 1."""
    boxes = []
    for x in (-4.4, 4.4):
        for y in (-4.8, -1.6, 1.6, 4.8):
            boxes.append(((x, y, GROUND + 0.9), (0.2, 0.2, 1.8), 1.0))
    for x in (-4.0, 0.0, 4.0):
        boxes.append(((x, 0.0, GROUND + 1.0), (0.2, 2 * extent, 2.0), 1.0))
    boxes.append(((2.0, 3.2, GROUND + 0.8), (0.8, 2.4, 1.6), 1.0))
    return _scene_from_boxes(boxes, extent, granularity, "highway")


def weak_target(
    ratio: float = 1.0, granularity: float = 0.12, *, extent: float = 3.0, gap: float = 1.2
) -> Scene:
    """The weak-target study (Section 4.3): two bars 0.72 × 2.4 × 0.48 m (x × y × z) on
    either side of the y axis, centred in y and z. The bar at negative x has ρ = 1, the one at
    positive x has ρ = ``ratio`` (paper: 1, 0.5, 0.333, 0.25).

    The paper's "separated by 1.2 m" is read as the gap between the bars' faces (centres at
    x = ±0.96 m); ``gap=0.48`` gives the other reading, 1.2 m between centres."""
    if not (isinstance(ratio, int | float | np.floating) and 0 < ratio <= 1):
        raise ValueError(
            f"weak_target: `ratio` is the weak bar's reflectivity relative to the strong one, "
            f"in (0, 1]; got {ratio!r} (for a 4:1 contrast pass 0.25)."
        )
    check_positive("weak_target: `gap`", gap)
    size = (0.72, 2.4, 0.48)
    offset = gap / 2 + size[0] / 2
    boxes = [((-offset, 0.0, 0.0), size, 1.0), ((offset, 0.0, 0.0), size, float(ratio))]
    return _scene_from_boxes(boxes, extent, granularity, "weak_target")


# --- Scenes the paper never used --------------------------------------------------------


PRIMITIVES = ("box", "ball", "pole", "plate")


def random_primitives(
    seed: int, granularity: float = 0.2, *, extent: float = 5.0, count: tuple[int, int] = (3, 7)
) -> Scene:
    """A scene of ``count`` (at least, at most) random primitives, for testing on scenes
    nothing was tuned on: boxes (0.4-2 m sides), balls (0.3-1.2 m radius), thin vertical
    poles and thin horizontal plates (one to two ``granularity`` thick), at random positions
    inside ±0.7·``extent`` (so they fit), each with a reflectivity magnitude in [0.25, 1]
    and, for half of them, a random phase. Later primitives overwrite earlier ones.
    The same seed gives the same scene at every granularity (up to sampling)."""
    check_nonnegative_int("random_primitives: `seed`", seed)
    if not (len(count) == 2 and 1 <= count[0] <= count[1]):
        raise ValueError(
            f"random_primitives: `count` must be (least, most) with 1 ≤ least ≤ most, got "
            f"{count!r}."
        )
    rng = np.random.default_rng(seed)
    xyz = _coordinates(extent, granularity, "random_primitives")
    rho = np.zeros(xyz[0].shape, np.complex64)
    reach = 0.7 * extent
    thin = max(granularity, 0.2)  # poles and plates hold at least one plane of points
    for _ in range(rng.integers(count[0], count[1] + 1)):
        kind = PRIMITIVES[rng.integers(len(PRIMITIVES))]
        centre = rng.uniform(-reach, reach, 3)
        value = rng.uniform(0.25, 1.0)
        if rng.random() < 0.5:
            value = value * np.exp(1j * rng.uniform(-np.pi, np.pi))
        if kind == "ball":
            inside = _ball(xyz, centre, rng.uniform(0.3, 1.2))
        elif kind == "box":
            inside = _box(xyz, centre, rng.uniform(0.4, 2.0, 3))
        elif kind == "pole":
            inside = _box(xyz, centre, (thin, thin, rng.uniform(1.0, 2.5)))
        else:  # plate
            inside = _box(xyz, centre, (*rng.uniform(1.0, 2.5, 2), thin))
        rho[inside] = value
    return Scene(jnp.asarray(rho), float(extent), float(granularity))
