"""`fit(..., support=...)`: the operator on fewer points changes no answer that the support
contains, every method takes one, and a support that drops part of the scene is reported."""

import numpy as np
import pytest
import scipy.ndimage

import rift_jax as rj
from rift_jax._support import mask_at


def test_a_support_holding_the_scene_gives_the_full_grid_answer(small_cube):
    """Matched grid, exact data: least squares on the truth dilated by one voxel (64 of 729
    points) and on the whole grid both recover the scene, to float32 agreement."""
    radar, scene, train, test = small_cube
    support = scipy.ndimage.binary_dilation(np.asarray(scene.reflectivity) != 0)
    options = dict(method="lsmr", granularity=0.5, tol=0.0, progress=False)
    full = rj.fit(scene, train, radar=radar, iterations=300, check_every=100, **options)
    kept = rj.fit(scene, train, radar=radar, support=support, iterations=60, **options)
    assert kept.n_points == support.sum() < full.n_points == support.size
    assert kept.stats["support_points"] == support.sum()
    a, b = np.asarray(full.scene.reflectivity), np.asarray(kept.scene.reflectivity)
    assert np.linalg.norm(a - b) / np.linalg.norm(a) < 1e-3
    assert np.all(b[~support] == 0)
    assert kept.evaluate(scene, test)["m_ssim"] > 0.99
    assert kept.stats["support_leak"] < 1e-2  # nothing left outside to explain


@pytest.mark.parametrize("method", ["kaczmarz", "gauss-newton", "fista", "rift-n", "rift-s"])
def test_every_method_takes_a_support(small_cube, method):
    radar, scene, train, test = small_cube
    support = scipy.ndimage.binary_dilation(np.asarray(scene.reflectivity) != 0)
    budget = {"epochs": 3} if method.startswith("rift") else {"iterations": 2}
    result = rj.fit(
        scene, train, radar=radar, method=method, granularity=0.5, support=support,
        progress=False, **budget,
    )  # fmt: skip
    rho = np.asarray(result.scene.reflectivity)
    assert result.n_points == support.sum() and np.all(rho[~support] == 0)
    assert np.any(rho[support] != 0) and np.all(np.isfinite(result.evaluate(scene, test)["m_ssim"]))
    if result.field is not None:  # the continuous field is zero off the support too
        assert np.all(np.asarray(result.render(0.25).reflectivity)[~mask_at(
            support, result.scene, rj.grid_points(2.0, 0.25)
        ).reshape(17, 17, 17)] == 0)  # fmt: skip
        np.testing.assert_allclose(result.render(0.5).reflectivity, rho, rtol=1e-4, atol=1e-6)


def test_a_support_that_drops_part_of_the_scene_warns(small_cube):
    radar, scene, train, _ = small_cube
    support = np.zeros(scene.shape, bool)
    support[: scene.shape[0] // 2 + 1] = True  # half the box: half the cube is left out
    with pytest.warns(UserWarning, match="may have dropped part of the scene"):
        result = rj.fit(
            scene, train, radar=radar, method="lsmr", granularity=0.5, support=support,
            iterations=20, progress=False,
        )  # fmt: skip
    assert result.stats["support_leak"] > 0.1


def test_bad_supports(small_cube):
    radar, scene, train, _ = small_cube
    fit = dict(radar=radar, method="lsmr", granularity=0.5, iterations=1, progress=False)
    for support, match in [
        (np.zeros(scene.shape, bool), "no points"),
        (np.ones((3, 3, 3), bool), "shape"),
        (np.ones(scene.shape), "dtype"),
        ("auto", "boolean mask"),
        (rj.Scene.empty(2.0, 1.0), "grid"),
    ]:
        with pytest.raises(ValueError, match=match):
            rj.fit(scene, train, support=support, **fit)
    result = rj.fit(scene, train, support=scene, **fit)  # a Scene on the same grid
    assert result.n_points == int(np.sum(np.asarray(scene.reflectivity) != 0))
