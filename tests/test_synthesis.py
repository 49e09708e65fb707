import jax.numpy as jnp
import numpy as np
import pytest
from conftest import compilations, relative_error

import rift_jax as rj
from rift_jax._padding import ladder_size
from rift_jax._synthesis import SYNTHESIS_SIZES_PER_OCTAVE


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


def test_scenes_of_about_the_same_size_share_one_compiled_forward(scene, caplog):
    """Occupied points are padded (ρ = 0) to a ladder of sizes: 73 and 76 points are both
    summed on 80, the second with no compilation (with a radar no other test uses, so the
    first one compiles here: forwards share programs across view counts), and each sum is
    its own to float32 rounding (against the grid-wide sum, whose padding is the grid's
    empty voxels)."""
    vps = rj.Viewpoints.grid(2, 2)
    radar = rj.Radar(n_frequencies=5, n_tx=3, n_rx=2)
    values = np.asarray(scene.reflectivity).copy()
    occupied = np.flatnonzero(values)
    assert len(occupied) == 76 and ladder_size(73, SYNTHESIS_SIZES_PER_OCTAVE) == 80
    fewer = values.copy()
    fewer.ravel()[occupied[:3]] = 0
    smaller = rj.Scene(fewer, scene.extent, scene.granularity)
    first = compilations(caplog, lambda: rj.synthesize(smaller, vps, radar).signal)
    assert any(m.startswith("Compiling jit(_signals)") for m in first)
    assert compilations(caplog, lambda: rj.synthesize(scene, vps, radar).signal) == []
    data = rj.synthesize(smaller, vps, radar)
    full = rj.grt_operator(radar, vps, smaller.points()).mv(fewer.ravel())
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


def test_point_scatterers_on_grid_points_are_the_scene(small_radar):
    rng = np.random.default_rng(0)
    rho = np.asarray(rj.scenes.cube(0.5, extent=2.0, edge=1.0).reflectivity)
    rho = rho * np.exp(1j * rng.uniform(-np.pi, np.pi, rho.shape))  # complex, as a truth may be
    scene = rj.Scene(jnp.asarray(rho, jnp.complex64), 2.0, 0.5)
    points = rj.PointScatterers(*scene.occupied(), extent=2.0)
    vps = rj.Viewpoints.grid(3, 2)
    for snr in (None, 10.0):
        a = rj.synthesize(scene, vps, small_radar, snr_db=snr, seed=3)
        b = rj.synthesize(points, vps, small_radar, snr_db=snr, seed=3)
        assert relative_error(b.signal, a.signal) < 1e-6
        assert b.scale == pytest.approx(a.scale, rel=1e-6)
    # On its own grid the spread is the scene itself.
    np.testing.assert_allclose(points.resample(0.5).reflectivity, rho, atol=1e-6)
    # A shift of 1 cm, a fiftieth of a voxel, is three wavelengths: another signal.
    shifted = rj.PointScatterers(points.points + [0.01, 0, 0], points.reflectivity, 2.0)
    moved = rj.synthesize(shifted, vps, small_radar)
    assert relative_error(moved.signal, a.signal) > 0.5
    # ... and the same image on the grid, nearly.
    spread = np.asarray(shifted.resample(0.5).reflectivity)
    assert relative_error(spread, rho) < 0.05


def test_point_scatterers_spread_trilinearly():
    point = np.array([[0.1, -0.3, 0.45]])  # grid 0.5 m over ±1 m: axis -1, -0.5, 0, 0.5, 1
    scene = rj.PointScatterers(point, [2.0 - 1.0j], extent=1.0).resample(0.5)
    rho = np.asarray(scene.reflectivity)
    assert np.count_nonzero(rho) == 8 and rho.sum() == pytest.approx(2.0 - 1.0j, rel=1e-6)
    weights = np.abs(rho) / np.abs(rho).sum()
    centroid = np.tensordot(weights, scene.points().reshape(5, 5, 5, 3), axes=3)
    np.testing.assert_allclose(centroid, point[0], atol=1e-6)  # the spread keeps the position
    assert abs(rho[2, 1, 3]) == pytest.approx(np.sqrt(5) * 0.8 * 0.6 * 0.9, rel=1e-5)


def test_point_scatterers_reject_bad_input(small_radar):
    with pytest.raises(ValueError, match="`points`"):
        rj.PointScatterers(np.zeros((2, 2)), [1, 1], extent=1.0)
    with pytest.raises(ValueError, match="`points`"):
        rj.PointScatterers([[0, 0, np.nan]], [1], extent=1.0)
    with pytest.raises(ValueError, match="inside ±`extent`"):
        rj.PointScatterers([[0, 0, 1.5]], [1], extent=1.0)
    with pytest.raises(ValueError, match="`reflectivity`"):
        rj.PointScatterers([[0, 0, 0.5]], [1, 2], extent=1.0)
    with pytest.raises(ValueError, match="`extent`"):
        rj.PointScatterers([[0, 0, 0.5]], [1], extent=-1.0)
    points = rj.PointScatterers([[0.1, 0.2, 0.3]], [1.0], extent=1.0)
    with pytest.raises(ValueError, match="`granularity`"):  # no grid of their own
        rj.fit(points, rj.Viewpoints.grid(2, 2), radar=small_radar, progress=False)
    with pytest.raises(ValueError, match="no non-zero"):
        rj.synthesize(rj.PointScatterers([[0, 0, 0]], [0], 1.0), rj.Viewpoints.grid(2, 2))
