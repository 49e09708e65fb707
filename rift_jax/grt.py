"""The GRT kernels for one viewpoint: `forward` (ρ → S) and its exact adjoint, and the
relative error that their separable spreading factor may put on any term
(`AMPLITUDE_TOLERANCE`)."""

from ._grt import AMPLITUDE_TOLERANCE as AMPLITUDE_TOLERANCE
from ._grt import adjoint as adjoint
from ._grt import forward as forward

__all__ = ["forward", "adjoint", "AMPLITUDE_TOLERANCE"]
