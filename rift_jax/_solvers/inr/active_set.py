"""Where RIFT trains: the candidate points of a stage and the active set chosen among them.

With a recipe's ``prune``, a step trains only the points where the field lives (|ρ| at
least ``prune`` of its peak, and their neighbours); the set is padded to a size that
changes rarely, since the step compiles once per size, and a smaller size is compiled only
where the work it saves outweighs a compilation (`COMPILE_WORK`).
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.spatial
from jaxtyping import Array, Complex, Float

from ..._models import Field
from ..._operator import GRT
from ..._padding import ladder_size
from ..._sharding import replicated

# What a RIFT step's compilation is worth in point-measurements (one point's contribution to
# one measurement, forward and backward): a step compiles in ~4-5 s on the 2-core CPU
# (measured), in which its forward and backward pass cover ~2.5·10⁹ point-measurements a
# second (the GRT benchmark's forward rate, 6.5·10⁹ a second, over ~2.6 for the backward).
# A set keeps its padded size while the padding's share of the remaining steps costs less
# than this. A constant, not a timing, so that runs repeat exactly; on a GPU, where steps
# are ~40× faster and compilations not, it errs towards compiling.
COMPILE_WORK = 1e10


class Candidates:
    """The points a RIFT stage may train (the GRT `fn`'s) and how to pick its active set.

    ``coords`` are the points divided by ``scale``, the extent of the field they are for:
    the training's field, which maps ±1 onto its INR's cube (see
    `rift_jax._solvers.inr.training`), renders at them what a field of extent ``scale``
    renders at ``points``."""

    def __init__(self, fn: GRT, points: np.ndarray, scale: float = 1.0):  # points: float64
        self.fn, self.points, self.scale = fn, points, float(scale)
        # the points that exist: an operator padded to a shared size (`grt_operator`'s
        # pad_to) holds copies of one of them, which must never join an active set
        self.live = fn.live_points()
        self.n_live = int(self.live.sum())
        self.coords = _in_frame(jnp.asarray(points, jnp.float32), self.scale)
        self.tree = scipy.spatial.cKDTree(points)
        if len(points) > 1:  # neighbours: within √3 spacings (the 26 around a grid point)
            distance, _ = self.tree.query(points, k=2)
            spacing = np.min(distance[:, 1][distance[:, 1] > 0], initial=np.inf)
            self.radius = 1.01 * math.sqrt(3) * spacing if np.isfinite(spacing) else 0.0
        else:
            self.radius = 0.0

    def select(self, field: Field, prune: float) -> np.ndarray:
        """The sorted indices of the live points where |ρ| ≥ prune · max |ρ| for ``field``
        (in the frame of `coords`: of extent 1 when ``scale`` is not), and their live
        neighbours."""
        assert self.scale == 1.0 or field.extent == 1.0, "scaled coords: a field of extent 1"
        magnitude = np.where(self.live, np.abs(np.asarray(field.render(self.coords))), 0)
        seeds = np.flatnonzero(self.live & (magnitude >= prune * magnitude.max()))
        near = self.tree.query_ball_point(self.points[seeds], self.radius, return_sorted=False)
        chosen = np.unique(np.concatenate([seeds, *map(np.asarray, near)]).astype(np.int64))
        return chosen[self.live[chosen]]

    def restricted(
        self,
        active: np.ndarray | None,
        current: StepPoints | None = None,
        point_cost: float | None = None,
    ) -> StepPoints:
        """The points a step trains: the active ones (all for None), replicated.

        An active set is padded to a size that changes rarely: the step is compiled for
        the number of points, and at the paper's cube each new size added 6-9 s to its
        epoch, against ~0.8 s for an epoch that compiles nothing (measured). ``current``'s
        size is kept while the set fits in it and fills at least two thirds of it (each
        step's cost follows the padded size), or, given ``point_cost`` (the work one point
        adds to the rest of the training, in point-measurements), while the padding beyond
        the set's own size costs less than a compilation (`COMPILE_WORK`): small problems
        then compile one step. Otherwise the set gets the next size of a ladder growing
        ~1.25x (`rift_jax._padding.ladder_size`). Padding repeats the first active point,
        not live (`GRT.live`: ρ = 0 there), so it adds nothing to the signals or
        gradients. Every set, all the points too, carries `live`, so that one program
        serves every set of a size."""
        if active is None:
            fn = self.fn
            if fn.live is None:
                fn = fn.on(fn.points, jnp.asarray(self.live))
            return replicated(StepPoints(fn, self.coords))
        n, limit = len(active), len(self.points)
        own = min(ladder_size(n), limit)
        size = None if current is None else current.n_points
        fits = size is not None and n <= size
        cheap = fits and point_cost is not None and (size - own) * point_cost <= COMPILE_WORK
        if not (fits and (size <= 1.5 * n or cheap)):
            size = own
        index = np.concatenate([active, np.full(size - n, active[0])])
        live = np.arange(size) < n
        points = jax.tree.map(lambda a: a[index], self.fn.points)
        return replicated(StepPoints(self.fn.on(points, jnp.asarray(live)), self.coords[index]))


@functools.partial(jax.jit, static_argnums=1)
def _in_frame(points: Float[Array, "n 3"], extent: float) -> Float[Array, "n 3"]:
    """``points / extent`` as `Field` divides them inside its programs, the extent a constant
    (XLA may multiply by its reciprocal instead, and on CPU does): bit for bit the
    coordinates a field of that extent gives its INR, on every backend."""
    return points / extent


class StepPoints(eqx.Module):
    """What a RIFT step trains: the GRT on its points and their float32 coordinates in the
    field's frame (`Candidates.coords`; the GRT's `live` marks padding, where ρ counts as
    0)."""

    fn: GRT
    coords: Float[Array, "k 3"]

    @property
    def n_points(self) -> int:
        return len(self.coords)

    def render(self, field: Field) -> Complex[Array, " k"]:
        return field.render(self.coords)
