"""Support: the grid points a reconstruction may use; ρ = 0 everywhere else.

The paper's scenes fill 1-4 % of their box, yet every GRT call pays for every voxel. On a
support, the operator is simply `grt_operator` on fewer points (there is no second kernel),
so every solver's cost falls with the occupied volume. On exact data from the grid itself, a
support that contains the scene changes no least-squares answer (tested). Otherwise it is a
prior, and a strong one: on the paper's two-grid protocol it lifts LSMR's m-SSIM on the cube
from 0.28 to 0.97 (benchmarks/support.py). A support that misses part of the scene cannot
explain that part's data; `fit` reports how much the residual backprojects outside it.

Estimating a support from the data ("auto") is not here yet. A plain threshold of the
backprojection was measured not to be conservative: on random-primitive scenes it dropped
true scatterers at thresholds that still skip most of the grid.
"""

from __future__ import annotations

import numpy as np

from ._scenes import Scene


def as_mask(support, grid: Scene) -> np.ndarray:
    """A user's support (a boolean array of the grid's shape, or a `Scene` on the same grid
    whose non-zero voxels are the support) as a boolean (n, n, n) array."""
    if isinstance(support, Scene):
        if (support.extent, support.granularity) != (grid.extent, grid.granularity):
            raise ValueError(
                f"fit: the `support` Scene is on the grid ±{support.extent} m at "
                f"{support.granularity} m, but the reconstruction grid is ±{grid.extent} m at "
                f"{grid.granularity} m."
            )
        mask = np.asarray(support.reflectivity) != 0
    else:
        mask = np.asarray(support)
        if mask.dtype != bool:
            raise ValueError(
                "fit: `support` must be None, a boolean mask or a Scene, got an array of "
                f"dtype {mask.dtype}."
            )
        if mask.shape != grid.shape:
            raise ValueError(
                f"fit: the `support` mask must have the reconstruction grid's shape "
                f"{grid.shape} (±{grid.extent} m at {grid.granularity} m), got {mask.shape}."
            )
    if not mask.any():
        raise ValueError("fit: `support` holds no points; it must keep at least one.")
    mask = mask.copy()  # the result's own: a later change to the caller's array cannot move it
    mask.setflags(write=False)
    return mask


def mask_at(mask: np.ndarray, grid: Scene, points: np.ndarray) -> np.ndarray:
    """Whether each of ``points`` (metres) lies in a support voxel of ``grid``: the voxel
    whose centre is nearest (a point halfway between two takes the upper one), so a support
    carries over to any other grid's points. Voxel i sits at (i − (n − 1)/2)·granularity."""
    n = mask.shape[0]
    position = np.asarray(points, np.float64) / grid.granularity + (n - 1) / 2
    index = np.floor(position + 0.5).astype(np.int64)
    inside = np.all((index >= 0) & (index < n), axis=1)
    keep = np.zeros(len(index), bool)
    keep[inside] = mask[tuple(index[inside].T)]
    return keep
