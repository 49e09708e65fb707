"""The paper's four metrics (Section 3.3 and Appendix "Further Discussion on Metrics").

Scene metrics compare reflectivity *magnitudes* (the phase of ρ is not identifiable from the
paper's data: docs/conventions.md, 'Two-grid protocol'), each volume divided by its own
maximum. When a prediction and the truth live on different grids, the truth is resampled to
the prediction's grid with scikit-image first (the paper's protocol; `Scene.resample`). The
signal metric compares phases of signals at viewpoints that were not used for fitting.
"""

from __future__ import annotations

import numbers

import numpy as np
from scipy.optimize import linear_sum_assignment
from skimage.metrics import structural_similarity

from ._scenes import Scene
from ._synthesis import PointScatterers, RadarData
from ._validation import check_finite


def _magnitudes(pred, truth, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Both inputs as float64 |ρ| volumes on ``pred``'s grid, each divided by its max."""
    scenes = [x for x in (pred, truth) if isinstance(x, Scene)]
    if len(scenes) == 2 and pred.extent != truth.extent:
        raise ValueError(
            f"{where}: `pred` and `truth` must cover the same extent, got ±{pred.extent} m "
            f"and ±{truth.extent} m."
        )
    extent = scenes[0].extent if scenes else 1.0  # arrays are taken to span the same cube
    pred = _as_scene(pred, extent, f"{where}: `pred`")
    truth = _as_scene(truth, extent, f"{where}: `truth`")
    if truth.shape != pred.shape:
        truth = truth.resample(pred.granularity)
    return _unit_max(pred), _unit_max(truth)


def _as_scene(x, extent: float, name: str) -> Scene:
    if isinstance(x, Scene):
        return x
    arr = np.asarray(x)
    if arr.ndim != 3 or len(set(arr.shape)) != 1 or arr.shape[0] < 3:
        raise ValueError(
            f"{name} must be a Scene or a cubic (n, n, n) array with at least 3 points per "
            f"axis, got shape {arr.shape}."
        )
    return Scene.from_array(arr, extent)


def _unit_max(scene: Scene) -> np.ndarray:
    magnitude = np.abs(np.asarray(scene.reflectivity, np.complex128))
    peak = magnitude.max()
    return magnitude / peak if peak > 0 else magnitude


def m_ssim(pred, truth) -> float:
    """Mean SSIM of reflectivity magnitudes over 2-D slices along z.

    Each volume's |ρ| is divided by its own maximum (so both lie in [0, 1]); if the grids
    differ, ``truth`` is first resampled to ``pred``'s grid (`Scene.resample`). Then
    ``skimage.metrics.structural_similarity(p[:, :, k], t[:, :, k], data_range=1)`` (its default
    7×7 uniform window, or the largest odd window that fits a smaller grid) is averaged over
    the slices k.

    **Arguments:** `pred`, `truth`: `Scene`s, or cubic (n, n, n) arrays taken to span the same
    cube.

    **Returns:** m-SSIM in [-1, 1]; 1 for identical magnitudes.
    """
    p, t = _magnitudes(pred, truth, "m_ssim")
    side = p.shape[0]  # ≥ 3 (a Scene's grid has ≥ 3 points per axis)
    win_size = min(7, side if side % 2 else side - 1)
    return float(
        np.mean(
            [
                structural_similarity(p[:, :, k], t[:, :, k], data_range=1.0, win_size=win_size)
                for k in range(p.shape[2])
            ]
        )
    )


def m_cos(pred, truth) -> float:
    """Cosine similarity of the magnitude volumes, ``Σ|p||t| / (‖p‖ ‖t‖)`` (on ``pred``'s grid,
    as `m_ssim`). In [0, 1]; 1 when one magnitude volume is a positive multiple of the other;
    by convention 1 for two empty volumes and 0 when only one is empty."""
    p, t = _magnitudes(pred, truth, "m_cos")
    norms = np.linalg.norm(p) * np.linalg.norm(t)
    if norms == 0:
        return float(np.linalg.norm(p) == np.linalg.norm(t))
    return float(np.sum(p * t) / norms)


def t_iou(pred, truth, *, threshold: float = 0.2) -> float:
    """IoU of thresholded occupancy: voxels with ``|ρ| / max|ρ| ≥ threshold``, for both the
    prediction and the truth (on ``pred``'s grid, as `m_ssim`). For a truth on its own grid
    whose non-zero voxels are all at least ``threshold``·max, its occupancy is exactly its
    non-zero voxels. By convention 1 when both occupancies are empty."""
    if not 0 < threshold <= 1:
        raise ValueError(f"t_iou: `threshold` must be in (0, 1], got {threshold!r}.")
    p, t = _magnitudes(pred, truth, "t_iou")
    p_occ = p >= threshold
    t_occ = t >= threshold
    union = np.sum(p_occ | t_occ)
    return float(np.sum(p_occ & t_occ) / union) if union else 1.0


def p_rmse(pred_signal, true_signal) -> float:
    """RMSE, in radians, of the wrapped phase difference ``angle(p) − angle(t)`` ∈ [-π, π) over
    every sample (viewpoint, frequency, TX, RX) of the given signals.

    Use it on viewpoints that were not fitted. Magnitudes and a common scale do not enter;
    uniformly random phases give π/√3 ≈ 1.81 rad.

    **Arguments:** `pred_signal`, `true_signal`: `RadarData` or complex arrays of one shape.
    """
    p, t = (
        np.asarray(x.signal if isinstance(x, RadarData) else x) for x in (pred_signal, true_signal)
    )
    for name, x in (("pred_signal", p), ("true_signal", t)):
        if not np.iscomplexobj(x) and not np.issubdtype(x.dtype, np.number):
            raise ValueError(f"p_rmse: `{name}` must be a complex array, got {x.dtype}.")
        check_finite(x, f"p_rmse: `{name}`")
    if p.shape != t.shape or p.size == 0:
        raise ValueError(
            f"p_rmse: signals must have one non-empty shape, got {p.shape} and {t.shape}."
        )
    difference = np.angle(p.astype(np.complex128)) - np.angle(t.astype(np.complex128))
    phase = (difference + np.pi) % (2 * np.pi) - np.pi
    return float(np.sqrt(np.mean(phase**2)))


def match_points(found: PointScatterers | None, truth: PointScatterers, *, gate: float
                 ) -> dict[str, float]:  # fmt: skip
    """Point scatterers scored as detections: each found point matched to at most one true
    point within ``gate`` metres (a quarter wavelength, say: a point farther off predicts a
    different phase), as many pairs as can be, and of those the assignment of least total
    distance (scipy's ``linear_sum_assignment``).

    **Returns:** ``detected`` (matched true points), ``missed`` (true points unmatched),
    ``false_points`` (found points unmatched); over the matched pairs, the position error's
    ``position_max`` and ``position_rms`` (m) and ``amplitude_error``, the RMS of
    |a_found − a_true|/|a_true| (complex amplitudes in the truth's units; infinite for a
    true amplitude of 0). NaN without a match.

    **Arguments:** `found`: the points of a fit (`FitResult.points`; None when none was
    found); `truth`: the true ones; `gate`: the matching distance (m, > 0).
    """
    if not isinstance(truth, PointScatterers) or not (
        found is None or isinstance(found, PointScatterers)
    ):
        raise ValueError(
            "match_points: `found` and `truth` must be PointScatterers (`found` may be None), "
            f"got {type(found).__name__} and {type(truth).__name__}."
        )
    if not (isinstance(gate, numbers.Real) and gate > 0):
        raise ValueError(f"match_points: `gate` must be a distance > 0 (m), got {gate!r}.")
    positions = np.zeros((0, 3)) if found is None else found.points
    distance = np.linalg.norm(truth.points[:, None] - positions[None], axis=-1)
    # pairs beyond the gate cost more than any set of pairs within it: the matching then
    # keeps every pair it can within the gate (least total distance overall could pair a
    # miss with a false point far away, and give up a pair a millimetre apart for it)
    beyond = gate * (min(distance.shape) + 1)
    rows, columns = linear_sum_assignment(np.where(distance < gate, distance, beyond))
    kept = distance[rows, columns] < gate
    rows, columns = rows[kept], columns[kept]
    errors = distance[rows, columns]
    nan = float("nan")
    amplitude = nan
    if len(rows):
        true = np.asarray(truth.reflectivity, np.complex128)[rows]
        wrong = np.abs(np.asarray(found.reflectivity, np.complex128)[columns] - true)
        size = np.abs(true)
        relative = np.divide(wrong, size, out=np.full_like(wrong, np.inf), where=size > 0)
        amplitude = float(np.sqrt(np.mean(relative**2)))
    return {
        "detected": float(len(rows)),
        "missed": float(len(truth.points) - len(rows)),
        "false_points": float(len(positions) - len(rows)),
        "position_max": float(errors.max()) if len(rows) else nan,
        "position_rms": float(np.sqrt(np.mean(errors**2))) if len(rows) else nan,
        "amplitude_error": amplitude,
    }
