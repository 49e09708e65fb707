"""The GRT over many viewpoints as one linear operator: ρ on grid points → stacked signals.

Every solver (Kaczmarz, LSMR, Gauss-Newton, FISTA, the INR) consumes the object that
`grt_operator` returns: a `GRTOperator` (a lineax operator) whose `fn` is a `GRT` module.
`GRT` also exposes the per-viewpoint row blocks (`view`, `view_adjoint`) that block methods
use.

Viewpoints are independent, so they are spread over the available devices (with
`shard_map`; on CPU, rift_jax starts JAX with one host device per core, see
`rift_jax/__init__.py`) and mapped sequentially (CPU) or in vmapped batches (GPU) on each.
A single view (`view`, `view_adjoint`), or fewer views than devices, splits its voxels over
the devices instead (`rift_jax._sharding`). The products are jitted, so plain calls compile
once per shape; plain forward calls run in blocks of views (`views_per_block`), so that they
compile once per set of points, whatever their number of views.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
from jaxtyping import Array, Bool, Complex, Float, Int

from . import _grt
from ._geometry import Radar, Viewpoints, antennas_at
from ._precision import Float64Pair, exact_jit, host_float64, leading, split, to_float64
from ._sharding import over_views, pinned, replicated
from ._validation import (
    as_finite_array,
    check_finite,
    check_instance,
    check_positive_int,
    is_concrete,
)

# Views per block of a top-level forward call (`GRT.__call__`), before rounding up to a
# multiple of the device count. Each view count compiled its own forward program (~1.5 s on
# a 2-core CPU; the test suite's top-level forwards had 114 shapes, 60 once their view
# counts were set aside), while padding a call to whole blocks costs less than a block's
# work. (Fewer views than a block: see `GRT._blocks`.)
VIEW_BLOCK = 8
# Calls of more views run in one program: there the work outweighs a compilation, and
# blocks ran ~30 % slower than one program (400 views of the paper's radar on 552 points:
# 1.32 s against 0.99 s, 2 CPU devices; each block is a launch of its own), and their
# eager concatenation cost another 0.19 s.
BLOCKED_VIEWS = 64


def views_per_block() -> int:
    """`VIEW_BLOCK`, or a vmapped batch (`_views_per_batch`) for every device if more,
    rounded up to a multiple of the device count (each device then gets whole views)."""
    devices = jax.device_count()
    return -(-max(VIEW_BLOCK, _views_per_batch() * devices) // devices) * devices


def _views_per_batch() -> int:
    """Viewpoints vmapped together on one device: one on CPU (each view already fills a core's
    caches), several on accelerators (which need the parallelism)."""
    return 1 if jax.default_backend() == "cpu" else 8


class GRT(eqx.Module):
    """The Generalized Radon Transform for a fixed radar, viewpoints and grid points.

    ``GRT(ρ)[i] = grt.forward(points, ρ, *antennas_at(radar, *pose_i), freqs)``, shape
    (n_views, n_freq, n_tx, n_rx); `adjoint` is its exact conjugate transpose. The
    viewpoints' poses (positions and orientations, `Viewpoints.poses`) and the points are
    array leaves held as float32 (hi, lo) pairs, so they keep float64 precision without x64
    (`rift_jax._precision`); distances and phases are computed in float64, see
    `rift_jax.grt`. ``amplitude`` is the kernels' separable spreading factor for these
    points and poses: `grt_operator` chooses it, and so does the constructor when it is not
    given.

    ``live`` marks the points that exist (None, for a GRT built directly: every point;
    `grt_operator` always sets it, so that its operators of one size, padded or not, have
    one structure and share their compiled programs): the GRT is then A·diag(live),
    whose other columns are zero, so ρ there changes no signal and gets no backprojection.
    The others are padding (`grt_operator`'s ``pad_to``): a problem padded to a size shared
    with others reuses their compiled programs, and every solver's answer on the live
    points is the unpadded one.
    """

    radar: Radar = eqx.field(static=True)
    positions: Float64Pair
    orientations: Float64Pair
    points: Float64Pair
    chunk_size: int | None = eqx.field(static=True, default=None)
    live: Bool[Array, " n_points"] | None = None
    amplitude: _grt.Amplitude | None = eqx.field(static=True, default=None)

    def __post_init__(self):
        if self.amplitude is None:  # built directly rather than by `grt_operator`: the
            # spreading that this radar, these poses and points need
            if is_concrete((self.positions, self.orientations, self.points)):
                poses = (host_float64(self.positions), host_float64(self.orientations))
                self.amplitude = _amplitude_for(self.radar, poses, host_float64(self.points))
            elif self.radar.near_field and self.radar.separation > 0:
                self.amplitude = _grt.Amplitude.unread(self.radar.spreading)
            elif self.radar.near_field:  # TX and RX at one point: r_t = r_r, q = 0
                self.amplitude = _grt.Amplitude.of(self.radar.spreading)
            else:
                self.amplitude = _grt.Amplitude.of("far-field")

    @property
    def n_views(self) -> int:
        return leading(self.positions)

    @property
    def n_points(self) -> int:
        return leading(self.points)

    @property
    def out_shape(self) -> tuple[int, int, int, int]:
        return (self.n_views, *self.radar.signal_shape)

    def _geometry(self, position, orientation):
        with jax.enable_x64(True):
            tx, rx = antennas_at(self.radar, to_float64(position), to_float64(orientation))
        return self.points, tx, rx, self.radar.frequencies

    def on(self, points: Float64Pair, live: Bool[Array, " k"] | None = None) -> GRT:
        """The same radar and viewpoints on other ``points`` (a float32 pair, see
        `rift_jax._precision.split`), of which ``live`` exist (None: all; marked so when
        this GRT marks its own).

        The amplitude is kept when the new points reach no farther from the centre than
        these (supports, active sets, finer grids of the same box): its bound, from that
        reach, holds for them too, and the programs compiled for one size serve every
        point set padded to it. It is chosen again for points reaching farther, and for
        amplitudes of more than three terms (read from these points' own q), when the
        points are concrete."""
        amplitude = self.amplitude
        near = amplitude.near
        if live is None and self.live is not None:  # one structure, as `grt_operator`'s
            live = jax.device_put(np.ones(leading(points), bool))  # (jnp.ones compiles)
        if is_concrete((points, self.points)):
            new, old = host_float64(points), host_float64(self.points)
            farther = np.max(np.linalg.norm(new, axis=1)) > np.max(np.linalg.norm(old, axis=1))
            if farther or (near is not None and len(near) > 3):
                poses = (host_float64(self.positions), host_float64(self.orientations))
                amplitude = _amplitude_for(self.radar, poses, new)
        return GRT(
            self.radar, self.positions, self.orientations, points, self.chunk_size, live, amplitude
        )

    def live_points(self) -> np.ndarray:
        """Which points exist, as a boolean NumPy array (all of them without padding), for
        host-side work such as choosing among them; concrete `live` only."""
        return np.ones(self.n_points, bool) if self.live is None else np.asarray(self.live)

    def masked(self, x: Complex[Array, " n_points"]) -> Complex[Array, " n_points"]:
        """``x`` zero at the points that are not live: diag(live) x."""
        return x if self.live is None else jnp.where(self.live, x, 0)

    def _index(self, index) -> Array:
        """``index`` checked (when concrete) and as an array, so that every view shares one
        compilation."""
        if is_concrete(index) and not -self.n_views <= int(index) < self.n_views:
            raise ValueError(f"GRT: view `index` {index} out of range for {self.n_views} views.")
        return jnp.asarray(index, jnp.int32)  # one dtype: a NumPy int64 must not recompile

    def subset(self, index: Int[Array, " k"]) -> GRT:
        """The GRT of viewpoints ``index`` only (an integer array, may be traced): a batch of
        row blocks. Calling it spreads those viewpoints over devices, as for the whole."""
        poses = jax.tree.map(lambda a: a[index], (self.positions, self.orientations))
        return eqx.tree_at(lambda g: (g.positions, g.orientations), self, poses)

    def view(self, rho: Complex[Array, " n_points"], index) -> Complex[Array, "f m n"]:
        """The signal of viewpoint ``index`` (may be traced): one row block of the operator.
        Its voxels are split over the devices (not inside a `shard_map`)."""
        rho = self.masked(jnp.asarray(rho, jnp.complex64))
        return _row(self, _grt.forward_view, rho, self._index(index))

    def view_adjoint(self, signal: Complex[Array, "f m n"], index) -> Complex[Array, " n_points"]:
        """Backprojection of one viewpoint's signal: the adjoint of `view`."""
        signal = jnp.asarray(signal, jnp.complex64)
        return self.masked(_row(self, _grt.adjoint_view, signal, self._index(index)))

    def __call__(self, rho: Complex[Array, " n_points"]) -> Complex[Array, "v f m n"]:
        """All viewpoints' signals, (n_views, n_freq, n_tx, n_rx).

        Called on concrete values and up to `BLOCKED_VIEWS` views, the views run in blocks
        (`GRT._blocks`: `views_per_block` views, the last block padded with repeats of its
        last view, whose signals are dropped), each on inputs copied to every device: such
        calls on these points share a compiled program whatever their number of views (a
        synthesis of the training views, a fit's residual, `FitResult.predict` on the test
        views). More views, traced (inside a solver's iteration), or with an input pinned to
        one device: all views run in one program."""
        rho = jnp.asarray(rho, jnp.complex64)
        if rho.shape != (self.n_points,):
            raise ValueError(f"GRT: `rho` must have shape ({self.n_points},), got {rho.shape}.")
        if (
            not is_concrete((self, rho))
            or pinned((self, rho))
            or not 0 < self.n_views <= BLOCKED_VIEWS
        ):
            return self._signals(rho)
        whole, rho = replicated((self, rho))
        blocks = [block._signals(rho) for block in whole._blocks()]
        last = self.n_views - (len(blocks) - 1) * leading(blocks[0])
        if last < leading(blocks[-1]):  # at most a block's worth of slice shapes
            blocks[-1] = blocks[-1][:last]
        return blocks[0] if len(blocks) == 1 else jnp.concatenate(blocks)

    def _blocks(self) -> list[GRT]:
        """This GRT as consecutive blocks of `views_per_block` viewpoints, the last one
        padded with repeats of the last viewpoint, their poses copied to every device (cut
        on the host: an eager slice of a device array compiles once per offset). Fewer
        views make one block: of the next power of two, rounded up to a multiple of the
        device count (less than twice their work where a whole block could be 8x), or of
        their own number when they are fewer than the devices (each view then splits its
        voxels over the devices)."""
        devices, n = jax.device_count(), self.n_views
        size = views_per_block()
        if n < devices:
            size = n
        elif n < size:
            size = min(size, -(-(1 << (n - 1).bit_length()) // devices) * devices)
        leaves, tree = jax.tree.flatten((self.positions, self.orientations))
        pad = -n % size
        leaves = [np.concatenate([a, np.repeat(a[-1:], pad, 0)]) for a in map(np.asarray, leaves)]
        starts = range(0, n + pad, size)
        cut = [a[i : i + size] for i in starts for a in leaves]
        # one transfer for every block (an array at a time cost ~2 ms per block)
        cut = replicated(cut) if devices > 1 else jax.device_put(cut)
        k = len(leaves)
        return [
            eqx.tree_at(
                lambda g: (g.positions, g.orientations),
                self,
                jax.tree.unflatten(tree, cut[j * k : (j + 1) * k]),
            )
            for j in range(len(starts))
        ]

    @exact_jit  # one tracing context wherever it is called from: one cache entry
    def _signals(self, rho: Complex[Array, " n_points"]) -> Complex[Array, "v f m n"]:
        """`__call__` for every view in one program (ρ checked by the caller)."""
        rho = self.masked(rho)

        def local(positions, orientations, rho):
            batch = _views_per_batch()  # one: a plain loop, so the kernels' per-chunk
            # conditionals stay conditionals (a vmap, even of one view, runs both arms)
            return jax.lax.map(
                lambda pose: self._kernel(_grt.forward_view, rho, *pose),
                (positions, orientations),
                batch_size=batch if batch > 1 else None,
            )

        poses = (self.positions, self.orientations)
        return over_views(local, *poses, rho, reduce=False)[: self.n_views]

    @exact_jit  # as `_signals`
    def adjoint(self, signal: Complex[Array, "v f m n"]) -> Complex[Array, " n_points"]:
        """Backprojection of all viewpoints, Σ_i view_adjoint(signal[i], i): the exact
        conjugate transpose of `__call__`."""
        signal = jnp.asarray(signal, jnp.complex64)
        if signal.shape != self.out_shape:
            raise ValueError(
                f"GRT.adjoint: `signal` must have shape {self.out_shape}, got {signal.shape}."
            )

        def local(positions, orientations, signal):
            def step(acc, xs):
                position, orientation, s = xs
                return acc + self._kernel(_grt.adjoint_view, s, position, orientation), None

            leaves = jax.tree.leaves((positions, orientations))  # per-device in shard_map
            zero = _grt._zeros((self.n_points,), signal.dtype, *leaves)
            return jax.lax.scan(step, zero, (positions, orientations, signal))[0]

        poses = (self.positions, self.orientations)
        return self.masked(over_views(local, *poses, signal, reduce=True))

    def _kernel(self, kernel, data, position, orientation):
        """``kernel`` (`forward_view` or `adjoint_view`: split over voxels where that
        applies) for one viewpoint's pose."""
        points, tx, rx, freqs = self._geometry(position, orientation)
        plan = _grt.frequency_plan(freqs)
        return kernel(
            points,
            tx,
            rx,
            None if plan.uniform else split(freqs),
            data,
            plan=plan,
            amplitude=self.amplitude,
            chunk=self.chunk_size,
        )


@exact_jit  # as `GRT._signals`
def _row(fn: GRT, kernel, data, index):
    """One row block (``kernel`` is `forward_view` or `adjoint_view`), jitted once per shape."""
    pose = jax.tree.map(lambda a: a[index], (fn.positions, fn.orientations))
    return fn._kernel(kernel, data, *pose)


class GRTOperator(lx.AbstractLinearOperator):
    """The GRT (or its transpose, conjugate or adjoint) as a lineax linear operator.

    Every variant runs a hand-written kernel: ``A = fn``, ``Aᵀ y = conj(fn.adjoint(conj(y)))``,
    ``conj(A) x = conj(fn(conj(x)))`` and ``Aᴴ = fn.adjoint``. (A `FunctionLinearOperator` would
    transpose ``fn`` with `jax.linear_transpose`: correct, but ~10x slower than the adjoint
    kernel, measured.) `fn` is the `GRT` module, with the row blocks `view`/`view_adjoint`.
    """

    fn: GRT
    transposed: bool = eqx.field(static=True, default=False)
    conjugated: bool = eqx.field(static=True, default=False)

    def mv(self, vector):
        # a linear map carries NaN into every output sample: say so where it came from
        # (concrete input only; inside a solver's trace there is nothing to look at)
        check_finite(vector, "GRTOperator.mv: `vector`")
        if self.transposed and self.conjugated:
            return self.fn.adjoint(vector)
        if self.transposed:
            return jnp.conj(self.fn.adjoint(jnp.conj(vector)))
        if self.conjugated:
            return jnp.conj(self.fn(jnp.conj(vector)))
        return self.fn(vector)

    def transpose(self) -> GRTOperator:
        return GRTOperator(self.fn, not self.transposed, self.conjugated)

    def as_matrix(self) -> Complex[Array, "out in"]:
        """The dense matrix (out_size × in_size), one column per basis vector: for tiny
        problems and tests only."""
        basis = jnp.eye(self.in_size(), dtype=jnp.complex64).reshape(
            (self.in_size(),) + self.in_structure().shape
        )
        columns = jax.lax.map(self.mv, basis)
        return columns.reshape(self.in_size(), self.out_size()).T

    def in_structure(self) -> jax.ShapeDtypeStruct:
        shape = self.fn.out_shape if self.transposed else (self.fn.n_points,)
        return jax.ShapeDtypeStruct(shape, jnp.complex64)

    def out_structure(self) -> jax.ShapeDtypeStruct:
        shape = (self.fn.n_points,) if self.transposed else self.fn.out_shape
        return jax.ShapeDtypeStruct(shape, jnp.complex64)


@lx.linearise.register(GRTOperator)
@lx.materialise.register(GRTOperator)
def _(operator):  # already linear and already as concrete as it will be (see `as_matrix`)
    return operator


@lx.conj.register(GRTOperator)
def _(operator):
    return GRTOperator(operator.fn, operator.transposed, not operator.conjugated)


@lx.diagonal.register(GRTOperator)
def _(operator):
    return jnp.diag(operator.as_matrix())


@lx.tridiagonal.register(GRTOperator)
def _(operator):
    matrix = operator.as_matrix()
    return jnp.diag(matrix), jnp.diag(matrix, -1), jnp.diag(matrix, 1)


@lx.is_symmetric.register(GRTOperator)
@lx.is_diagonal.register(GRTOperator)
@lx.is_tridiagonal.register(GRTOperator)
@lx.has_unit_diagonal.register(GRTOperator)
@lx.is_lower_triangular.register(GRTOperator)
@lx.is_upper_triangular.register(GRTOperator)
@lx.is_positive_semidefinite.register(GRTOperator)
@lx.is_negative_semidefinite.register(GRTOperator)
def _(operator):  # a rectangular forward model has none of these structures
    return False


def grt_operator(
    radar: Radar,
    viewpoints: Viewpoints,
    grid_points: Float[Array, "n_points 3"],
    *,
    chunk_size: int | None = None,
    pad_to: int | None = None,
) -> GRTOperator:
    """The GRT over ``viewpoints`` as a lineax linear operator.

    **Arguments:**

    - `radar`: a `Radar`.
    - `viewpoints`: a `Viewpoints` (the operator's row blocks, in order).
    - `grid_points`: (V, 3) points (metres) on which ρ lives, e.g. ``Scene.points()``.
    - `chunk_size`: voxels per scan step inside the kernel (None: `rift_jax.grt` default).
    - `pad_to`: pad the points to this many with copies of the last one that hold ρ = 0
      (zero columns: `GRT.live`), so that problems of similar sizes share compiled
      programs; ρ and Aᴴy then have ``pad_to`` entries, the padded ones zero in Aᴴy.
      Without it, `GRT.live` marks every point: operators of one size, padded or not,
      have one structure and share their compiled programs.

    **Returns:** a `GRTOperator` (a `lineax.AbstractLinearOperator`) from complex64 ρ of shape
    (V,) to signals of shape (n_views, n_freq, n_tx, n_rx). Its `.fn` is the `GRT` module (row
    blocks via ``.fn.view``/``.fn.view_adjoint``, backprojection via ``.fn.adjoint``); its
    `.transpose()` runs the hand-written adjoint kernel. Gradients through `.mv` come from
    JAX's own transpose of the forward kernel (exact, slower than the adjoint kernel).
    """
    check_instance("grt_operator: `radar`", radar, Radar, "a rift_jax.Radar")
    check_instance("grt_operator: `viewpoints`", viewpoints, Viewpoints, "rift_jax.Viewpoints")
    points = as_finite_array(grid_points, "grt_operator: `grid_points`", np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] == 0:
        raise ValueError(
            f"grt_operator: `grid_points` must have shape (V, 3) with V ≥ 1, got {points.shape}."
        )
    positions, orientations = viewpoints.poses(radar)
    _check_inside(positions, points)
    if chunk_size is not None:
        check_positive_int("grt_operator: `chunk_size`", chunk_size)
    if pad_to is not None:
        check_positive_int("grt_operator: `pad_to`", pad_to)
        if pad_to < len(points):
            raise ValueError(
                f"grt_operator: `pad_to` ({pad_to}) must be at least the number of "
                f"`grid_points` ({len(points)})."
            )
    # `live` even when every point is: an operator of one shape then has one structure,
    # padded or not, and shares its compiled programs (a mask of ones changes no value)
    live = jax.device_put(np.arange(pad_to or len(points)) < len(points))
    if pad_to is not None:  # on the host: an eager jnp.pad would compile for every size
        points = np.pad(points, ((0, pad_to - len(points)), (0, 0)), mode="edge")
    amplitude = _amplitude_for(radar, (positions, orientations), points)
    poses = split(positions), split(orientations)
    return GRTOperator(GRT(radar, *poses, split(points), chunk_size, live, amplitude))


def check_inside(radar: Radar, viewpoints: Viewpoints, points: np.ndarray) -> None:
    """`grt_operator`'s ValueError for ``points`` that reach the radar, without building
    an operator (for a caller that must refuse them before other work)."""
    _check_inside(viewpoints.poses(radar)[0], np.asarray(points, np.float64))


def _check_inside(positions: np.ndarray, points: np.ndarray) -> None:
    reach, distance = _reach(positions, points)
    if reach >= distance:
        # this keeps the points off the antennas, where the GRT's 1/R amplitudes diverge (a
        # voxel at an antenna gave |S| ≈ 1e9 and swamped every other voxel)
        raise ValueError(
            f"grt_operator: `grid_points` reach {reach:.4g} m from the scene's centre, but the "
            f"radar stands {distance:g} m away (Radar.distance, or the nearest pose): every "
            "point must lie closer to the centre than the radar."
        )


def _reach(positions: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """How far ``points`` reach from the scene's centre (the origin) and how near the
    nearest viewpoint stands to it: a bound on the points' distance to the viewpoints, in
    O(views + points) on the host."""
    reach = float(np.max(np.linalg.norm(points, axis=1)))
    return reach, float(np.min(np.linalg.norm(positions, axis=1)))


def _amplitude_for(radar: Radar, poses, points: np.ndarray) -> _grt.Amplitude:
    """The kernels' `rift_jax._grt.Amplitude` for this radar at these ``poses`` (positions
    and orientations) and these points: its error bound from the antennas' largest
    separation and a lower bound on their distance to the points (and, where that calls
    for more than three terms, the points' own, `rift_jax._grt.largest_q`)."""
    if not radar.near_field:
        return _grt.Amplitude.of("far-field")
    antennas = max(float(np.max(np.linalg.norm(o, axis=1))) for o in radar.offsets)
    reach, distance = _reach(poses[0], points)
    bound = _grt.amplitude_bound(radar.separation, distance - reach - antennas)

    def largest():
        views = (antennas_at(radar, *pose) for pose in zip(*poses, strict=True))
        return _grt.largest_q(points, views)

    return _grt.Amplitude.of(radar.spreading, bound, largest)
