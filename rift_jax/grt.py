"""The GRT kernels for one viewpoint: `forward` (ρ → S) and its exact adjoint."""

from ._grt import adjoint as adjoint
from ._grt import forward as forward

__all__ = ["forward", "adjoint"]
