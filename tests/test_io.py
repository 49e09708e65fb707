"""Data in and out: `save` / `load` round trips (NPZ and HDF5, exact to the bit), the RIFT
authors' public NPZ layout read back as the data it was written from, PLY point clouds
that an independent reader (plyfile) parses, and bad files refused by name."""

from __future__ import annotations

import dataclasses
import json
import os
import stat

import jax
import numpy as np
import plyfile
import pytest

import rift_jax as rj

SUFFIXES = [".npz", ".h5"]


@pytest.fixture(scope="module")
def measured():
    """A small measured dataset: 12 views of a 1 m cube, with noise."""
    radar = rj.Radar(n_frequencies=8, n_tx=3, n_rx=4, distance=8.0)
    scene = rj.scenes.cube(0.5, extent=1.0, edge=1.0)
    views = rj.Viewpoints.grid(4, 3, polar_range=(0.3, 1.3))
    return scene, rj.synthesize(scene, views, radar, snr_db=20.0, seed=3)


GRID = dict(extent=1.0, granularity=0.5, method="lsmr", iterations=4, progress=False)


@pytest.fixture(scope="module")
def reference(measured):
    """The measured data's reconstruction (one compilation, shared by the tests)."""
    _, data = measured
    return rj.fit(data, data.viewpoints, **GRID)


def same_tree(a, b) -> None:
    """Equal leaf by leaf: arrays bit for bit with their dtypes, everything else by ==."""
    leaves_a, tree_a = jax.tree_util.tree_flatten(a)
    leaves_b, tree_b = jax.tree_util.tree_flatten(b)
    assert tree_a == tree_b  # the static fields (radar, viewpoints, extent, ...) too
    for x, y in zip(leaves_a, leaves_b, strict=True):
        x, y = np.asarray(x), np.asarray(y)
        assert x.dtype == y.dtype and x.shape == y.shape
        assert x.tobytes() == y.tobytes()


def same_radar_data(a: rj.RadarData, b: rj.RadarData) -> None:
    same_tree(a.signal, b.signal)
    assert (a.scale, a.radar, a.snr_db) == (b.scale, b.radar, b.snr_db)
    for name in ("azimuth", "polar"):
        x, y = getattr(a.viewpoints, name), getattr(b.viewpoints, name)
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes()


# --- save / load ----------------------------------------------------------------------


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_radar_data_round_trip_is_exact_and_fits_the_same(measured, reference, tmp_path, suffix):
    _, data = measured
    path = rj.save(tmp_path / f"data{suffix}", data)
    loaded = rj.load(path)
    assert isinstance(loaded, rj.RadarData)
    same_radar_data(loaded, data)
    after = rj.fit(loaded, loaded.viewpoints, **GRID)
    same_tree(after.scene, reference.scene)


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_scenes_and_point_scatterers_round_trip_exactly(tmp_path, suffix, rng):
    scene = rj.scenes.sphere(0.25, extent=1.0)
    noisy = rj.Scene.from_array(
        rng.normal(size=(9, 9, 9)) + 1j * rng.normal(size=(9, 9, 9)), extent=1.0
    )
    points = rj.PointScatterers(rng.uniform(-1, 1, (5, 3)), rng.normal(size=5) + 1j, extent=1.0)
    for obj in (scene, noisy, points):
        loaded = rj.load(rj.save(tmp_path / f"obj{suffix}", obj))
        assert type(loaded) is type(obj)
        same_tree(loaded, obj)
    assert loaded.points.dtype == np.float64  # positions keep float64, as the GRT needs


def test_the_files_say_what_they_hold(measured, tmp_path):
    """Other tools can read the files: the header names the format, its version, the units,
    and the radar; HDF5 datasets carry their units; frequencies and antenna positions are
    there for tools that do not know rift_jax's geometry."""
    import h5py

    _, data = measured
    rj.save(tmp_path / "data.npz", data)
    rj.save(tmp_path / "data.h5", data)
    with np.load(tmp_path / "data.npz", allow_pickle=False) as npz:
        header = json.loads(str(npz["rift_jax_header"]))
        np.testing.assert_array_equal(npz["radar/frequencies"], data.radar.frequencies)
        tx, rx = rj.antenna_positions(
            data.radar, data.viewpoints.azimuth[5], data.viewpoints.polar[5]
        )
        np.testing.assert_array_equal(npz["antennas/tx"][5], tx)
        np.testing.assert_array_equal(npz["antennas/rx"][5], rx)
    assert header["format"] == "rift_jax" and header["format_version"] == 1
    assert header["rift_jax_version"] == rj.__version__ and header["kind"] == "RadarData"
    assert header["units"] == {"length": "m", "frequency": "Hz", "angle": "rad", "time": "s"}
    assert header["content"]["radar"]["f_min"] == data.radar.f_min
    with h5py.File(tmp_path / "data.h5", "r") as h5:
        assert h5.attrs["format"] == "rift_jax" and h5.attrs["kind"] == "RadarData"
        assert json.loads(h5.attrs["rift_jax_header"]) == header
        assert h5["radar/frequencies"].attrs["units"] == "Hz"
        assert h5["viewpoints/azimuth"].attrs["units"] == "rad"
        assert h5["antennas/tx"].attrs["units"] == "m"
        assert h5["signal"].dtype == np.complex64


def test_an_interrupted_save_keeps_the_previous_file(measured, tmp_path, monkeypatch):
    scene, _ = measured
    path = rj.save(tmp_path / "scene.h5", scene)
    before = path.read_bytes()

    def interrupted(source, target):
        raise KeyboardInterrupt

    monkeypatch.setattr(rj._io.atomic.os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        rj.save(path, rj.Scene.empty(1.0, 0.5))
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.h5"]


@pytest.mark.parametrize("umask", [0o022, 0o077])
def test_saved_files_get_the_mode_of_any_new_file(tmp_path, umask):
    """An atomic write's temporary file is no 0600 `mkstemp` file: the saved file has the
    mode the process's umask gives every new file, as a plain ``open(path, "w")`` would."""
    previous = os.umask(umask)
    try:
        plain = tmp_path / "plain"
        plain.write_bytes(b"")
        saved = rj.save(tmp_path / "scene.npz", rj.Scene.empty(1.0, 0.5))
        ply = rj.export_ply(tmp_path / "scene.ply", rj.scenes.sphere(0.25, extent=1.0))
    finally:
        os.umask(previous)
    expected = stat.S_IMODE(plain.stat().st_mode)
    assert expected == 0o666 & ~umask
    for path in (saved, ply):
        assert stat.S_IMODE(path.stat().st_mode) == expected, path.name


def _rewrite_npz(path, **changes):
    with np.load(path, allow_pickle=False) as npz:
        arrays = {name: npz[name] for name in npz.files}
    for name, value in changes.items():
        if value is None:
            arrays.pop(name)
        else:
            arrays[name] = value
    np.savez(path, **arrays)


def test_files_of_another_format_or_version_are_refused_by_name(measured, tmp_path):
    _, data = measured
    path = rj.save(tmp_path / "data.npz", data)
    with np.load(path, allow_pickle=False) as npz:
        header = json.loads(str(npz["rift_jax_header"]))

    newer = {**header, "format_version": 3, "rift_jax_version": "9.0"}
    _rewrite_npz(path, rift_jax_header=np.array(json.dumps(newer)))
    with pytest.raises(ValueError, match=r"format version 3 \(written by rift_jax 9.0\).*reads"):
        rj.load(path)
    _rewrite_npz(path, rift_jax_header=np.array(json.dumps(header)), signal=None)
    with pytest.raises(ValueError, match="load: `path` .* has no array 'signal'"):
        rj.load(path)
    _rewrite_npz(path, rift_jax_header=None)
    with pytest.raises(ValueError, match="is not a rift_jax file"):
        rj.load(path)
    other = {**header, "format": "someone_else"}
    _rewrite_npz(path, rift_jax_header=np.array(json.dumps(other)))
    with pytest.raises(ValueError, match="format 'someone_else'"):
        rj.load(path)
    (tmp_path / "junk.h5").write_text("not HDF5")
    with pytest.raises(ValueError, match="is not a readable HDF5 file"):
        rj.load(tmp_path / "junk.h5")
    public = write_rift_public(tmp_path / "public.npz", data)
    with pytest.raises(ValueError, match="authors' layout: read it with rift_jax.load_rift_public"):
        rj.load(public)


def same_result(a: rj.FitResult, b: rj.FitResult) -> None:
    """Every field equal: arrays and modules leaf by leaf, options and stats with their
    types (an np.float32 stays one), the rest by ==."""
    for field in dataclasses.fields(rj.FitResult):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if field.name in ("options", "stats"):
            same_values(x, y)
        elif field.name == "viewpoints":
            same_tree((x.azimuth, x.polar), (y.azimuth, y.polar))
        elif field.name == "history":  # a dataclass of arrays, not a pytree
            same_tree(dataclasses.astuple(x), dataclasses.astuple(y))
        elif field.name in ("radar", "method", "seconds", "stopped"):
            assert x == y and type(x) is type(y), field.name
        else:
            same_tree(x, y)  # scene, field, support, trained


def same_values(x, y) -> None:
    arrays = (np.ndarray, jax.Array)  # a JAX array comes back as a NumPy one
    assert type(x) is type(y) or (isinstance(x, arrays) and isinstance(y, arrays))
    if isinstance(x, dict):
        assert list(x) == list(y)
        for key in x:
            same_values(x[key], y[key])
    elif isinstance(x, list | tuple):
        assert len(x) == len(y)
        for u, v in zip(x, y, strict=True):
            same_values(u, v)
    elif isinstance(x, rj.Field | rj.AbstractINR | np.ndarray | jax.Array):
        same_tree(x, y)
    elif isinstance(x, float) and np.isnan(x):
        assert np.isnan(y)
    else:
        assert x == y


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_fit_results_round_trip_exactly_with_their_field(reference, tmp_path, suffix, rng):
    """A least-squares result as `fit` returned it, and one carrying everything a result
    can hold: RIFT's Field (RiftN and RiftS), a support, a finer trained scene, a loss
    history, and options and stats of every kind the solvers produce."""
    assert rj.load(rj.save(tmp_path / f"lsmr{suffix}", reference)).stopped == reference.stopped
    same_result(rj.load(rj.save(tmp_path / f"lsmr{suffix}", reference)), reference)

    field = rj.Field(rj.RiftN(width=8, depth=2, key=jax.random.key(1)), 1.0, gain=0.3 - 2j)
    siren = rj.RiftS(width=6, depth=1, omega_0=12.0, key=jax.random.key(2))
    support = np.zeros(reference.scene.shape, bool)
    support[1:4, 1:4, 1:4] = True
    full = dataclasses.replace(
        reference,
        method="rift-n",
        history=rj.solvers.History(
            np.array([0.9, 0.5]), np.array([0.1, 0.2]), np.array([3.0, 1.0])
        ),
        stopped=rj.solvers.Stop(rj.solvers.Outcome.CONVERGED, 2),
        field=field,
        support=support,
        trained=rj.scenes.sphere(0.25, extent=1.0, radius=0.5),
        options={
            "seed": 0,
            "recipe": rj.solvers.Recipe(epochs=5, halve_every=None, patience=2),
            "init": field,
            "model": siren,
            "hash": rj.HashGrid(
                width=4,
                depth=1,
                levels=3,
                features=2,
                table_size=16,
                coarsest=2,
                finest=7,
                key=jax.random.key(3),
            ),  # fmt: skip
            "x0": np.arange(4, dtype=np.complex64),
            "fine_points": rng.uniform(-1, 1, (6, 3)),
            "shape": (8, 2),
            "tol": np.float32(1e-3),
        },
        stats={
            "model": "rift-n",
            "recipe": dataclasses.asdict(rj.solvers.Recipe()),
            "best_epoch": 1,
            "best_loss": float("nan"),
            "initial_gain": float("inf"),
            "holdout_views": [0, 5],
            "holdout_residual": [0.5, 0.25],
            "remedies": [{"attempt": 1, "collapse": "zero field", "learning_rate": 0.005}],
            "collapse": None,
            "gain": 1.5 - 0.5j,
            "relaxations": np.array([1.0, 0.5], np.float32),
            "support_points": np.int64(27),
            "nonnegative": np.bool_(False),
            "step": jax.numpy.float32(0.25),
        },
    )
    loaded = rj.load(rj.save(tmp_path / f"full{suffix}", full))
    same_result(loaded, full)
    assert loaded.options["tol"].dtype == np.float32
    # a recipe saved before `epoch_views` existed reads back as its run was: one pass
    from rift_jax._io import codec

    old = codec._decode_value({"$recipe": {"epochs": 5}}, None, "old.h5")
    assert old == rj.solvers.Recipe(epochs=5, epoch_views=None)
    np.testing.assert_array_equal(loaded.render(0.25).reflectivity, full.render(0.25).reflectivity)


def test_every_model_has_its_place_in_the_file():
    """A model added to `rift_jax._models.MODELS` (what `fit`'s ``model=`` names) needs the
    settings that rebuild it in the file's codec too, or saving its results would fail."""
    from rift_jax._io import codec
    from rift_jax._models import MODELS

    assert set(codec._SETTINGS) == set(MODELS.values())


def test_every_field_of_a_fit_result_has_its_place_in_the_file():
    """A field added to FitResult must be saved too (rift_jax/_io/codec.py, `_encode_result` and
    `_decode_result`), or a loaded result would silently lose it."""
    saved = {"scene", "history", "seconds", "method", "options", "stopped", "radar"}
    saved |= {"viewpoints", "stats", "field", "support", "trained", "points"}
    assert {field.name for field in dataclasses.fields(rj.FitResult)} == saved


def test_what_a_file_cannot_hold_is_refused_by_name(reference, tmp_path):
    custom = dataclasses.replace(reference, options={"loss": lambda pred, target: 0.0})
    with pytest.raises(ValueError, match="save: `options/loss` is a function"):
        rj.save(tmp_path / "result.npz", custom)
    with pytest.raises(ValueError, match="keys of `stats` must be strings"):
        rj.save(tmp_path / "result.npz", dataclasses.replace(reference, stats={1: 2}))
    with pytest.raises(ValueError, match="not starting with '\\$'"):
        rj.save(tmp_path / "result.h5", dataclasses.replace(reference, stats={"$array": 2}))
    names = dataclasses.replace(reference, stats={"names": np.array(["a", "b"])})
    with pytest.raises(ValueError, match="`stats/names` is an array of <U1"):
        rj.save(tmp_path / "result.h5", names)
    assert list(tmp_path.iterdir()) == []  # refused before anything was written


# --- The RIFT authors' layout ---------------------------------------------------------


def write_rift_public(path, data: rj.RadarData, *, phase_sign=-1, chirps=2, antennas=None):
    """``data`` written as the RIFT authors' NPZ files are (baodaqian/RIFT_Public,
    rift/npz_dataset.py): response[view, tx, rx, chirp, adc] of the raw signal with phase
    exp(phase_sign·j·k·R), absolute antenna and array-centre positions, and the radar in
    ``metadata_json`` (the frequency of ADC sample i is fc − B/2 + i·B/n)."""
    radar, views = data.radar, data.viewpoints
    n = radar.n_frequencies
    bandwidth = (radar.f_max - radar.f_min) * n / (n - 1)
    a, p = views.azimuth, views.polar
    centres, frames = views.poses(radar)
    if antennas is None:
        antennas = [rj.antennas_at(radar, *pose) for pose in zip(centres, frames, strict=True)]
    raw = np.asarray(data.signal) * np.float32(data.scale)
    raw = np.conj(raw) if phase_sign == -1 else raw
    response = np.repeat(raw.transpose(0, 2, 3, 1)[:, :, :, None, :], chirps, axis=3)
    meta = {
        "target_type": "mesh",
        "experiment": "sphere10k",
        "target_position_m": [0.0, 0.0, 0.0],
        "radar_fc_hz": radar.f_min + bandwidth / 2,
        "radar_bandwidth_hz": bandwidth,
        "num_adc_samples": n,
        "num_chirps_cpi": chirps,
        "scaled_max_extent_m": 1.0,
    }
    angles = np.degrees(np.stack([a, np.pi / 2 - p], axis=1))  # their (azimuth, elevation)
    np.savez(
        path,
        response=response.astype(np.complex64),
        tx_pos=np.stack([tx for tx, _ in antennas]),
        rx_pos=np.stack([rx for _, rx in antennas]),
        viewpoint_positions=centres,
        viewpoint_angles=angles,
        metadata_json=np.array(json.dumps(meta)),
    )
    return path


@pytest.mark.parametrize("phase_sign", [-1, 1])
def test_the_authors_layout_reads_back_as_the_data(measured, tmp_path, phase_sign):
    _, data = measured
    path = write_rift_public(tmp_path / "public.npz", data, phase_sign=phase_sign)
    read = rj.load_rift_public(path, phase_sign=phase_sign)
    np.testing.assert_allclose(read.signal, data.signal, rtol=0, atol=2e-7)
    assert read.scale == pytest.approx(data.scale, rel=1e-6)
    np.testing.assert_allclose(read.radar.frequencies, data.radar.frequencies, rtol=1e-14)
    for name in ("n_tx", "n_rx", "near_field"):
        assert getattr(read.radar, name) == getattr(data.radar, name)
    assert read.radar.spacing == pytest.approx(data.radar.spacing, rel=1e-12)
    assert read.radar.distance == pytest.approx(data.radar.distance, rel=1e-14)
    np.testing.assert_allclose(
        np.exp(1j * read.viewpoints.azimuth), np.exp(1j * data.viewpoints.azimuth), atol=1e-14
    )
    np.testing.assert_allclose(read.viewpoints.polar, data.viewpoints.polar, atol=1e-14)


@pytest.mark.slow  # a radar equal to the data's to 1e-12, not bit for bit: a fit of its own
@pytest.mark.parametrize("phase_sign", [-1, 1])
def test_the_authors_layout_reconstructs_alike(measured, reference, tmp_path, phase_sign):
    _, data = measured
    path = write_rift_public(tmp_path / "public.npz", data, phase_sign=phase_sign)
    read = rj.load_rift_public(path, phase_sign=phase_sign)
    ours = reference.scene.reflectivity
    theirs = rj.fit(read, read.viewpoints, **GRID).scene.reflectivity  # the same radar, to 1e-12
    assert np.linalg.norm(theirs - ours) / np.linalg.norm(ours) < 1e-4


def test_the_wrong_phase_sign_mirrors_the_data(measured, tmp_path):
    _, data = measured
    path = write_rift_public(tmp_path / "public.npz", data, phase_sign=-1)
    read = rj.load_rift_public(path, phase_sign=1)
    np.testing.assert_allclose(read.signal, np.conj(data.signal), atol=2e-7)


def test_the_authors_cross_reads_as_a_radar_of_its_own(measured, tmp_path):
    """The authors' simulator puts centred TX and RX arrays on a cross (TX along the look-at
    frame's 'right', RX along its 'up'): not the paper's L, so it reads as
    `Radar.from_antennas` at `Viewpoints.from_poses`, which put every antenna back where
    the file has it."""
    _, data = measured
    radar, views = data.radar, data.viewpoints
    antennas = []
    for a, p in zip(views.azimuth, views.polar, strict=True):
        centre = radar.distance * np.array(
            [np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)]
        )
        right = np.array([np.sin(a), -np.cos(a), 0.0])
        up = np.array([-np.cos(p) * np.cos(a), -np.cos(p) * np.sin(a), np.sin(p)])
        offsets = lambda n: (np.arange(n) - (n - 1) / 2)[:, None] * radar.spacing  # noqa: E731
        antennas.append((centre + offsets(radar.n_tx) * right, centre + offsets(radar.n_rx) * up))
    read_back = rj.load_rift_public(
        write_rift_public(tmp_path / "cross.npz", data, antennas=antennas)
    )
    assert not read_back.radar.is_paper_array and read_back.viewpoints.positions is not None
    for view, (tx, rx) in enumerate(antennas):
        pose = (read_back.viewpoints.positions[view], read_back.viewpoints.orientations[view])
        placed = rj.antennas_at(read_back.radar, *pose)
        np.testing.assert_allclose(placed[0], tx, rtol=0, atol=1e-9)
        np.testing.assert_allclose(placed[1], rx, rtol=0, atol=1e-9)
    # a file whose array changes shape between views is no one radar: refused by name
    antennas[3] = (antennas[3][0] + np.array([0.0, 0.0, 2e-3]), antennas[3][1])
    path = write_rift_public(tmp_path / "bent.npz", data, antennas=antennas)
    with pytest.raises(ValueError, match=r"`tx_pos` is not one array moved from view to view"):
        rj.load_rift_public(path)


def test_a_monostatic_track_in_the_authors_layout_reads_back(tmp_path):
    """One antenna at the array centre (no L to read a spacing from), the first pulse
    straight above the scene (no 'up' leaning to +z): a radar of its own at its poses,
    whose GRT gives back the signal written."""
    radar = rj.Radar.from_antennas(np.zeros((1, 3)), np.zeros((1, 3)), np.linspace(95e9, 96e9, 8))
    track = np.array([[0.0, 0.0, 8.0], [8.0, 0.0, 1.0], [0.0, 8.0, 1.0], [-8.0, 0.0, 1.0]])
    views = rj.Viewpoints.from_poses(track, up=(1.0, 1.0, 0.0))
    truth = rj.scenes.cube(0.5, extent=1.0, edge=1.0)
    data = rj.synthesize(truth, views, radar)
    read = rj.load_rift_public(write_rift_public(tmp_path / "track.npz", data))
    assert read.radar.n_tx == read.radar.n_rx == 1
    np.testing.assert_allclose(read.radar.frequencies, radar.frequencies, rtol=1e-14)
    np.testing.assert_allclose(read.viewpoints.positions, track, atol=1e-12)
    looking = -track / np.linalg.norm(track, axis=1, keepdims=True)  # at the scene's centre
    np.testing.assert_allclose(read.viewpoints.orientations[:, :, 2], looking, atol=1e-12)
    np.testing.assert_allclose(read.signal, data.signal, rtol=0, atol=2e-7)
    again = rj.synthesize(truth, read.viewpoints, read.radar).signal
    np.testing.assert_allclose(again, data.signal, rtol=0, atol=1e-6)


def test_bad_files_in_the_authors_layout_are_refused_by_name(measured, tmp_path):
    _, data = measured
    path = write_rift_public(tmp_path / "public.npz", data)
    with np.load(path, allow_pickle=False) as npz:
        meta = json.loads(str(npz["metadata_json"]))
        tx = npz["tx_pos"]

    def rewritten(**changes):
        copy = tmp_path / "copy.npz"
        copy.write_bytes(path.read_bytes())
        _rewrite_npz(copy, **changes)
        return copy

    cases = [
        (dict(rx_pos=None), r"lacks \['rx_pos'\]"),
        (dict(tx_pos=tx[:, :2]), r"`tx_pos` must have shape \(12, 3, 3\)"),
        (dict(metadata_json=np.array("{")), "`metadata_json` is not JSON text"),
        (dict(metadata_json=np.array("[1]")), "`metadata_json` must be a JSON object"),
        (
            dict(metadata_json=np.array(json.dumps({**meta, "num_adc_samples": 9}))),
            "num_adc_samples=9 but `response` has 8",
        ),
        (
            dict(metadata_json=np.array(json.dumps({**meta, "target_position_m": [0, 0, 1]}))),
            "target_position_m=",
        ),
        (
            dict(
                metadata_json=np.array(json.dumps({k: meta[k] for k in meta if k != "radar_fc_hz"}))
            ),
            "`metadata_json` lacks 'radar_fc_hz'",
        ),
        (
            dict(viewpoint_positions=np.ones((12, 3)) * np.arange(12)[:, None]),
            "`viewpoint_positions` give no pose",  # the first at the target itself
        ),
    ]
    for changes, message in cases:
        with pytest.raises(ValueError, match=message):
            rj.load_rift_public(rewritten(**changes))
    pickled = tmp_path / "pickled.npz"
    with np.load(path, allow_pickle=False) as npz:
        arrays = {name: npz[name] for name in npz.files}
    arrays["metadata_json"] = np.array([meta], dtype=object)
    np.savez(pickled, **arrays)  # as the authors' older files: rift_jax never unpickles
    with pytest.raises(ValueError, match="`metadata_json` .* is a pickled object array"):
        rj.load_rift_public(pickled)
    np.save(tmp_path / "one.npy", np.zeros(3))
    with pytest.raises(ValueError, match="holds one array, not an NPZ archive"):
        rj.load_rift_public(tmp_path / "one.npy")


# --- PLY ------------------------------------------------------------------------------


def test_ply_point_clouds_parse_with_the_right_points_and_values(reference, tmp_path, rng):
    values = rng.normal(size=(9, 9, 9)) + 1j * rng.normal(size=(9, 9, 9))
    values[np.abs(values) < 1.5] = 0
    scene = rj.Scene.from_array(values, extent=1.0)
    path = rj.export_ply(tmp_path / "scene.ply", scene, threshold=0.3)
    ply = plyfile.PlyData.read(path)  # an independent, strict reader
    assert ply.header.splitlines()[1] == "format binary_little_endian 1.0"
    vertex = ply["vertex"]
    rho = np.asarray(scene.reflectivity).ravel()
    keep = np.abs(rho) >= 0.3 * np.abs(rho).max()
    assert vertex.count == keep.sum() > 0
    points = scene.points()[keep]
    for i, axis in enumerate("xyz"):
        np.testing.assert_array_equal(vertex[axis], points[:, i].astype(np.float32))
    np.testing.assert_array_equal(vertex["magnitude"], np.abs(rho[keep]).astype(np.float32))
    np.testing.assert_allclose(vertex["phase"], np.angle(rho[keep]), atol=1e-6)
    brightest = np.argmax(vertex["magnitude"])
    rgb = [vertex[c][brightest] for c in ("red", "green", "blue")]
    assert rgb == [253, 231, 36]  # the top of viridis

    # a FitResult exports its scene; point scatterers their points; zero gives no vertex
    from_result = plyfile.PlyData.read(rj.export_ply(tmp_path / "fit.ply", reference))
    from_scene = plyfile.PlyData.read(rj.export_ply(tmp_path / "own.ply", reference.scene))
    assert from_result["vertex"].data.tobytes() == from_scene["vertex"].data.tobytes()
    scatterers = rj.PointScatterers([[0.1, 0.2, 0.3], [-0.5, 0, 0]], [1.0, 0.01], extent=1.0)
    cloud = plyfile.PlyData.read(rj.export_ply(tmp_path / "points.ply", scatterers))
    assert cloud["vertex"].count == 1 and cloud["vertex"]["x"][0] == np.float32(0.1)
    empty = plyfile.PlyData.read(rj.export_ply(tmp_path / "empty.ply", rj.Scene.empty(1.0, 0.5)))
    assert empty["vertex"].count == 0


# --- The example ----------------------------------------------------------------------


@pytest.mark.slow  # a docs/examples script, end to end, as the others
def test_the_your_own_data_example_writes_what_it_says(tmp_path):
    """docs/examples/your_own_data.py, run as its page shows: every file it names, each
    readable, the reconstruction a fair image of the pyramid, and the saved result the
    one it returned."""
    import importlib.util
    from pathlib import Path

    script = Path(__file__).resolve().parent.parent / "docs" / "examples" / "your_own_data.py"
    spec = importlib.util.spec_from_file_location("your_own_data", script)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    result = example.main(["--out", str(tmp_path / "out")])
    out = tmp_path / "out"
    assert sorted(p.name for p in out.iterdir()) == [
        "measurements.h5",
        "reconstruction.h5",
        "reconstruction.ply",
        "your_own_data.png",
    ]
    data = rj.load(out / "measurements.h5")
    assert data.signal.shape == (30, 16, 8, 8) and data.snr_db == 20
    same_result(rj.load(out / "reconstruction.h5"), result)
    truth = rj.scenes.pyramid(0.2, extent=1.0, base=1.4, height=1.4)
    assert rj.metrics.t_iou(result.scene, truth) > 0.9
    magnitude = np.abs(np.asarray(result.scene.reflectivity))
    cloud = plyfile.PlyData.read(out / "reconstruction.ply")
    assert cloud["vertex"].count == np.sum(magnitude >= 0.3 * magnitude.max())
    assert (out / "your_own_data.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
