import re
import warnings

import numpy as np
import pytest

import rift_jax as rj
from rift_jax import scenes


def occupied(scene):
    return int(np.count_nonzero(np.asarray(scene.reflectivity)))


def test_grids_include_endpoints_and_nest():
    fine, coarse = rj.Scene.empty(5.0, 0.2), rj.Scene.empty(5.0, 0.4)
    assert fine.shape == (51,) * 3 and coarse.shape == (26,) * 3
    np.testing.assert_allclose(fine.axis()[[0, -1]], [-5, 5])
    np.testing.assert_allclose(fine.axis()[::2], coarse.axis(), atol=1e-12)
    points = fine.points()
    assert points.shape == (51**3, 3)
    # x-major, matching reflectivity.ravel()
    np.testing.assert_allclose(points[1], [-5, -5, -4.8])
    assert rj.Scene.empty(3.0, 0.12).shape == (51,) * 3


def test_paper_scene_sizes():
    g = 0.2
    sphere = scenes.sphere(g)
    assert occupied(sphere) == pytest.approx(4 / 3 * np.pi * 2**3 / g**3, rel=0.01)
    assert occupied(scenes.cube(g)) == 11**3
    pyramid = np.abs(np.asarray(scenes.pyramid(g).reflectivity)) > 0
    z = rj.Scene.empty(5.0, g).axis()
    layers = pyramid.sum(axis=(0, 1))
    assert layers[np.isclose(z, -1.0)] == 121 and layers[np.isclose(z, 1.0)] == 1
    assert not layers[z < -1.01].any() and not layers[z > 1.01].any()
    # Parking lot: ten poles of 12 voxels (2.2 m from z = -1); the cars' centres fall between
    # grid points, so they cover 4 x 3 x 4 and 6 x 2 x 3 grid points.
    assert occupied(scenes.parking_lot(g)) == 10 * 12 + 4 * 3 * 4 + 6 * 2 * 3
    # Highway: 8 poles of 10 voxels, 3 fences 51 x 11, car 5 x 13 x 9 (x, y, z voxels).
    assert occupied(scenes.highway(g)) == 8 * 10 + 3 * 51 * 11 + 5 * 13 * 9
    for build in (scenes.parking_lot, scenes.highway):
        rho = np.abs(np.asarray(build(g).reflectivity))
        z = rj.Scene.empty(5.0, g).axis()
        assert rho.max() == 1 and not rho[:, :, z < -1.01].any()  # all stand on z = -1


def test_weak_target_bars():
    scene = scenes.weak_target(0.25)
    assert scene.granularity == 0.12 and scene.extent == 3.0
    rho = np.abs(np.asarray(scene.reflectivity))
    x = scene.axis()
    strong, weak = rho[x < 0].max(), rho[x > 0].max()
    assert strong == 1.0 and weak == pytest.approx(0.25)
    occupied_x = x[rho.max(axis=(1, 2)) > 0]
    gap = occupied_x[occupied_x > 0].min() - occupied_x[occupied_x < 0].max()
    assert gap == pytest.approx(1.2, abs=1e-6)
    # Voxel centres span the bar's size: 0.72 m in x, 2.4 m in y, 0.48 m in z.
    for axis, size in ((0, 0.72), (1, 2.4), (2, 0.48)):
        other = tuple(a for a in range(3) if a != axis)
        coords = x[rho.max(axis=other) > 0]
        span = coords[coords > 0].max() - coords[coords > 0].min() if axis == 0 else np.ptp(coords)
        assert span == pytest.approx(size, abs=1e-6)
    centres = scenes.weak_target(1.0, gap=0.48)
    x_centre = x[np.abs(np.asarray(centres.reflectivity)).max(axis=(1, 2)) > 0]
    assert x_centre[x_centre > 0].mean() - x_centre[x_centre < 0].mean() == pytest.approx(1.2)
    with pytest.raises(ValueError, match="ratio"):
        scenes.weak_target(4.0)


@pytest.mark.parametrize("granularity", [0.0, -0.2, float("nan"), 6.0])
def test_bad_granularity(granularity):
    with pytest.raises(ValueError, match="granularity"):
        scenes.cube(granularity)


def test_from_array_and_errors():
    array = np.zeros((11, 11, 11))
    array[5, 5, 5] = 2.0
    scene = rj.Scene.from_array(array, extent=1.0)
    assert scene.granularity == pytest.approx(0.2)
    points, rho = scene.occupied()
    np.testing.assert_allclose(points, [[0, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(rho, [2.0])
    with pytest.raises(ValueError, match="cube"):
        rj.Scene.from_array(np.zeros((4, 4, 5)), 1.0)
    with pytest.raises(ValueError, match="finite"):
        rj.Scene(scene.reflectivity.at[0, 0, 0].set(np.nan), 1.0, 0.2)
    bad = array.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        rj.Scene.from_array(bad, 1.0)
    with pytest.raises(ValueError, match="shape"):
        rj.Scene(scene.reflectivity, 1.0, 0.3)


def test_resample_samples_nested_points_exactly(rng):
    values = rng.normal(size=(51,) * 3) + 1j * rng.normal(size=(51,) * 3)
    scene = rj.Scene.from_array(values, 5.0)
    coarse = scene.resample(0.4, anti_aliasing=False)
    assert coarse.shape == (26,) * 3 and coarse.granularity == 0.4
    np.testing.assert_allclose(np.asarray(coarse.reflectivity), values[::2, ::2, ::2], atol=1e-5)


def test_resample_linear_field_and_anti_aliasing():
    axis = rj.Scene.empty(5.0, 0.4).axis()
    x = np.meshgrid(axis, axis, axis, indexing="ij")[0]
    scene = rj.Scene.from_array(x + 0.5j * x, 5.0)
    fine = scene.resample(0.2)  # refining: trilinear interpolation is exact on a linear field
    fine_x = np.meshgrid(*(fine.axis(),) * 3, indexing="ij")[0]
    np.testing.assert_allclose(np.asarray(fine.reflectivity), fine_x + 0.5j * fine_x, atol=1e-5)
    cube = scenes.cube(0.2)
    smooth = np.abs(np.asarray(cube.resample(0.4).reflectivity))
    sharp = np.abs(np.asarray(cube.resample(0.4, anti_aliasing=False).reflectivity))
    assert set(np.unique(sharp)) <= {0.0, 1.0}
    assert ((smooth > 0.01) & (smooth < 0.99)).any()


def test_random_primitives_are_seeded_varied_and_checked():
    """The same seed gives the same scene; seeds differ; reflectivities lie in [0.25, 1] in
    magnitude, some complex; objects stay inside the grid; bad arguments are refused."""
    a = np.asarray(rj.scenes.random_primitives(3, 0.4).reflectivity)
    assert np.array_equal(a, np.asarray(rj.scenes.random_primitives(3, 0.4).reflectivity))
    b = np.asarray(rj.scenes.random_primitives(4, 0.4).reflectivity)
    assert not np.array_equal(a, b)
    values = np.concatenate(
        [np.asarray(rj.scenes.random_primitives(s, 0.4).reflectivity).ravel() for s in range(6)]
    )
    occupied = values[values != 0]
    assert occupied.size > 0
    assert np.all((np.abs(occupied) >= 0.25 - 1e-6) & (np.abs(occupied) <= 1 + 1e-6))
    assert np.any(np.abs(occupied.imag) > 1e-3) and np.any(occupied.imag == 0)
    for face in (a[0], a[-1], a[:, 0], a[:, -1], a[:, :, 0], a[:, :, -1]):
        assert not np.any(face)  # inside ±0.7·extent, clear of the faces
    with pytest.raises(ValueError, match="seed"):
        rj.scenes.random_primitives(-1)
    with pytest.raises(ValueError, match="count"):
        rj.scenes.random_primitives(0, count=(3, 2))


def test_a_grid_that_stops_short_of_its_extent_warns():
    """``Scene.empty(1.2, 0.35)``: 7 points per axis reach ±1.05 m while `extent` says 1.2;
    each way to make such a grid says so. Grids whose granularity divides 2·extent are quiet."""
    short = r"0.35 m over `extent` ±1.2 m reaches only ±1.05 m \(7 points per axis\)"
    with pytest.warns(rj.GridWarning, match=short + ".*e.g. 0.342857142 m") as empty:
        assert rj.Scene.empty(1.2, 0.35).shape == (7,) * 3
    with pytest.warns(rj.GridWarning, match=short) as built:
        scenes.cube(0.35, extent=1.2, edge=1.0)
    with pytest.warns(rj.GridWarning, match=short) as resampled:
        rj.Scene.empty(1.2, 0.2).resample(0.35)
    for warned in (empty, built, resampled):  # each names this line, not rift_jax's
        assert [w.filename for w in warned] == [__file__]
    # the granularity it suggests is rounded down, so that it spans the extent itself
    with pytest.warns(rj.GridWarning, match=r"e.g. 0.166666666 m") as warned:
        rj.Scene.empty(0.5, 0.17)
    suggested = float(re.search(r"e.g. ([0-9.]+) m", str(warned[0].message)).group(1))
    with warnings.catch_warnings():
        warnings.simplefilter("error", rj.GridWarning)
        rj.Scene.empty(1.2, 0.3).resample(0.4)
        rj.Scene.empty(3.0, 0.12)
        scenes.cube(0.2, extent=1.0)
        rj.Scene.empty(0.5, suggested)
