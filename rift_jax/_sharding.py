"""Spreading GRT work over devices: viewpoints, or one view's voxels, one share per device.

On CPU, rift_jax starts JAX with one host device per core (`rift_jax/__init__.py`), because
XLA runs one small computation on about one core; on a GPU machine the devices are the GPUs;
after `jax.distributed.initialize` they are every process's devices. Both splits use
`jax.shard_map` on one mesh, `device_mesh()`: one axis, `DEVICES`, over `jax.devices()`.
One mesh, not one per split: an array's sharding names its mesh, and a jitted solver step
whose input came out of one split and goes back in beside arrays placed by another would
otherwise see a new sharding and compile again (every FISTA run compiled its step a second
time that way):

- **over viewpoints** (`over_views`): independent views, one share per device; outputs are
  concatenated, or summed (a backprojection) with one `psum`;
- **over voxels** (`over_voxels`): one view's voxels split between the devices. A forward's
  partial signals are added with one `psum` of n_freq·n_tx·n_rx numbers; an adjoint's
  per-voxel outputs are concatenated. This is what a single view (a plain `grt.forward`
  call, a row block) and batches of fewer views than devices use. Block Kaczmarz splits the
  voxels once for a whole sweep, with the same axis and padding (`kaczmarz._sweep`).

Nothing is split inside a `shard_map` (rift_jax's or the caller's): there, each call runs
whole on its device.

Padding (a view or voxel count that the devices do not divide) repeats the last point or
angle with zero data, and is sliced off or contributes nothing.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.sharding import AxisType
from jax.sharding import PartitionSpec as P

from ._precision import leading
from ._validation import is_concrete

DEVICES = "devices"


def device_mesh() -> jax.sharding.Mesh:
    """The one-axis mesh over every device (one per CPU core on CPU, see
    `rift_jax/__init__`) that every split and `replicated` use."""
    devices = jax.devices()
    return jax.make_mesh((len(devices),), (DEVICES,), devices=devices, axis_types=(AxisType.Auto,))


def replicated(tree):
    """``tree``'s arrays copied to every device (its other leaves as they are); inside a
    `jit`, constrained to be (where `jax.device_put` does not enforce it).

    Pass the inputs of a jitted *loop* around the operator (lineax, optimistix, jaxopt, a
    `fori_loop`) through this: XLA does not partition a jit whose inputs all sit on one
    device, and a `shard_map` nested in its loop then fails to compile on CPU ("No
    registered implementation for ... GlobalToLocalShape"). A loop step that returns its
    carry through it, and starts from a carry placed by it, compiles once. A jit compiles
    again for inputs placed otherwise, so calls that should share a compiled program (the
    operator's products in the solvers' and `fit`'s diagnostics) pass theirs through it.
    """
    if jax.device_count() == 1 or jax.sharding.get_abstract_mesh().manual_axes:
        return tree  # inside a `shard_map`, each device's values are its own
    arrays, rest = eqx.partition(tree, eqx.is_array)  # a solver state also holds functions
    everywhere = jax.sharding.NamedSharding(device_mesh(), P())
    if is_concrete(arrays):
        arrays = jax.device_put(arrays, everywhere)
    else:
        arrays = jax.lax.with_sharding_constraint(arrays, everywhere)
    return eqx.combine(arrays, rest)


def split_over_devices(x):
    """``x`` split along its leading axis (a multiple of the device count) over the
    devices, as a `shard_map` over `DEVICES` returns it: a loop whose step returns its
    carry split (Kaczmarz's ρ) starts from it so, and compiles once."""
    if jax.device_count() == 1:
        return x
    return jax.device_put(x, jax.sharding.NamedSharding(device_mesh(), P(DEVICES)))


def gathered(x):
    """``x`` whole in this process. After `jax.distributed.initialize`, an operator's output
    is split over every process's devices and no process holds all of it: it is gathered
    from all of them (`process_allgather`). Anything else is returned as it is."""
    if isinstance(x, jax.Array) and not x.is_fully_addressable:
        from jax.experimental import multihost_utils

        return jnp.asarray(multihost_utils.process_allgather(x, tiled=True))
    return x


def pad_leading(tree, pad: int, mode: str):
    """Every array of ``tree`` padded by ``pad`` entries along its leading axis (`jnp.pad`
    ``mode``: "edge" repeats the last point or angle, "constant" adds zeros)."""

    def one(x):
        return jnp.pad(x, ((0, pad),) + ((0, 0),) * (x.ndim - 1), mode=mode)

    return jax.tree.map(one, tree)


def over_views(local, azimuth, polar, data, *, reduce: bool):
    """Run ``local(azimuth, polar, data)`` on shards of the viewpoints, one per device.

    ``reduce=False``: ``data`` is replicated and per-view outputs are concatenated (padded
    views included; the caller slices them off). ``reduce=True``: ``data`` is per-view
    (sharded like the angles, zero for padding) and the per-device sums are added together.
    Fewer views than devices run outside any `shard_map`: each view then splits its voxels.
    """
    if not split_views(leading(azimuth), azimuth, polar, data):
        return local(azimuth, polar, data)
    pad = -leading(azimuth) % jax.device_count()
    azimuth, polar = pad_leading((azimuth, polar), pad, "edge")
    if reduce:
        data = pad_leading(data, pad, "constant")
        body = functools.partial(_summed, local)
        specs, out_spec = (P(DEVICES), P(DEVICES), P(DEVICES)), P()
    else:
        body = local
        specs, out_spec = (P(DEVICES), P(DEVICES), P()), P(DEVICES)
    mesh = device_mesh()
    return jax.shard_map(body, mesh=mesh, in_specs=specs, out_specs=out_spec)(azimuth, polar, data)


def pinned(tree) -> bool:
    """Whether any array of ``tree`` is committed to a single device (as after
    ``jax.device_put(x, device)``): work on it must stay there. Only concrete arrays show
    it; inside a `jit` their tracers do not, so the entry points ask before jitting."""
    return any(
        isinstance(x, jax.Array)
        and not isinstance(x, jax.core.Tracer)
        and x.committed
        and len(x.sharding.device_set) == 1
        for x in jax.tree.leaves(tree)
    )


def _splittable(arrays) -> bool:
    """Whether work may be split over the devices at all: there are several, this is not
    already inside a `shard_map` (rift_jax's own view split, Kaczmarz's voxel split, or the
    caller's), and no input is `pinned`."""
    if jax.device_count() == 1 or jax.sharding.get_abstract_mesh().manual_axes:
        return False
    return not pinned(arrays)


def split_views(n_views: int, *arrays) -> bool:
    """Whether ``n_views`` viewpoints are split over the devices: when `_splittable` and
    there is at least one view for each device. (A count the devices do not divide is padded
    with repeats of the last view: n_dev + 1 views cost about as much as 2·n_dev.)"""
    return _splittable(arrays) and n_views >= jax.device_count()


def split_voxels(n_points: int, chunk: int, *arrays) -> bool:
    """Whether one view's ``n_points`` voxels are split over the devices: when `_splittable`
    and each device gets at least one whole scan chunk (below that, the `psum` and the
    dispatch cost more than the arithmetic saved)."""
    return _splittable(arrays) and n_points >= jax.device_count() * chunk


def over_voxels(local, points, voxel_data, shared, *, reduce: bool):
    """Run ``local(points, voxel_data, shared)`` on shards of the voxels, one per device.

    ``points`` and ``voxel_data`` (ρ, or None) are split along their leading axis;
    ``shared`` (antennas, frequencies, a signal) is replicated. ``reduce=True``: the
    per-device outputs (partial signals) are summed; ``reduce=False``: they are per-voxel and
    concatenated, padding sliced off.
    """
    n_dev, n = jax.device_count(), leading(points)
    pad = -n % n_dev
    points = pad_leading(points, pad, "edge")
    voxel_data = pad_leading(voxel_data, pad, "constant")  # padded voxels carry ρ = 0
    body = functools.partial(_summed, local) if reduce else local
    out_spec = P() if reduce else P(DEVICES)
    out = jax.shard_map(
        body,
        mesh=device_mesh(),
        in_specs=(P(DEVICES), P(DEVICES), P()),
        out_specs=out_spec,
    )(points, voxel_data, shared)
    return out if reduce else out[:n]


def _summed(local, *args):
    return jax.lax.psum(local(*args), DEVICES)
