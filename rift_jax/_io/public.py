"""The RIFT authors' public NPZ layout (baodaqian/RIFT_Public), read as a `RadarData`."""

from __future__ import annotations

import json
import os
import zipfile

import jax.numpy as jnp
import numpy as np

from .._geometry import C0, Radar, Viewpoints, every_view_antennas
from .._synthesis import RadarData

_PUBLIC_KEYS = ("response", "tx_pos", "rx_pos", "viewpoint_positions", "metadata_json")


def load_rift_public(path: str | os.PathLike, *, phase_sign: int = -1) -> RadarData:
    """Read a radar dataset in the RIFT authors' public NPZ layout as a `RadarData`.

    Their layout (baodaqian/RIFT_Public, ``rift/npz_dataset.py``) holds:

    - ``response``: complex (n_views, n_tx, n_rx, n_chirps, n_adc). The chirps repeat one
      static measurement and are averaged here, as the authors do; the ADC samples are the
      frequencies.
    - ``metadata_json``: a JSON object with ``radar_fc_hz``, ``radar_bandwidth_hz`` and
      ``num_adc_samples``: sample i is at f = fc − B/2 + i·B/n (no frequency array is
      stored, and the grid stops one step short of fc + B/2). ``target_position_m``, when
      given, must be the origin: rift_jax's scenes are centred there.
    - ``viewpoint_positions``: (n_views, 3) array centres (m), the target at the origin.
    - ``tx_pos``, ``rx_pos``: (n_views, n_tx | n_rx, 3) absolute element positions (m).

    rift_jax's GRT takes a `Radar` (an antenna layout in the radar's frame) and
    `Viewpoints` (its poses). When every antenna sits where `rift_jax.antenna_positions`
    puts the paper's L (to within λ_min / 1000, a phase error below 2π/1000) on a sphere
    of viewpoints, the file reads as the paper's `Radar` (spacing from the first TX
    element) and `Viewpoints` by angle (``azimuth = atan2(y, x)``, ``polar = arccos(z /
    r)``). Any other layout moved rigidly from view to view (the authors' own simulations
    put a cross of centred TX and RX arrays in each view's look-at frame) reads as
    `Radar.from_antennas`, its layout from the first view, and `Viewpoints.from_poses`,
    each view's orientation the rotation that best places that layout on its antennas
    (Kabsch). Antennas that no rotation places within the tolerance are refused with a
    ValueError naming ``tx_pos`` or ``rx_pos`` and saying how far off they are.

    **Arguments:**

    - `path`: the ``.npz`` file. It is read without unpickling; a ``metadata_json``
      stored as a pickled object array is refused (re-save it as a string).
    - `phase_sign`: the sign s of the data's propagation phase exp(s·j·k·R). The authors'
      NPZ loader reads their data as exp(−j·k·R) (−1, the default); rift_jax's GRT uses
      exp(+j·k·R), so such data are conjugated. Pass +1 for data already in rift_jax's
      convention. (The sign is a simulator's convention: their repository documents +1
      for its CSV exports; the wrong sign mirrors the scene differently at every view.)

    **Returns:** a `RadarData`: the averaged response in rift_jax's axis order (n_views,
    n_freq, n_tx, n_rx), normalised to max |S| = 1 (``scale``: that peak), with a near-field
    `Radar` (their forward model's 1/(R_t + R_r)² spreading is rift_jax's) and the
    `Viewpoints`. Reconstruct it with ``rj.fit(data, data.viewpoints, extent=...,
    granularity=...)``; the metadata's ``scaled_max_extent_m`` is the object's size.
    """
    where = "load_rift_public"
    if phase_sign not in (1, -1) or isinstance(phase_sign, bool):
        raise ValueError(f"{where}: `phase_sign` must be +1 or -1, got {phase_sign!r}.")
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"{where}: `path` must be a str or path, got {type(path).__name__}.")
    try:
        archive = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise ValueError(f"{where}: `path` {str(path)!r} is not an NPZ file ({error}).") from error
    if not isinstance(archive, np.lib.npyio.NpzFile):
        raise ValueError(f"{where}: `path` {str(path)!r} holds one array, not an NPZ archive.")
    with archive as data:
        missing = [key for key in _PUBLIC_KEYS if key not in data.files]
        if missing:
            raise ValueError(
                f"{where}: `path` {str(path)!r} lacks {missing}: the authors' layout holds "
                f"{list(_PUBLIC_KEYS)}."
            )
        try:
            meta = data["metadata_json"]
        except ValueError as error:  # an object array: only pickle could read it
            raise ValueError(
                f"{where}: `metadata_json` in {str(path)!r} is a pickled object array; "
                "rift_jax never unpickles (it can run code). Re-save it as a string: "
                "np.savez(..., metadata_json=json.dumps(meta))."
            ) from error
        arrays = {key: data[key] for key in _PUBLIC_KEYS if key != "metadata_json"}
    meta = _public_metadata(meta, where)
    response = arrays["response"]
    if response.ndim != 5 or not np.iscomplexobj(response):
        raise ValueError(
            f"{where}: `response` must be complex (n_views, n_tx, n_rx, n_chirps, n_adc), got "
            f"{response.dtype} {response.shape}."
        )
    n_views, n_tx, n_rx, n_chirps, n_adc = response.shape
    shapes = {
        "tx_pos": (n_views, n_tx, 3),
        "rx_pos": (n_views, n_rx, 3),
        "viewpoint_positions": (n_views, 3),
    }
    for key, shape in shapes.items():
        if arrays[key].shape != shape:
            raise ValueError(
                f"{where}: `{key}` must have shape {shape} to match `response` "
                f"{response.shape}, got {arrays[key].shape}."
            )
        if not np.all(np.isfinite(arrays[key])):
            raise ValueError(f"{where}: `{key}` holds NaN or inf.")
    if int(meta["num_adc_samples"]) != n_adc:
        raise ValueError(
            f"{where}: `metadata_json` says num_adc_samples={meta['num_adc_samples']!r} but "
            f"`response` has {n_adc} samples per chirp."
        )
    if "num_chirps_cpi" in meta and int(meta["num_chirps_cpi"]) != n_chirps:
        raise ValueError(
            f"{where}: `metadata_json` says num_chirps_cpi={meta['num_chirps_cpi']!r} but "
            f"`response` has {n_chirps} chirps."
        )
    target = np.asarray(meta.get("target_position_m", (0.0, 0.0, 0.0)), np.float64)
    if target.shape != (3,) or np.any(target != 0):
        raise ValueError(
            f"{where}: `metadata_json` places the target at target_position_m="
            f"{meta.get('target_position_m')!r}; rift_jax's scenes are centred at the origin."
        )

    # frequencies: the authors' grid fc − B/2 + i·B/n, i < n (one step short of fc + B/2)
    fc, bandwidth = float(meta["radar_fc_hz"]), float(meta["radar_bandwidth_hz"])
    f_min, step = fc - bandwidth / 2, bandwidth / n_adc
    f_max = f_min + (n_adc - 1) * step
    tolerance = C0 / max(f_max, f_min) / 1000  # λ_min / 1000: a phase error ≤ 2π/1000

    centres = np.asarray(arrays["viewpoint_positions"], np.float64)
    tx_pos = np.asarray(arrays["tx_pos"], np.float64)
    rx_pos = np.asarray(arrays["rx_pos"], np.float64)
    frequencies = (f_min, f_max, n_adc)
    radar, viewpoints = _paper_layout(centres, tx_pos, rx_pos, frequencies, tolerance, where)
    if radar is None:
        radar, viewpoints = _rigid_layout(centres, tx_pos, rx_pos, frequencies, tolerance, where)

    signal = np.mean(response, axis=3, dtype=np.complex128).transpose(0, 3, 1, 2)
    if phase_sign == -1:
        signal = np.conj(signal)
    if not np.all(np.isfinite(signal)):
        raise ValueError(f"{where}: `response` holds NaN or inf.")
    peak = float(np.max(np.abs(signal)))
    if peak == 0:
        raise ValueError(f"{where}: `response` is all zero.")
    signal = jnp.asarray((signal / peak).astype(np.complex64))
    return RadarData(signal, peak, viewpoints, radar, None)


def _paper_layout(centres, tx_pos, rx_pos, frequencies, tolerance, where):
    """The paper's L on the sphere (`Radar`, `Viewpoints` by angles), if every antenna
    sits where `rift_jax.antenna_positions` puts it; (None, None) otherwise."""
    f_min, f_max, n = frequencies
    distances = np.linalg.norm(centres, axis=1)
    distance = float(np.mean(distances))
    if np.max(np.abs(distances - distance)) > tolerance:
        return None, None
    azimuth = np.arctan2(centres[:, 1], centres[:, 0])
    polar = np.arccos(np.clip(centres[:, 2] / distances, -1.0, 1.0))
    # the L's first TX element sits half a spacing from the array centre
    spacing = 2 * float(np.linalg.norm(tx_pos[0, 0] - centres[0]))
    if spacing == 0:  # an antenna at the array centre: no L
        return None, None
    try:
        radar = Radar(n, f_min, f_max, tx_pos.shape[1], rx_pos.shape[1], spacing, distance)
    except ValueError as error:
        raise ValueError(
            f"{where}: `metadata_json` or the positions give no valid Radar: {error}"
        ) from error
    viewpoints = Viewpoints(azimuth, polar)
    expected_tx, expected_rx = every_view_antennas(radar, viewpoints)
    for found, expected in ((tx_pos, expected_tx), (rx_pos, expected_rx)):
        if np.linalg.norm(found - expected, axis=-1).max() > tolerance:
            return None, None
    return radar, viewpoints


def _rigid_layout(centres, tx_pos, rx_pos, frequencies, tolerance, where):
    """Any one array moved rigidly from view to view: its layout in the first view's frame
    (looking at the origin, TX arm leaning to +z: `Viewpoints.from_poses`), and each view's
    rotation by the Kabsch algorithm (the rotation that best maps that layout onto the
    view's antennas). Refused, naming the positions, when no rotation places every antenna
    within ``tolerance``. For antennas on one line (or at one point) the rotation about that
    line is not fixed by them: the orientations are then one of many that place every
    antenna, which is all the GRT reads."""
    f_min, f_max, n = frequencies
    antennas = np.concatenate([tx_pos, rx_pos], axis=1) - centres[:, None]
    try:  # the TX arm leaning to +z, or to +x for a first view on the z axis
        first = Viewpoints.from_poses(centres[:1], up=_up(centres[0])).orientations[0]
    except ValueError as error:
        raise ValueError(f"{where}: `viewpoint_positions` give no pose: {error}") from error
    layout = antennas[0] @ first  # coordinates in the first view's frame
    u, _, vt = np.linalg.svd(np.einsum("ai,vaj->vij", layout, antennas))
    handed = np.sign(np.linalg.det(vt.transpose(0, 2, 1) @ u.transpose(0, 2, 1)))
    fix = np.ones((len(centres), 3))
    fix[:, 2] = handed
    rotations = (vt.transpose(0, 2, 1) * fix[:, None]) @ u.transpose(0, 2, 1)
    if not np.any(layout):  # every antenna at the array's centre: nothing to turn, and the
        # SVD's rotation of nothing would not look at the scene: the look-at poses instead
        rotations = np.stack(
            [Viewpoints.from_poses(c[None], up=_up(c)).orientations[0] for c in centres]
        )
    placed = layout[None] @ rotations.transpose(0, 2, 1)
    off = np.linalg.norm(placed - antennas, axis=-1)
    if off.max() > tolerance:
        view, element = np.unravel_index(np.argmax(off), off.shape)
        n_tx = tx_pos.shape[1]
        key, element = ("tx_pos", element) if element < n_tx else ("rx_pos", element - n_tx)
        raise ValueError(
            f"{where}: `{key}` is not one array moved from view to view: element {element} "
            f"of view {view} lies {1e3 * off.max():.4g} mm from where view 0's layout, turned "
            f"to fit, puts it (tolerance {1e6 * tolerance:.3g} µm, λ_min/1000). rift_jax's "
            "Radar is one antenna layout (Radar.from_antennas) seen from many poses."
        )
    frequency_grid = f_min + (f_max - f_min) / max(n - 1, 1) * np.arange(n)
    try:
        radar = Radar.from_antennas(
            layout[: tx_pos.shape[1]],
            layout[tx_pos.shape[1] :],
            frequency_grid,
            distance=float(np.min(np.linalg.norm(centres, axis=1))),
        )
    except ValueError as error:
        raise ValueError(
            f"{where}: `metadata_json` or the positions give no valid Radar: {error}"
        ) from error
    return radar, Viewpoints.from_poses(centres, orientations=rotations)


def _up(centre: np.ndarray) -> tuple[float, float, float]:
    """The world's +z, unless ``centre`` looks along it (a view on the z axis): then +x."""
    length = float(np.linalg.norm(centre))
    if length > 0 and abs(centre[2]) > (1 - 1e-12) * length:
        return (1.0, 0.0, 0.0)
    return (0.0, 0.0, 1.0)


def _public_metadata(raw, where: str) -> dict:
    """``metadata_json`` as a dict: a str, a 0-d or one-element string array, or bytes."""
    raw = np.asarray(raw)
    if raw.size != 1:
        raise ValueError(
            f"{where}: `metadata_json` must be one JSON string, got shape {raw.shape}."
        )
    raw = raw.reshape(-1)[0]
    raw = raw.item() if isinstance(raw, np.generic) else raw
    if isinstance(raw, bytes):
        raw = raw.decode("utf-8")
    try:
        meta = json.loads(raw)
    except (TypeError, json.JSONDecodeError) as error:
        raise ValueError(f"{where}: `metadata_json` is not JSON text ({error}).") from error
    if not isinstance(meta, dict):
        raise ValueError(
            f"{where}: `metadata_json` must be a JSON object, got {type(meta).__name__}."
        )
    for key in ("radar_fc_hz", "radar_bandwidth_hz", "num_adc_samples"):
        if key not in meta:
            raise ValueError(f"{where}: `metadata_json` lacks {key!r}, which the frequencies need.")
    return meta
