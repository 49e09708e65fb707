import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference

import rift_jax as rj


def test_radar_defaults_are_the_papers():
    radar = rj.Radar()
    assert radar.spacing == pytest.approx(1.4276e-3, rel=1e-4)
    f = radar.frequencies
    assert f.shape == (100,) and f[0] == 95e9 and f[-1] == 105e9
    np.testing.assert_allclose(np.diff(f), 10e9 / 99)
    assert radar.signal_shape == (100, 16, 16)
    assert radar.distance == 10.0 and radar.near_field


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(f_min=0.0), "f_min"),
        (dict(f_min=-1e9), "f_min"),
        (dict(f_max=90e9), "f_max"),
        (dict(n_tx=0), "n_tx"),
        (dict(n_frequencies=2.5), "n_frequencies"),
        (dict(distance=float("nan")), "distance"),
        (dict(spacing=-1e-3), "spacing"),
    ],
)
def test_radar_rejects_bad_settings(kwargs, word):
    with pytest.raises(ValueError, match=word):
        rj.Radar(**kwargs)


def test_viewpoint_grid_matches_paper():
    vps = rj.Viewpoints.grid()
    assert len(vps) == 2601
    assert vps.azimuth.min() == 0 and vps.azimuth.max() == pytest.approx(2 * np.pi)
    assert vps.polar.min() == 0 and vps.polar.max() == pytest.approx(np.pi)
    weak = rj.Viewpoints.grid(41, 21, (0.1 * np.pi, 0.3 * np.pi), (0.1 * np.pi, 0.3 * np.pi))
    assert len(weak) == 861


def test_viewpoint_indexing_and_split():
    vps = rj.Viewpoints.grid(6, 5)
    assert len(vps[3]) == 1 and len(vps[2:7]) == 5
    sub = vps.subset([0, 4, 9])
    np.testing.assert_array_equal(sub.azimuth, vps.azimuth[[0, 4, 9]])
    train, test = vps.split(12, 7, seed=3)
    assert len(train) == 12 and len(test) == 7
    pairs = lambda v: set(zip(v.azimuth.tolist(), v.polar.tolist(), strict=True))  # noqa: E731
    assert not pairs(train) & pairs(test)
    again, _ = vps.split(12, 7, seed=3)
    np.testing.assert_array_equal(again.azimuth, train.azimuth)
    other, _ = vps.split(12, 7, seed=4)
    assert not np.array_equal(other.azimuth, train.azimuth) or not np.array_equal(
        other.polar, train.polar
    )
    with pytest.raises(ValueError, match="exceeds"):
        vps.split(20, 20)


@pytest.mark.parametrize(
    "azimuth, polar, word",
    [
        ([], [], "at least one"),
        ([0.0, 1.0], [0.5], "same length"),
        ([0.0], [4.0], "polar"),
        ([0.0], [-0.1], "polar"),
        ([90.0], [1.0], "azimuth"),
        ([np.nan], [1.0], "azimuth"),
    ],
)
def test_viewpoints_reject_bad_angles(azimuth, polar, word):
    with pytest.raises(ValueError, match=word):
        rj.Viewpoints(np.array(azimuth), np.array(polar))


def test_antenna_positions_match_reference_and_geometry():
    radar = rj.Radar()
    for azimuth, polar in [(0.3, 1.1), (2.0, 0.0), (5.5, np.pi)]:
        tx, rx = rj.antenna_positions(radar, azimuth, polar)
        assert tx.dtype == jnp.float64 and tx.shape == (16, 3) and rx.shape == (16, 3)
        ref_tx, ref_rx = reference.antenna_positions(10.0, radar.spacing, 16, 16, azimuth, polar)
        np.testing.assert_allclose(np.asarray(tx), ref_tx, rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.asarray(rx), ref_rx, rtol=0, atol=1e-12)
        # An L: both arms start half a spacing from the centre, orthogonal to each other
        # and to the line of sight.
        centre = ref_tx[0] - (ref_tx[1] - ref_tx[0]) / 2
        assert np.linalg.norm(centre) == pytest.approx(10.0)
        u_t, u_r = np.diff(ref_tx, axis=0)[0], np.diff(ref_rx, axis=0)[0]
        assert np.linalg.norm(u_t) == pytest.approx(radar.spacing)
        assert abs(u_t @ u_r) < 1e-15 and abs(u_t @ centre) < 1e-12 and abs(u_r @ centre) < 1e-12


def test_antenna_positions_vmap_and_jit_agree():
    radar = rj.Radar(distance=50.0)
    az = np.array([0.1, 1.0, 3.0], np.float32)  # float32: what a trace sees without x64
    pol = np.array([0.5, 1.5, 2.5], np.float32)
    batched = jax.vmap(lambda a, p: rj.antenna_positions(radar, a, p))(az, pol)
    jitted = jax.jit(lambda a, p: rj.antenna_positions(radar, a, p))(az[1], pol[1])
    eager = rj.antenna_positions(radar, az[1], pol[1])
    np.testing.assert_array_equal(np.asarray(batched[0][1]), np.asarray(eager[0]))
    np.testing.assert_array_equal(np.asarray(jitted[1]), np.asarray(eager[1]))
