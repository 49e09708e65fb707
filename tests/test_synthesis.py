import jax.numpy as jnp
import numpy as np
import pytest
from conftest import relative_error

import rift_jax as rj


@pytest.fixture(scope="module")
def scene():
    return rj.scenes.pyramid(0.4)


def test_synthesize_normalises_and_keeps_the_scale(scene, small_radar):
    vps = rj.Viewpoints.grid(3, 2)
    data = rj.synthesize(scene, vps, small_radar)
    assert isinstance(data, rj.RadarData)
    assert data.signal.shape == (6, 12, 4, 5) and data.signal.dtype == jnp.complex64
    assert float(jnp.max(jnp.abs(data.signal))) == pytest.approx(1.0, rel=1e-6)
    # Skipping empty space changes nothing: the full grid gives the same raw signal.
    full = rj.grt_operator(small_radar, vps, scene.points()).mv(scene.reflectivity.ravel())
    assert relative_error(data.signal * data.scale, full) < 1e-5


def test_noise_has_the_requested_snr_and_is_seeded(scene, small_radar):
    vps = rj.Viewpoints.grid(4, 4)
    clean = rj.synthesize(scene, vps, small_radar)
    noisy = rj.synthesize(scene, vps, small_radar, snr_db=10.0, seed=1)
    again = rj.synthesize(scene, vps, small_radar, snr_db=10.0, seed=1)
    other = rj.synthesize(scene, vps, small_radar, snr_db=10.0, seed=2)
    np.testing.assert_array_equal(np.asarray(noisy.signal), np.asarray(again.signal))
    assert not np.array_equal(np.asarray(noisy.signal), np.asarray(other.signal))
    raw_clean = clean.signal * clean.scale
    noise = noisy.signal * noisy.scale - raw_clean
    snr = 10 * np.log10(np.mean(np.abs(raw_clean) ** 2) / np.mean(np.abs(noise) ** 2))
    assert snr == pytest.approx(10.0, abs=0.3)
    assert noisy.snr_db == 10.0


def test_synthesize_rejects_bad_input(small_radar):
    vps = rj.Viewpoints.grid(2, 2)
    with pytest.raises(ValueError, match="no non-zero"):
        rj.synthesize(rj.Scene.empty(2.0, 0.5), vps, small_radar)
    with pytest.raises(ValueError, match="scene"):
        rj.synthesize(np.ones((5, 5, 5)), vps, small_radar)
    with pytest.raises(ValueError, match="snr_db"):
        rj.synthesize(rj.scenes.cube(0.5), vps, small_radar, snr_db=float("nan"))
