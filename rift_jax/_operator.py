"""The GRT over many viewpoints as one linear operator: ρ on grid points → stacked signals.

Every solver (Kaczmarz, LSMR, Gauss-Newton, FISTA, the INR) consumes the object that
`grt_operator` returns: a `lineax.FunctionLinearOperator` whose function is a `GRT` module.
`GRT` also exposes the per-viewpoint row blocks (`view`, `view_adjoint`) that block methods
use.

Viewpoints are independent, so they are spread over the available devices (with
`shard_map`; on CPU, rift_jax starts JAX with one host device per core, see
`rift_jax/__init__.py`) and mapped sequentially (CPU) or in vmapped batches (GPU) on each.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
from jax.sharding import AxisType
from jax.sharding import PartitionSpec as P
from jaxtyping import Array, Complex, Float

from . import _grt
from ._geometry import Radar, Viewpoints, antenna_positions
from ._precision import Float64Pair, leading, split, to_float64
from ._validation import as_finite_array, is_concrete


def _views_per_batch() -> int:
    """Viewpoints vmapped together on one device: one on CPU (each view already fills a core's
    caches), several on accelerators (which need the parallelism)."""
    return 1 if jax.default_backend() == "cpu" else 8


class GRT(eqx.Module):
    """The Generalized Radon Transform for a fixed radar, viewpoints and grid points.

    ``GRT(ρ)[i] = grt.forward(points, ρ, *antenna_positions(radar, az_i, pol_i), freqs)``,
    shape (n_views, n_freq, n_tx, n_rx); `adjoint` is its exact conjugate transpose.
    Viewpoint angles and points are array leaves held as float32 (hi, lo) pairs, so they keep
    float64 precision without x64 (`rift_jax._precision`); distances and phases are computed
    in float64, see `rift_jax.grt`.
    """

    radar: Radar = eqx.field(static=True)
    azimuth: Float64Pair
    polar: Float64Pair
    points: Float64Pair
    chunk_size: int | None = eqx.field(static=True, default=None)

    @property
    def n_views(self) -> int:
        return leading(self.azimuth)

    @property
    def n_points(self) -> int:
        return leading(self.points)

    @property
    def out_shape(self) -> tuple[int, int, int, int]:
        return (self.n_views, *self.radar.signal_shape)

    def _geometry(self, azimuth, polar):
        with jax.enable_x64(True):
            tx, rx = antenna_positions(self.radar, to_float64(azimuth), to_float64(polar))
        return self.points, tx, rx, self.radar.frequencies

    def _angles(self, index):
        if is_concrete(index) and not -self.n_views <= int(index) < self.n_views:
            raise ValueError(f"GRT: view `index` {index} out of range for {self.n_views} views.")
        return jax.tree.map(lambda a: a[index], (self.azimuth, self.polar))

    def view(self, rho: Complex[Array, " n_points"], index) -> Complex[Array, "f m n"]:
        """The signal of viewpoint ``index`` (may be traced): one row block of the operator."""
        rho = jnp.asarray(rho, jnp.complex64)
        return self._kernel(_grt._forward_kernel, rho, *self._angles(index))

    def view_adjoint(self, signal: Complex[Array, "f m n"], index) -> Complex[Array, " n_points"]:
        """Backprojection of one viewpoint's signal: the adjoint of `view`."""
        signal = jnp.asarray(signal, jnp.complex64)
        return self._kernel(_grt._adjoint_kernel, signal, *self._angles(index))

    def __call__(self, rho: Complex[Array, " n_points"]) -> Complex[Array, "v f m n"]:
        """All viewpoints' signals, (n_views, n_freq, n_tx, n_rx)."""
        rho = jnp.asarray(rho, jnp.complex64)
        if rho.shape != (self.n_points,):
            raise ValueError(f"GRT: `rho` must have shape ({self.n_points},), got {rho.shape}.")

        def local(azimuth, polar, rho):
            return jax.lax.map(
                lambda ap: self._kernel(_grt._forward_kernel, rho, *ap),
                (azimuth, polar),
                batch_size=_views_per_batch(),
            )

        return _over_views(local, self.azimuth, self.polar, rho, reduce=False)[: self.n_views]

    def adjoint(self, signal: Complex[Array, "v f m n"]) -> Complex[Array, " n_points"]:
        """Backprojection of all viewpoints, Σ_i view_adjoint(signal[i], i): the exact
        conjugate transpose of `__call__`."""
        signal = jnp.asarray(signal, jnp.complex64)
        if signal.shape != self.out_shape:
            raise ValueError(
                f"GRT.adjoint: `signal` must have shape {self.out_shape}, got {signal.shape}."
            )

        def local(azimuth, polar, signal):
            def step(acc, xs):
                a, p, s = xs
                return acc + self._kernel(_grt._adjoint_kernel, s, a, p), None

            leaves = jax.tree.leaves((azimuth, polar))  # per-device inside shard_map
            zero = _grt._zeros((self.n_points,), signal.dtype, *leaves)
            return jax.lax.scan(step, zero, (azimuth, polar, signal))[0]

        return _over_views(local, self.azimuth, self.polar, signal, reduce=True)

    def _kernel(self, kernel, data, azimuth, polar):
        points, tx, rx, freqs = self._geometry(azimuth, polar)
        return kernel(
            points,
            tx,
            rx,
            None,
            data,
            plan=_grt.frequency_plan(freqs),
            near_field=self.radar.near_field,
            chunk=self.chunk_size,
        )


_AXIS = "views"


def _over_views(local, azimuth, polar, data, *, reduce: bool):
    """Run ``local(azimuth, polar, data)`` on shards of the viewpoints, one per device.

    ``reduce=False``: ``data`` is replicated and per-view outputs are concatenated (padded
    views included; the caller slices them off). ``reduce=True``: ``data`` is per-view (sharded
    like the angles, zero for padding) and the per-device sums are added together.
    """
    devices = jax.devices()
    n_dev = len(devices)
    n_views = leading(azimuth)
    if n_dev == 1 or n_views < n_dev:
        return local(azimuth, polar, data)
    pad = -n_views % n_dev
    azimuth, polar = jax.tree.map(lambda a: jnp.pad(a, (0, pad)), (azimuth, polar))
    mesh = jax.make_mesh((n_dev,), (_AXIS,), devices=devices, axis_types=(AxisType.Auto,))
    if reduce:
        data = jnp.pad(data, ((0, pad),) + ((0, 0),) * (data.ndim - 1))
        body = functools.partial(_summed, local)
        specs, out_spec = (P(_AXIS), P(_AXIS), P(_AXIS)), P()
    else:
        body = local
        specs, out_spec = (P(_AXIS), P(_AXIS), P()), P(_AXIS)
    return jax.shard_map(body, mesh=mesh, in_specs=specs, out_specs=out_spec)(azimuth, polar, data)


def _summed(local, azimuth, polar, data):
    return jax.lax.psum(local(azimuth, polar, data), _AXIS)


def grt_operator(
    radar: Radar,
    viewpoints: Viewpoints,
    grid_points: Float[Array, "n_points 3"],
    *,
    chunk_size: int | None = None,
) -> lx.FunctionLinearOperator:
    """The GRT over ``viewpoints`` as a lineax linear operator.

    **Arguments:**

    - `radar`: a `Radar`.
    - `viewpoints`: a `Viewpoints` (the operator's row blocks, in order).
    - `grid_points`: (V, 3) points (metres) on which ρ lives, e.g. ``Scene.points()``.
    - `chunk_size`: voxels per scan step inside the kernel (None: `rift_jax.grt` default).

    **Returns:** a `lineax.FunctionLinearOperator` from complex64 ρ of shape (V,) to signals of
    shape (n_views, n_freq, n_tx, n_rx). Its `.fn` is the `GRT` module (row blocks via
    ``.fn.view``/``.fn.view_adjoint``, backprojection via ``.fn.adjoint``); its transpose, and
    every gradient through it, runs the hand-written adjoint kernel.
    """
    if not isinstance(radar, Radar):
        raise ValueError(
            f"grt_operator: `radar` must be a rift_jax.Radar, got {type(radar).__name__}."
        )
    if not isinstance(viewpoints, Viewpoints):
        raise ValueError(
            "grt_operator: `viewpoints` must be rift_jax.Viewpoints, got "
            f"{type(viewpoints).__name__}."
        )
    points = as_finite_array(grid_points, "grt_operator: `grid_points`", np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] == 0:
        raise ValueError(
            f"grt_operator: `grid_points` must have shape (V, 3) with V ≥ 1, got {points.shape}."
        )
    if chunk_size is not None and (not isinstance(chunk_size, int) or chunk_size < 1):
        raise ValueError(
            f"grt_operator: `chunk_size` must be a positive integer, got {chunk_size!r}."
        )
    fn = GRT(radar, split(viewpoints.azimuth), split(viewpoints.polar), split(points), chunk_size)
    structure = jax.ShapeDtypeStruct((points.shape[0],), jnp.complex64)
    # No closure conversion: `fn` is already a pytree (a `GRT` module), and keeping it as one
    # lets solvers reach the row blocks through `operator.fn`.
    return lx.FunctionLinearOperator(fn, structure, closure_convert=False)
