"""What the solvers share: argument checks, and the GRT as a real-linear map.

optimistix and jaxopt are built for real parameters (optimistix warns that its complex
support "may still return incorrect results"), so those adapters see ρ as the pair
(Re ρ, Im ρ). For the real inner product ⟨u, v⟩ = Re(uᴴv), the transpose of the realified
operator is the realified adjoint Aᴴ, which `realified` attaches with `linear_call` so that
linearisation and transposition (optimistix's Gauss-Newton) run the hand-written adjoint
kernel instead of JAX's ~10x slower transpose of the forward kernel.
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import linear_call
from jaxtyping import Array, Complex, Float

from .._operator import GRT, GRTOperator
from .._precision import exact_jit
from .._sharding import gathered, replicated
from .._validation import check_finite, check_positive_int
from ._solution import History, Outcome, Solution, Stop

RealPair = tuple[Float[Array, " *shape"], Float[Array, " *shape"]]


def as_pair(z: Complex[Array, " *shape"]) -> RealPair:
    return jnp.real(z), jnp.imag(z)


def as_complex(pair: RealPair) -> Complex[Array, " *shape"]:
    return jax.lax.complex(*pair)


def realified(fn: GRT):
    """ρ ↦ Aρ on (Re, Im) pairs for the `GRT` ``fn``, whose transpose (for linearize,
    linear_transpose, and so reverse-mode gradients) is Aᴴ."""

    def forward(_, pair):
        return as_pair(fn(as_complex(pair)))

    def transpose(_, pair):
        return as_pair(fn.adjoint(as_complex(pair)))

    return lambda pair: linear_call(forward, transpose, None, pair)


def check_problem(where: str, operator, signal, x0, iterations) -> tuple[Array, Array]:
    """Validate a solver's common arguments; return complex64 (signal, x0)."""
    if not isinstance(operator, GRTOperator) or operator.transposed or operator.conjugated:
        raise ValueError(
            f"{where}: `operator` must be the GRTOperator from rift_jax.grt_operator, got "
            f"{type(operator).__name__}."
        )
    check_positive_int(f"{where}: `iterations`", iterations)
    expected = operator.out_structure().shape
    signal = np.asarray(gathered(signal))
    if signal.shape != expected:
        raise ValueError(
            f"{where}: `signal` must have shape {expected} (n_views, n_freq, n_tx, n_rx) for "
            f"this operator, got {signal.shape}."
        )
    check_finite(signal, f"{where}: `signal`")
    n = operator.fn.n_points
    if x0 is None:
        x0 = np.zeros(n, np.complex64)
    x0 = np.asarray(x0)
    if x0.shape != (n,) or not np.all(np.isfinite(x0)):
        raise ValueError(f"{where}: `x0` must be a finite array of shape ({n},), got {x0.shape}.")
    return replicated((jnp.asarray(signal, jnp.complex64), jnp.asarray(x0, jnp.complex64)))


def relative(norm, reference) -> Array:
    """``norm / reference``, 0 for a zero reference (a zero signal is fitted exactly by 0)."""
    return jnp.where(reference > 0, norm / jnp.where(reference > 0, reference, 1), 0.0)


def zero_signal(where: str, signal: Array, x0: Array):
    """For an all-zero signal and start, the `Solution` every solver here gives: ρ = 0
    (minimum-norm least squares, and the fixed point of FISTA's shrinkage), with a warning.
    None otherwise."""
    if bool(jnp.any(signal != 0)) or bool(jnp.any(x0 != 0)):
        return None
    warnings.warn(
        f"{where}: the signal is all zero, so the reconstruction is the zero scene.",
        stacklevel=3,
    )
    return Solution(x0, History(np.zeros(0), np.zeros(0)), Stop(Outcome.ZERO_SIGNAL, 0))


def residual_of(fn: GRT, signal: Array, rho: Array) -> float:
    """The relative residual ‖y − Aρ‖/‖y‖: 1 for ρ = 0 (free, e.g. a solver's usual
    start), otherwise one forward pass (the operator's own compiled product, see
    `misfit`)."""
    if not bool(jnp.any(rho != 0)):
        return 1.0
    fn, signal, rho = replicated((fn, signal, rho))
    return float(misfit(fn(rho), signal))


# The viewpoints `fit`'s checks (residual, coherence, support leak) read at most, evenly
# spread, so that a 1000-view fit does not pay minutes for them. Up to this many they read
# every view, as RIFT's collapse check then does: their products share compiled programs.
DIAGNOSTIC_VIEWS = 100

# Diagnostics and set-up passes (a residual, a starting gain, a power iteration) call the
# operator's own jitted products and reduce their output in a small program of their own,
# rather than jitting a function that embeds the products: each such program compiled the
# whole GRT again (2-5 s each on the 2-core CPU; ~12 % of the test suite's time), while
# the operator's products on the same points are compiled once per fit anyway. Their
# inputs are `replicated` first: a jit compiles again for inputs placed otherwise.


@exact_jit
def misfit(prediction: Array, signal: Array) -> Array:
    """‖y − p‖/‖y‖ (0 for a zero ``signal``)."""
    return relative(jnp.linalg.norm(signal - prediction), jnp.linalg.norm(signal))


@exact_jit
def norms(*arrays: Array) -> tuple[Array, ...]:
    """‖x‖ of each of ``arrays``."""
    return tuple(jnp.linalg.norm(x) for x in arrays)
