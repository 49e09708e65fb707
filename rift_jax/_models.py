"""The scene as an implicit neural representation: xyz → complex reflectivity.

`RiftN` and `RiftS` are the paper's two INRs (Appendix "Model Structure"): one coordinate in
(scaled to [-1, 1]), (Re ρ, Im ρ) out; callers vmap. `Field` wraps one of them with the
scene's coordinate scale and a global complex gain, and is what training returns: a
continuous scene that renders on any grid.
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float, PRNGKeyArray

from ._precision import exact_jit, exact_products
from ._validation import check_positive, check_positive_int


class AbstractINR(eqx.Module):
    """An INR: ``model(xyz)`` with xyz in [-1, 1]³ gives (Re ρ, Im ρ), shape (2,).

    `learning_rate` is the Adam step the default training recipe uses for this kind of
    model."""

    learning_rate: ClassVar[float] = 1e-2

    @abc.abstractmethod
    def __call__(self, xyz: Float[Array, " 3"]) -> Float[Array, " 2"]:
        raise NotImplementedError


def _check_shape(where: str, width, depth):
    check_positive_int(f"{where}: `width`", width)
    check_positive_int(f"{where}: `depth`", depth)


class RiftN(AbstractINR):
    """RIFT(N): ``depth`` units of Linear → LeakyReLU → LayerNorm, then Linear → tanh.

    The paper fixes the width (64) but not the depth (its figure is not in the text); four
    hidden units is our default.
    """

    hidden: tuple[eqx.nn.Linear, ...]
    norms: tuple[eqx.nn.LayerNorm, ...]
    output: eqx.nn.Linear
    negative_slope: float = eqx.field(static=True)

    def __init__(
        self,
        *,
        width: int = 64,
        depth: int = 4,
        negative_slope: float = 0.01,
        key: PRNGKeyArray,
    ):
        _check_shape("RiftN", width, depth)
        keys = jax.random.split(key, depth + 1)
        sizes = [3] + [width] * depth
        self.hidden = tuple(
            eqx.nn.Linear(n_in, n_out, key=k)
            for n_in, n_out, k in zip(sizes, sizes[1:], keys, strict=False)
        )
        self.norms = tuple(eqx.nn.LayerNorm(width) for _ in range(depth))
        self.output = eqx.nn.Linear(width, 2, key=keys[-1])
        self.negative_slope = negative_slope

    @exact_products  # full float32 on every backend (no TF32), called alone or in a Field
    def __call__(self, xyz: Float[Array, " 3"]) -> Float[Array, " 2"]:
        h = xyz
        for linear, norm in zip(self.hidden, self.norms, strict=True):
            h = norm(jax.nn.leaky_relu(linear(h), self.negative_slope))
        return jnp.tanh(self.output(h))


class RiftS(AbstractINR):
    """RIFT(S): a SIREN. ``depth`` units sin(ω₀(Wx + b)), then sin(Wx + b) (the paper's
    output nonlinearity is also a sine).

    SIREN's initialisation (Sitzmann et al. 2020, Sec. 3.2): first-layer weights
    U(−1/n, 1/n), later weights U(−√(6/n)/ω₀, √(6/n)/ω₀) for fan-in n, so that
    pre-activations stay ~N(0, 1) through depth; biases as PyTorch's default.

    Its default learning rate is 1e-3, not RiftN's 1e-2: ω₀ multiplies every weight's
    effect on the pre-activations, so an Adam step of 1e-2 moves them by ~0.3 rad and
    training diverges (measured on the cube: m-SSIM 0.005 at 1e-2, 0.36 at 1e-3 after 20
    epochs).
    """

    learning_rate: ClassVar[float] = 1e-3

    hidden: tuple[eqx.nn.Linear, ...]
    output: eqx.nn.Linear
    omega_0: float = eqx.field(static=True)

    def __init__(
        self, *, width: int = 64, depth: int = 4, omega_0: float = 30.0, key: PRNGKeyArray
    ):
        _check_shape("RiftS", width, depth)
        check_positive("RiftS: `omega_0`", omega_0)
        keys = jax.random.split(key, 2 * (depth + 1))
        sizes = [3] + [width] * depth + [2]
        layers = []
        for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
            linear = eqx.nn.Linear(n_in, n_out, key=keys[2 * i])
            bound = 1 / n_in if i == 0 else math.sqrt(6 / n_in) / omega_0
            weight = jax.random.uniform(
                keys[2 * i + 1], linear.weight.shape, linear.weight.dtype, -bound, bound
            )
            layers.append(eqx.tree_at(lambda lin: lin.weight, linear, weight))
        self.hidden = tuple(layers[:-1])
        self.output = layers[-1]
        self.omega_0 = omega_0

    @exact_products  # full float32 on every backend (no TF32), called alone or in a Field
    def __call__(self, xyz: Float[Array, " 3"]) -> Float[Array, " 2"]:
        h = xyz
        for linear in self.hidden:
            h = jnp.sin(self.omega_0 * linear(h))
        return jnp.sin(self.output(h))


class HashGrid(AbstractINR):
    """A multiresolution hash encoding (Müller et al. 2022, "Instant neural graphics
    primitives"; the encoding DART uses) and a small MLP.

    ``levels`` grids over [-1, 1]³, their cells per axis growing geometrically from
    ``coarsest`` to ``finest``. Each level keeps ``features`` values per grid corner in a
    table of ``table_size`` entries: one entry per corner where the level has no more
    corners than entries, a spatial hash (the paper's, XOR of the coordinates times large
    primes) where it has more. A point's encoding is, per level, the trilinear blend of its
    cell's 8 corners, all levels concatenated; ``depth`` ReLU layers of ``width`` then
    map it to (Re ρ, Im ρ) through tanh. Tables start U(−1e-4, 1e-4), as the paper's.

    Unlike `RiftN` and `RiftS` it has no smoothness of its own beyond its coarse levels:
    each fine corner is a free parameter.
    """

    tables: Float[Array, "levels table features"]
    hidden: tuple[eqx.nn.Linear, ...]
    output: eqx.nn.Linear
    resolutions: tuple[int, ...] = eqx.field(static=True)

    def __init__(
        self,
        *,
        width: int = 64,
        depth: int = 2,
        levels: int = 8,
        features: int = 2,
        table_size: int = 2**14,
        coarsest: int = 4,
        finest: int = 64,
        key: PRNGKeyArray,
    ):
        _check_shape("HashGrid", width, depth)
        for name, value in (("levels", levels), ("features", features),
                            ("table_size", table_size), ("coarsest", coarsest)):  # fmt: skip
            check_positive_int(f"HashGrid: `{name}`", value)
        if not (isinstance(finest, int) and finest >= coarsest):
            raise ValueError(
                f"HashGrid: `finest` must be an int ≥ `coarsest` ({coarsest}), got {finest!r}."
            )
        growth = (finest / coarsest) ** (1 / max(levels - 1, 1))
        # rounded, and the last level exactly `finest` (float growth could miss it by one)
        resolutions = [round(coarsest * growth**level) for level in range(levels - 1)]
        self.resolutions = (*resolutions, finest) if levels > 1 else (coarsest,)
        keys = jax.random.split(key, depth + 2)
        self.tables = jax.random.uniform(keys[0], (levels, table_size, features),
                                         minval=-1e-4, maxval=1e-4)  # fmt: skip
        sizes = [levels * features] + [width] * depth
        self.hidden = tuple(
            eqx.nn.Linear(n_in, n_out, key=k)
            for n_in, n_out, k in zip(sizes, sizes[1:], keys[1:], strict=False)
        )
        self.output = eqx.nn.Linear(sizes[-1], 2, key=keys[-1])

    @exact_products  # full float32 on every backend (no TF32), called alone or in a Field
    def __call__(self, xyz: Float[Array, " 3"]) -> Float[Array, " 2"]:
        h = self.encode(xyz)
        for linear in self.hidden:
            h = jax.nn.relu(linear(h))
        return jnp.tanh(self.output(h))

    def encode(self, xyz: Float[Array, " 3"]) -> Float[Array, " levels_x_features"]:
        """The point's encoding: per level, its cell's corner features blended trilinearly."""
        u = jnp.clip((xyz + 1) / 2, 0.0, 1.0)
        table_size = self.tables.shape[1]
        encoded = []
        for level, n in enumerate(self.resolutions):
            position = u * n
            low = jnp.clip(jnp.floor(position), 0, n - 1)
            frac = position - low
            corners = low.astype(jnp.uint32) + _CORNERS  # (8, 3)
            if (n + 1) ** 3 <= table_size:  # dense: one entry per corner
                index = corners[:, 0] + (n + 1) * (corners[:, 1] + (n + 1) * corners[:, 2])
            else:
                index = (corners[:, 0] ^ (corners[:, 1] * jnp.uint32(2654435761))
                         ^ (corners[:, 2] * jnp.uint32(805459861))) % table_size  # fmt: skip
            weight = jnp.prod(jnp.where(_CORNERS == 1, frac, 1 - frac), axis=1)
            encoded.append(weight @ self.tables[level, index])
        return jnp.concatenate(encoded)


# the 8 corners of a cell, as offsets from its lowest one
# (NumPy, not jnp: a jnp constant at import would start JAX's backend)
_CORNERS = np.asarray([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)], np.uint32)

MODELS = {"rift-n": RiftN, "rift-s": RiftS, "hash-grid": HashGrid}


class Field(eqx.Module):
    """A continuous scene: ρ(x) = g · (Re + i Im)(model(x / extent)).

    - `model`: an `AbstractINR` (`RiftN`, `RiftS`, or your own).
    - `log_gain`, `phase`: the global complex gain g = exp(log_gain + i·phase). The INR's
      output is bounded (tanh, sine), while the reflectivity that explains normalised data
      can be any size; the gain carries the scale (and `fit` folds the data's scale into it).
    - `extent`: half-width of the scene (m), mapping it onto the INR's [-1, 1]³.
    """

    model: AbstractINR
    log_gain: Float[Array, ""]
    phase: Float[Array, ""]
    extent: float = eqx.field(static=True)

    def __init__(self, model: AbstractINR, extent: float, gain: complex = 1.0):
        if not isinstance(model, AbstractINR):
            raise ValueError(
                f"Field: `model` must be a rift_jax AbstractINR (RiftN, RiftS, ...), got "
                f"{type(model).__name__}."
            )
        check_positive("Field: `extent`", extent)
        if not (np.isfinite(gain) and gain != 0):
            raise ValueError(f"Field: `gain` must be finite and non-zero, got {gain!r}.")
        self.model = model
        self.log_gain = jnp.asarray(math.log(abs(gain)), jnp.float32)
        self.phase = jnp.asarray(np.angle(gain), jnp.float32)
        self.extent = float(extent)

    @property
    def gain(self) -> Complex[Array, ""]:
        return jnp.exp(jax.lax.complex(self.log_gain, self.phase))

    @exact_products  # a user's own AbstractINR too: full float32 on every backend (no TF32)
    def __call__(self, xyz: Float[Array, " 3"]) -> Complex[Array, ""]:
        re, im = self.model(xyz / self.extent)
        return self.gain * jax.lax.complex(re, im)

    @exact_jit  # full float32, and one tracing context wherever it is called from
    def render(self, points: Float[Array, "n 3"]) -> Complex[Array, " n"]:
        """ρ at each of ``points`` (metres), complex64. Evaluated in batches of 65,536 points,
        so that fine grids do not hold every hidden activation at once. Jitted: compiles
        once per model and number of points."""
        points = jnp.asarray(points, jnp.float32)
        batch = min(points.shape[0], 2**16)
        return jax.lax.map(self, points, batch_size=batch).astype(jnp.complex64)

    def scaled(self, factor: float) -> Field:
        """The same field with ρ multiplied by ``factor`` > 0."""
        check_positive("Field.scaled: `factor`", factor)
        return eqx.tree_at(lambda f: f.log_gain, self, self.log_gain + math.log(factor))
