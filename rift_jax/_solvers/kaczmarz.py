"""Randomised block Kaczmarz, the paper's least-squares baseline (Section 4, Appendix
"Optimization Details": "100 iterations of block-Kaczmarz")."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec as P
from jaxtyping import Array, Complex

from .._operator import GRT, GRTOperator
from .._precision import Float64Pair, exact_jit
from .._sharding import VOXELS, device_mesh, pad_leading
from ._common import check_problem, relative, zero_signal
from ._solution import Solution, iterate


def kaczmarz(
    operator: GRTOperator,
    signal: Complex[Array, "n_views n_freq n_tx n_rx"],
    *,
    iterations: int = 100,
    relaxation: float = 1.0,
    tol: float = 0.0,
    seed: int = 0,
    x0: Complex[Array, " n_points"] | None = None,
    progress: bool = True,
) -> Solution:
    """Block Kaczmarz with one viewpoint per block, in a random order.

    **What an iteration is:** one sweep over every block (viewpoint) once, in a fresh random
    order drawn from ``seed``. The paper's default is 100 iterations.

    **The block update** for viewpoint b, with rows A_b and data y_b:

        r = y_b − A_b ρ,   g = A_bᴴ r,   ρ ← ρ + λ (‖g‖² / ‖A_b g‖²) g

    The step is the exact line search along the block's steepest-descent direction, which is
    the first CGLS step toward the block projection ρ + A_b⁺ r of classic block Kaczmarz. (An
    exact projection needs an inner solve per block: A_b has 25,600 rows.) The update costs
    three one-viewpoint kernel calls; for 0 < λ < 2 it never increases the block's residual.

    **Both cores on one block:** the blocks are sequential, so the voxels are split over the
    devices instead (one per CPU core). Each device keeps its share of ρ and adds its partial
    signals with one `psum` of 25,600 numbers.

    **Arguments:**

    - `operator`: the `GRTOperator` from `rift_jax.grt_operator`.
    - `signal`: measured signals, (n_views, n_freq, n_tx, n_rx), rows of ``operator``.
    - `iterations`: sweeps.
    - `relaxation`: λ in (0, 2).
    - `tol`: stop early when the residual stagnates (see `Solution`); 0 runs every sweep.
    - `seed`: seeds the block orders.
    - `x0`: starting ρ (default 0), e.g. a previous run's result to resume it.
    - `progress`: show a progress bar on runs longer than two seconds.

    **Returns:** a `Solution`. ``history.residual[k]`` is sqrt(Σ_b ‖r_b‖²)/‖y‖ over sweep k,
    each block's residual measured before its update: free, and close to the residual at
    the end of the sweep once the iterate changes little.
    """
    signal, x = check_problem("kaczmarz", operator, signal, x0, iterations)
    if not 0 < relaxation < 2:
        raise ValueError(f"kaczmarz: `relaxation` must be in (0, 2), got {relaxation!r}.")
    if (solution := zero_signal("kaczmarz", signal, x)) is not None:
        return solution
    fn = operator.fn
    n_points, n_dev = fn.n_points, jax.device_count()
    pad = -n_points % n_dev
    points = pad_leading(fn.points, pad, "edge")
    mask = jnp.arange(n_points + pad) < n_points  # padding voxels never move
    x = pad_leading(x, pad, "constant")
    norm = jnp.linalg.norm(signal)
    rng = np.random.default_rng(seed)
    lam = jnp.float32(relaxation)

    def step(x):
        order = jnp.asarray(rng.permutation(fn.n_views))
        x, squares = _sweep(fn, points, mask, x, signal, order, lam)
        return x, relative(jnp.sqrt(squares), norm)

    x, history, stopped = iterate(
        step, x, iterations=iterations, tol=tol, progress=progress, desc="kaczmarz"
    )
    return Solution(x[:n_points], history, stopped, {"relaxation": relaxation})


@exact_jit
def _sweep(fn: GRT, points, mask, x, signal, order, lam):
    """One sweep, ``-> (ρ, Σ_b ‖r_b‖²)``, with the voxels (points, mask, ρ) split over the
    devices. Module-level and jitted on its arguments, so repeated runs of one problem size
    compile once."""
    n_dev = jax.device_count()

    def body(points, mask, x, signal, order, lam):
        local = eqx.tree_at(lambda f: f.points, fn, points)
        total = (lambda v: jax.lax.psum(v, VOXELS)) if n_dev > 1 else (lambda v: v)

        def block(k, carry):
            x, squares = carry
            i = order[k]
            r = signal[i] - total(local.view(x, i))  # inside shard_map: views do not split
            g = jnp.where(mask, local.view_adjoint(r, i), 0)
            q = total(local.view(g, i))
            gg = total(jnp.vdot(g, g).real)
            qq = jnp.vdot(q, q).real
            alpha = jnp.where(qq > 0, gg / jnp.where(qq > 0, qq, 1), 0)
            return x + (lam * alpha) * g, squares + jnp.vdot(r, r).real

        return jax.lax.fori_loop(0, order.shape[0], block, (x, jnp.zeros((), jnp.float32)))

    if n_dev == 1:
        return body(points, mask, x, signal, order, lam)
    voxels = P(VOXELS)
    return jax.shard_map(
        body,
        mesh=device_mesh(VOXELS),
        in_specs=(Float64Pair(voxels, voxels), voxels, voxels, P(), P(), P()),
        out_specs=(voxels, P()),
    )(points, mask, x, signal, order, lam)
