"""The paper's metrics: identities, hand-computed cases, agreement with scikit-image."""

import numpy as np
import pytest
from skimage.metrics import structural_similarity

import rift_jax as rj
from rift_jax.metrics import m_cos, m_ssim, match_points, p_rmse, t_iou


@pytest.fixture
def volume(rng):
    return rng.normal(size=(9, 9, 9)) + 1j * rng.normal(size=(9, 9, 9))


def test_identical_inputs(volume, rng):
    scene = rj.Scene.from_array(volume, 2.0)
    assert m_ssim(scene, scene) == pytest.approx(1.0)
    assert m_cos(scene, scene) == pytest.approx(1.0)
    assert t_iou(scene, scene) == 1.0
    signal = rng.normal(size=(3, 4, 2, 2)) + 1j * rng.normal(size=(3, 4, 2, 2))
    assert p_rmse(signal, signal) == 0.0


def test_magnitudes_only_and_scale_free(volume):
    """Every scene metric sees |ρ| / max|ρ|: phase and overall scale do not count."""
    other = 3.0 * np.abs(volume) * np.exp(1j * 0.7)
    assert m_ssim(other, volume) == pytest.approx(1.0)
    assert m_cos(other, volume) == pytest.approx(1.0)
    assert t_iou(other, volume) == 1.0


def test_m_ssim_is_scikit_image_on_z_slices(volume, rng):
    truth = rng.uniform(size=(9, 9, 9))
    p, t = np.abs(volume) / np.abs(volume).max(), truth / truth.max()
    expected = np.mean(
        [structural_similarity(p[:, :, k], t[:, :, k], data_range=1.0) for k in range(9)]
    )
    assert m_ssim(volume, truth) == pytest.approx(expected, rel=1e-5)
    # along z, not x: a volume that differs only in its slice order along z scores the same
    assert m_ssim(volume[:, :, ::-1], truth[:, :, ::-1]) == pytest.approx(expected, rel=1e-5)


def test_m_ssim_small_grid_uses_a_smaller_window():
    a = np.zeros((5, 5, 5))
    a[2, 2, 2] = 1
    assert m_ssim(a, a) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="at least 3 points per axis"):
        m_ssim(np.ones((2, 2, 2)), np.ones((2, 2, 2)))


def test_m_cos_hand_computed():
    a = np.zeros((3, 3, 3))
    b = np.zeros((3, 3, 3))
    a[0, 0, 0] = 1
    b[0, 0, 0] = b[1, 1, 1] = 1
    assert m_cos(a, b) == pytest.approx(1 / np.sqrt(2))
    assert m_cos(a, np.zeros((3, 3, 3))) == 0.0


def test_t_iou_hand_computed():
    pred = np.zeros((3, 3, 3))
    truth = np.zeros((3, 3, 3))
    pred[0, 0, 0], pred[0, 0, 1], pred[0, 0, 2] = 1.0, 0.5, 0.1  # 0.1 < 0.2: not occupied
    truth[0, 0, 0] = truth[1, 1, 1] = 2.0
    assert t_iou(pred, truth) == pytest.approx(1 / 3)  # {000} / {000, 001, 111}
    assert t_iou(pred, truth, threshold=0.05) == pytest.approx(1 / 4)
    with pytest.raises(ValueError, match="`threshold`"):
        t_iou(pred, truth, threshold=0.0)


def test_p_rmse_hand_computed_and_wrapped():
    t = np.ones((2, 3, 1, 1), complex)
    assert p_rmse(1j * t, t) == pytest.approx(np.pi / 2)
    # a phase difference of 3π/2 is -π/2 once wrapped
    assert p_rmse(np.exp(1.5j * np.pi) * t, t) == pytest.approx(np.pi / 2)
    half = t.copy()
    half[0] *= np.exp(0.3j)
    assert p_rmse(half, t) == pytest.approx(np.sqrt(0.3**2 / 2))
    with pytest.raises(ValueError, match="one non-empty shape"):
        p_rmse(t, t[:1])
    with pytest.raises(ValueError, match="`pred_signal` must be finite"):
        p_rmse(np.full_like(t, np.nan), t)


def test_truth_is_resampled_to_the_prediction_grid():
    fine = rj.scenes.cube(0.5, extent=2.0, edge=1.0)
    coarse = fine.resample(1.0)
    assert m_ssim(coarse, fine) == pytest.approx(m_ssim(coarse, coarse), abs=1e-12)
    assert t_iou(coarse, fine) == t_iou(coarse, fine.resample(1.0))
    with pytest.raises(ValueError, match="same extent"):
        m_cos(rj.scenes.cube(0.5, extent=2.0), rj.scenes.cube(0.5, extent=3.0))


def test_bad_shapes():
    with pytest.raises(ValueError, match="`pred` must be a Scene or a cubic"):
        m_cos(np.ones((3, 3)), np.ones((3, 3, 3)))


def test_match_points_hand_computed():
    """Two of three true points found (10 and 20 µm off, amplitudes 10 % and 0 % wrong), one
    false point beside a missed one: the nearest one-to-one matching within the gate."""
    truth = rj.PointScatterers([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], [1, 2j, -1], 1.0)
    found = rj.PointScatterers([[0.1, 20e-6, 0], [10e-6, 0, 0], [0, 0.1, 0.01]], [2j, 1.1, -1], 1.0)
    scores = match_points(found, truth, gate=1e-3)
    assert (scores["detected"], scores["missed"], scores["false_points"]) == (2, 1, 1)
    assert scores["position_max"] == pytest.approx(20e-6)
    assert scores["position_rms"] == pytest.approx(np.sqrt((10e-6**2 + 20e-6**2) / 2))
    assert scores["amplitude_error"] == pytest.approx(np.sqrt(0.1**2 / 2), rel=1e-6)
    # a wider gate takes the false point for the missed one
    assert match_points(found, truth, gate=0.02)["detected"] == 3
    # a miss far from a false point does not cost the match a millimetre apart
    far = rj.PointScatterers([[0, 0, 0], [0.9, 0, 0]], [1, 1], 1.0)
    near_and_false = rj.PointScatterers([[1e-3, 0, 0], [-0.9, 0, 0]], [1, 1], 1.0)
    crossed = match_points(near_and_false, far, gate=0.01)
    assert (crossed["detected"], crossed["missed"], crossed["false_points"]) == (1, 1, 1)
    assert crossed["position_max"] == pytest.approx(1e-3)
    nothing = match_points(None, truth, gate=1e-3)
    assert (nothing["detected"], nothing["missed"], nothing["false_points"]) == (0, 3, 0)
    assert np.isnan(nothing["position_rms"]) and np.isnan(nothing["amplitude_error"])
    with pytest.raises(ValueError, match="`gate` must be a distance > 0"):
        match_points(found, truth, gate=0)
    with pytest.raises(ValueError, match="`found` and `truth` must be PointScatterers"):
        match_points(found, truth.points, gate=1e-3)
