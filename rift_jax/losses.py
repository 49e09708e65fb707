"""Data terms for INR training (`rift_jax.solvers.Recipe.loss`)."""

from ._losses import LOSSES as LOSSES
from ._losses import complex_mse as complex_mse
from ._losses import paper_loss as paper_loss
from ._losses import robust_loss as robust_loss

__all__ = ["paper_loss", "robust_loss", "complex_mse", "LOSSES"]
