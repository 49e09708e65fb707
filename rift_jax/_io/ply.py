"""A reconstruction's bright voxels as a PLY point cloud, which common 3-D viewers open."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._scenes import Scene
from .._synthesis import PointScatterers
from .._version import __version__
from .atomic import write_atomic


def export_ply(
    path: str | os.PathLike,
    scene_or_result,
    *,
    threshold: float = 0.1,
) -> Path:
    """Write a reconstruction's bright voxels as a PLY point cloud, which MeshLab,
    CloudCompare, ParaView and Blender open.

    Each voxel with ``|ρ| ≥ threshold · max |ρ|`` becomes a vertex with properties ``x``,
    ``y``, ``z`` (m, float32), ``magnitude`` (|ρ|) and ``phase`` (arg ρ, rad), both float32
    scalar fields, and ``red``, ``green``, ``blue`` (uchar): |ρ| / max |ρ| through the
    viridis colour map, so a viewer shows the brightness at once. Binary little-endian,
    written atomically.

    **Arguments:**

    - `path`: a ``.ply`` file.
    - `scene_or_result`: a `Scene`, a `FitResult` (its `scene`; for ``method="points"``,
      its `points`), or `PointScatterers`.
    - `threshold`: in (0, 1], relative to the brightest voxel (as `rift_jax.metrics.t_iou`).

    **Returns:** the path written. An all-zero scene gives a valid file with no vertices.
    """
    where = "export_ply"
    if not isinstance(path, str | os.PathLike) or Path(path).suffix.lower() != ".ply":
        raise ValueError(f"{where}: `path` must be a .ply file, got {path!r}.")
    path = Path(path)
    if (
        isinstance(threshold, bool)
        or not isinstance(threshold, int | float | np.number)
        or not (0 < threshold <= 1)
    ):
        raise ValueError(f"{where}: `threshold` must be in (0, 1], got {threshold!r}.")
    if isinstance(scene_or_result, Scene | PointScatterers):
        source = scene_or_result
    elif getattr(scene_or_result, "points", None) is not None:
        source = scene_or_result.points  # a FitResult of method="points": its scatterers
    elif hasattr(scene_or_result, "scene") and isinstance(scene_or_result.scene, Scene):
        source = scene_or_result.scene  # a FitResult
    else:
        raise ValueError(
            f"{where}: `scene_or_result` must be a rift_jax Scene, FitResult or "
            f"PointScatterers, got {type(scene_or_result).__name__}."
        )
    if isinstance(source, Scene):
        points, rho = source.points(), np.asarray(source.reflectivity).ravel()
    else:
        points, rho = np.asarray(source.points), np.asarray(source.reflectivity)
    magnitude = np.abs(rho)
    peak = float(magnitude.max()) if magnitude.size else 0.0
    keep = magnitude >= threshold * peak if peak > 0 else np.zeros(magnitude.shape, bool)
    if not path.parent.is_dir():
        raise ValueError(
            f"{where}: `path` must be in an existing folder; {str(path.parent)!r} is not."
        )
    write_atomic(path, lambda f: f.write(_ply_bytes(points[keep], rho[keep], peak)))
    return path


# A PLY writer is a header and one structured array: ~20 lines of NumPy. The well-kept
# readers/writers (plyfile, meshio) would add a dependency for every user for that; the
# tests read the files back with plyfile, an independent implementation of the format.
_PLY_VERTEX = np.dtype(
    [
        ("x", "<f4"),
        ("y", "<f4"),
        ("z", "<f4"),
        ("magnitude", "<f4"),
        ("phase", "<f4"),
        ("red", "u1"),
        ("green", "u1"),
        ("blue", "u1"),
    ]
)
_PLY_TYPES = {"<f4": "float", "|u1": "uchar"}


def _ply_bytes(points: np.ndarray, rho: np.ndarray, peak: float) -> bytes:
    from matplotlib import colormaps

    vertices = np.empty(len(points), _PLY_VERTEX)
    for i, axis in enumerate("xyz"):
        vertices[axis] = points[:, i]
    vertices["magnitude"], vertices["phase"] = np.abs(rho), np.angle(rho)
    if len(points):
        colours = colormaps["viridis"](np.abs(rho) / peak, bytes=True)
        vertices["red"], vertices["green"], vertices["blue"] = colours[:, :3].T
    lines = [
        "ply",
        "format binary_little_endian 1.0",
        f"comment rift_jax {__version__}: voxels with |rho| >= threshold * max |rho|; "
        "x y z in metres, phase in radians",
        f"element vertex {len(points)}",
        *(f"property {_PLY_TYPES[_PLY_VERTEX[n].str]} {n}" for n in _PLY_VERTEX.names),
        "end_header",
    ]
    return ("\n".join(lines) + "\n").encode("ascii") + vertices.tobytes()
