"""Data in and out: save and load signals, scenes and reconstructions with their metadata
(NPZ or HDF5), read the RIFT authors' public NPZ layout, and export a reconstruction as a
PLY point cloud that common 3-D viewers open.

One record, two containers. Everything an object holds is a set of named arrays (``signal``,
``viewpoints/azimuth``, ...) and one JSON header: the format's name and version, the
rift_jax version that wrote it, the units, the object's kind and its non-array fields (the
`Radar`, the scale, ...). An NPZ file holds the arrays under those names and the header as
the string array ``rift_jax_header``; an HDF5 file holds them as datasets (the names' "/"
are groups, each dataset with a ``units`` attribute where it has one) and the header as the
root attribute ``rift_jax_header``, with ``format``, ``format_version``, ``kind`` and
``rift_jax_version`` beside it for h5dump and HDFView. Arrays are stored as they are
(no compression, no casts), so a round trip is exact bit for bit. Nothing is pickled.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._fit import FitResult
from ._geometry import C0, Radar, Viewpoints, antenna_positions
from ._models import Field, HashGrid, RiftN, RiftS
from ._scenes import Scene
from ._solvers import History, Outcome, Recipe, Stop
from ._synthesis import PointScatterers, RadarData

FORMAT = "rift_jax"
FORMAT_VERSION = 1
"""Bump when a file of this version would be read wrongly by the code that reads it; every
version this module reads stays readable."""

UNITS = {"length": "m", "frequency": "Hz", "angle": "rad", "time": "s"}
_HEADER = "rift_jax_header"
_SUFFIXES = {".npz": "npz", ".h5": "hdf5", ".hdf5": "hdf5"}
# the `units` attribute of each HDF5 dataset that has one (by the name's last part)
_DATASET_UNITS = {
    "azimuth": "rad",
    "polar": "rad",
    "frequencies": "Hz",
    "tx": "m",
    "rx": "m",
    "points": "m",
    "seconds": "s",
}


def _version() -> str:
    from . import __version__  # at call time: the package's __init__ imports this module

    return __version__


# --- Public API -------------------------------------------------------------------------


def save(path: str | os.PathLike, obj: RadarData | Scene | PointScatterers | FitResult) -> Path:
    """Write ``obj`` to ``path``, as NPZ (``.npz``) or HDF5 (``.h5``, ``.hdf5``) by its
    suffix; atomically (a temporary file in the same folder, renamed into place), so an
    interrupted save leaves the previous file whole.

    What each kind of object stores, and in which units, is tabled in
    ``docs/examples/your_own_data.md``; `load` gives back an equal object, arrays bit for bit.

    **Arguments:**

    - `path`: where to write; its folder must exist.
    - `obj`: a `RadarData` (signal, scale, noise level, `Radar`, `Viewpoints`, and for other
      tools each view's frequencies and antenna positions), a `Scene`, `PointScatterers`,
      or a `FitResult`: everything it holds, RIFT's trained `Field` too (its weights, and
      the sizes that rebuild its model). A FitResult's `options` and `stats` are stored as
      JSON with their arrays beside it; what JSON cannot hold is refused by name (a
      callable loss, your own `AbstractINR`: give the result other options with
      ``dataclasses.replace(result, options=...)``).

    **Returns:** the path written.
    """
    path, container = _container("save", path)
    kind, content, arrays = _encode_object(obj)
    header = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "rift_jax_version": _version(),
        "kind": kind,
        "units": UNITS,
        "content": content,
    }
    text = json.dumps(header, allow_nan=False)  # strict JSON: other tools read it too
    if not path.parent.is_dir():
        raise ValueError(
            f"save: `path` must be in an existing folder; {str(path.parent)!r} is not."
        )
    _write_atomic(path, lambda f: _WRITERS[container](f, text, header, arrays))
    return path


def load(path: str | os.PathLike) -> RadarData | Scene | PointScatterers | FitResult:
    """Read what `save` wrote: a `RadarData`, `Scene`, `PointScatterers` or `FitResult`
    equal to the one saved (the format from the suffix, as `save`).

    A loaded `RadarData` goes straight into `rift_jax.fit`
    (``rj.fit(data, data.viewpoints, extent=..., granularity=...)``), with the results it
    gave before it was saved; a loaded `FitResult` predicts, renders and evaluates as the
    saved one did. Arrays in a FitResult's `options` and `stats` come back as NumPy arrays.

    **Raises:** ValueError naming what is wrong: a suffix other than ``.npz``, ``.h5`` or
    ``.hdf5``, a file of another format (for the RIFT authors' NPZ layout use
    `load_rift_public`) or of a newer format version, a missing entry.
    """
    path, container = _container("load", path)
    if not path.is_file():
        raise FileNotFoundError(f"load: no file at `path` {str(path)!r}.")
    header, arrays = _READERS[container](path)
    return _decode_object(header, arrays, str(path))


# --- Containers -------------------------------------------------------------------------


def _container(where: str, path) -> tuple[Path, str]:
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"{where}: `path` must be a str or path, got {type(path).__name__}.")
    path = Path(path)
    container = _SUFFIXES.get(path.suffix.lower())
    if container is None:
        raise ValueError(
            f"{where}: `path` must end in .npz (NumPy) or .h5 / .hdf5 (HDF5), got {path.name!r}."
        )
    return path, container


def _write_atomic(path: Path, write) -> None:
    """``write(file)`` into a temporary file beside ``path``, then rename it into place
    (the same idea as experiments/_output.py's `write_atomic`, which rift_jax does not
    import)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def _write_npz(f, text: str, header: dict, arrays: dict[str, np.ndarray]) -> None:
    np.savez(f, **{_HEADER: np.array(text)}, **arrays)


def _write_hdf5(f, text: str, header: dict, arrays: dict[str, np.ndarray]) -> None:
    import h5py

    with h5py.File(f, "w") as h5:
        h5.attrs[_HEADER] = text
        for key in ("format", "format_version", "kind", "rift_jax_version"):
            h5.attrs[key] = header[key]
        for name, array in arrays.items():
            dataset = h5.create_dataset(name, data=array)
            if (units := _DATASET_UNITS.get(name.rsplit("/", 1)[-1])) is not None:
                dataset.attrs["units"] = units


def _read_npz(path: Path) -> tuple[dict, dict[str, np.ndarray]]:
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except (ValueError, OSError, zipfile.BadZipFile) as error:
        raise ValueError(
            f"load: `path` {str(path)!r} is not a readable NPZ file ({error})."
        ) from error
    return _header(arrays.pop(_HEADER, None), arrays, path), arrays


def _read_hdf5(path: Path) -> tuple[dict, dict[str, np.ndarray]]:
    import h5py

    try:
        h5 = h5py.File(path, "r")
    except OSError as error:
        raise ValueError(
            f"load: `path` {str(path)!r} is not a readable HDF5 file ({error})."
        ) from error
    arrays = {}

    def take(name, item):
        if isinstance(item, h5py.Dataset):
            arrays[name] = np.asarray(item[()])  # a 0-d dataset reads as a scalar otherwise

    with h5:
        text = h5.attrs.get(_HEADER)
        h5.visititems(take)
    return _header(text, arrays, path), arrays


def _header(text, arrays: dict, path: Path) -> dict:
    """The JSON header, checked: this format, a version this code reads."""
    if text is None:
        hint = ""
        if {"response", "tx_pos", "rx_pos"} <= set(arrays):
            hint = " It is in the RIFT authors' layout: read it with rift_jax.load_rift_public."
        raise ValueError(
            f"load: `path` {str(path)!r} is not a rift_jax file (it has no "
            f"{_HEADER!r} entry).{hint}"
        )
    text = np.asarray(text)[()]  # a str, or a 0-d string array (NPZ)
    text = text.decode("utf-8") if isinstance(text, bytes) else str(text)
    try:
        header = json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(
            f"load: the {_HEADER!r} of `path` {str(path)!r} is not JSON ({error})."
        ) from error
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise ValueError(
            f"load: `path` {str(path)!r} is not a rift_jax file (its header says "
            f"format {header.get('format') if isinstance(header, dict) else None!r})."
        )
    version = header.get("format_version")
    if not isinstance(version, int) or not 1 <= version <= FORMAT_VERSION:
        raise ValueError(
            f"load: `path` {str(path)!r} has format version {version!r} (written by rift_jax "
            f"{header.get('rift_jax_version')}); this rift_jax ({_version()}) reads versions 1 "
            f"to {FORMAT_VERSION}: update rift_jax to read it."
        )
    return header


_WRITERS = {"npz": _write_npz, "hdf5": _write_hdf5}
_READERS = {"npz": _read_npz, "hdf5": _read_hdf5}


# --- Objects <-> (content, arrays) ------------------------------------------------------


class _Arrays:
    """A file's arrays, each taken by name with a clear error when it is missing."""

    def __init__(self, arrays: dict[str, np.ndarray], path: str):
        self.arrays, self.path = arrays, path

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self.arrays:
            raise ValueError(
                f"load: `path` {self.path!r} has no array {name!r}; the file is "
                "incomplete or was not written by rift_jax.save."
            )
        return self.arrays[name]


def _get(content: dict, key: str, path: str) -> Any:
    if not isinstance(content, dict) or key not in content:
        raise ValueError(
            f"load: the header of `path` {path!r} has no entry {key!r}; the file "
            "is incomplete or was not written by rift_jax.save."
        )
    return content[key]


def _encode_object(obj) -> tuple[str, dict, dict[str, np.ndarray]]:
    if isinstance(obj, RadarData):
        content = {
            "radar": _radar_record(obj.radar),
            "scale": float(obj.scale),
            "snr_db": None if obj.snr_db is None else float(obj.snr_db),
        }
        arrays = {"signal": np.asarray(obj.signal)}
        arrays |= _geometry_arrays(obj.radar, obj.viewpoints, antennas=True)
        return "RadarData", content, arrays
    if isinstance(obj, Scene):
        return "Scene", _grid_record(obj), {"reflectivity": np.asarray(obj.reflectivity)}
    if isinstance(obj, PointScatterers):
        arrays = {"points": np.asarray(obj.points), "reflectivity": np.asarray(obj.reflectivity)}
        return "PointScatterers", {"extent": obj.extent}, arrays
    if isinstance(obj, FitResult):
        return "FitResult", *_encode_result(obj)
    raise ValueError(
        "save: `obj` must be a rift_jax RadarData, Scene, PointScatterers or FitResult, got "
        f"{type(obj).__name__}."
    )


def _decode_object(header: dict, arrays: dict, path: str):
    kind = header.get("kind")
    content = _get(header, "content", path)
    take = _Arrays(arrays, path)
    if kind == "RadarData":
        radar = _radar(_get(content, "radar", path), path)
        viewpoints = _viewpoints(take, path)
        signal = take["signal"]
        _check_frequencies(radar, take["radar/frequencies"], f"load: `path` {path!r}")
        scale, snr_db = _get(content, "scale", path), _get(content, "snr_db", path)
        return RadarData(jnp.asarray(signal), scale, viewpoints, radar, snr_db)
    if kind == "Scene":
        return _scene(take["reflectivity"], content, path)
    if kind == "PointScatterers":
        return PointScatterers(take["points"], take["reflectivity"], _get(content, "extent", path))
    if kind == "FitResult":
        return _decode_result(content, take, path)
    raise ValueError(
        f"load: `path` {path!r} holds a {kind!r}; this rift_jax ({_version()}) reads "
        "RadarData, Scene, PointScatterers and FitResult."
    )


def _radar_record(radar: Radar) -> dict:
    return dataclasses.asdict(radar)


def _radar(record: dict, path: str) -> Radar:
    fields = [f.name for f in dataclasses.fields(Radar)]
    missing = [name for name in fields if name not in record]
    if missing:
        raise ValueError(f"load: the radar in `path` {path!r} lacks {missing}.")
    return Radar(**{name: record[name] for name in fields})


def _grid_record(scene: Scene) -> dict:
    return {"extent": scene.extent, "granularity": scene.granularity}


def _scene(reflectivity: np.ndarray, record: dict, path: str) -> Scene:
    extent, granularity = _get(record, "extent", path), _get(record, "granularity", path)
    return Scene(jnp.asarray(reflectivity), extent, granularity)


def _geometry_arrays(radar: Radar, viewpoints: Viewpoints, antennas: bool) -> dict:
    """The viewpoints' angles and the radar's frequencies (and, for other tools, every
    view's antenna positions, (n_views, n_tx | n_rx, 3) metres): derived from the `Radar`
    and `Viewpoints`, which are what `load` rebuilds."""
    arrays = {
        "viewpoints/azimuth": np.asarray(viewpoints.azimuth),
        "viewpoints/polar": np.asarray(viewpoints.polar),
        "radar/frequencies": radar.frequencies,
    }
    if antennas:
        tx, rx = _antennas(radar, viewpoints)
        arrays |= {"antennas/tx": tx, "antennas/rx": rx}
    return arrays


def _antennas(radar: Radar, viewpoints: Viewpoints) -> tuple[np.ndarray, np.ndarray]:
    pairs = [
        antenna_positions(radar, a, p)
        for a, p in zip(viewpoints.azimuth, viewpoints.polar, strict=True)
    ]
    return np.stack([tx for tx, _ in pairs]), np.stack([rx for _, rx in pairs])


def _viewpoints(take: _Arrays, path: str) -> Viewpoints:
    return Viewpoints(take["viewpoints/azimuth"], take["viewpoints/polar"])


def _check_frequencies(radar: Radar, frequencies: np.ndarray, where: str) -> None:
    if frequencies.shape != (radar.n_frequencies,) or not np.allclose(
        frequencies, radar.frequencies, rtol=1e-12, atol=0
    ):
        raise ValueError(
            f"{where}: its `radar/frequencies` are not its radar's ({radar.n_frequencies} on "
            f"[{radar.f_min:g}, {radar.f_max:g}] Hz, endpoints included)."
        )


# --- FitResult --------------------------------------------------------------------------


def _encode_result(result: FitResult) -> tuple[dict, dict[str, np.ndarray]]:
    history = result.history
    arrays = {
        "scene/reflectivity": np.asarray(result.scene.reflectivity),
        "history/residual": np.asarray(history.residual),
        "history/seconds": np.asarray(history.seconds),
    }
    if history.loss is not None:
        arrays["history/loss"] = np.asarray(history.loss)
    arrays |= _geometry_arrays(result.radar, result.viewpoints, antennas=False)
    if result.support is not None:
        arrays["support"] = np.asarray(result.support)
    if result.trained is not None:
        arrays["trained/reflectivity"] = np.asarray(result.trained.reflectivity)
    stop = result.stopped
    content = {
        "scene": _grid_record(result.scene),
        "seconds": float(result.seconds),
        "method": result.method,
        "options": _encode_value(result.options, "options", arrays),
        "stopped": {"outcome": stop.outcome.value, "at": stop.at},
        "radar": _radar_record(result.radar),
        "stats": _encode_value(result.stats, "stats", arrays),
        "history_loss": history.loss is not None,
        "support": result.support is not None,
        "trained": None if result.trained is None else _grid_record(result.trained),
        "field": None if result.field is None else _encode_module(result.field, "field", arrays),
    }
    return content, arrays


def _decode_result(content: dict, take: _Arrays, path: str) -> FitResult:
    def get(key):
        return _get(content, key, path)

    loss = take["history/loss"] if get("history_loss") else None
    history = History(take["history/residual"], take["history/seconds"], loss)
    radar = _radar(get("radar"), path)
    _check_frequencies(radar, take["radar/frequencies"], f"load: `path` {path!r}")
    stopped = get("stopped")
    try:
        stop = Stop(Outcome(stopped["outcome"]), stopped["at"])
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"load: `path` {path!r} has an unknown `stopped` {stopped!r}.") from error
    trained = get("trained")
    return FitResult(
        scene=_scene(take["scene/reflectivity"], get("scene"), path),
        history=history,
        seconds=get("seconds"),
        method=get("method"),
        options=_decode_value(get("options"), take, path),
        stopped=stop,
        radar=radar,
        viewpoints=_viewpoints(take, path),
        stats=_decode_value(get("stats"), take, path),
        field=None if get("field") is None else _decode_module(get("field"), take, path),
        support=take["support"] if get("support") else None,
        trained=None if trained is None else _scene(take["trained/reflectivity"], trained, path),
    )


# RIFT's models: the sizes that rebuild each one's skeleton, so that the stored weights
# can be put back into it (as eqx.tree_deserialise_leaves does; here each weight is a named
# array, readable by other tools, and checked against the skeleton's shape and dtype).
_MODELS = {"RiftN": RiftN, "RiftS": RiftS, "HashGrid": HashGrid}


def _model_record(model) -> dict:
    if type(model) not in _MODELS.values():
        raise ValueError(
            f"save: a FitResult's field or options hold a {type(model).__name__} model; only "
            f"{', '.join(_MODELS)} are saved (their sizes rebuild the model to load the "
            "weights into)."
        )
    record = {
        "model": type(model).__name__,
        "width": int(model.output.in_features),
        "depth": len(model.hidden),
    }
    return record | _settings(model)


def _settings(model) -> dict:
    """What, beside width and depth, rebuilds ``model``'s skeleton."""
    if isinstance(model, RiftN):
        return {"negative_slope": model.negative_slope}
    if isinstance(model, RiftS):
        return {"omega_0": model.omega_0}
    levels, table_size, features = model.tables.shape
    return {
        "levels": levels,
        "features": features,
        "table_size": table_size,
        "coarsest": model.resolutions[0],
        "finest": model.resolutions[-1],
    }


def _weights(module) -> list[tuple[str, Any]]:
    """(name, array) for each array leaf, named by its path (``model.hidden[0].weight``)."""
    flat, _ = jax.tree_util.tree_flatten_with_path(eqx.filter(module, eqx.is_array))
    return [(jax.tree_util.keystr(key).lstrip("."), leaf) for key, leaf in flat]


def _encode_module(module, name: str, arrays: dict) -> dict:
    """A `Field` or an INR: the sizes that rebuild it, its weights into ``arrays``."""
    if isinstance(module, Field):
        record = {"kind": "Field", "extent": module.extent, **_model_record(module.model)}
    else:
        record = {"kind": "model", **_model_record(module)}
    for key, leaf in _weights(module):
        arrays[f"{name}/{key}"] = np.asarray(leaf)
    return record | {"arrays": name}


def _decode_module(record: dict, take: _Arrays, path: str):
    def get(key):
        return _get(record, key, path)

    cls = _MODELS.get(get("model"))
    if cls is None:
        raise ValueError(
            f"load: `path` {path!r} holds a model {get('model')!r}; rift_jax "
            f"rebuilds {sorted(_MODELS)}."
        )
    skeleton = cls(width=get("width"), depth=get("depth"), key=jax.random.key(0))
    settings = {name: get(name) for name in _settings(skeleton)}
    model = cls(width=get("width"), depth=get("depth"), key=jax.random.key(0), **settings)
    skeleton = Field(model, get("extent")) if get("kind") == "Field" else model
    weights, static = eqx.partition(skeleton, eqx.is_array)
    flat, treedef = jax.tree_util.tree_flatten_with_path(weights)
    leaves = []
    for key, leaf in flat:
        name = f"{get('arrays')}/{jax.tree_util.keystr(key).lstrip('.')}"
        stored = take[name]
        if stored.shape != leaf.shape or stored.dtype != leaf.dtype:
            raise ValueError(
                f"load: `path` {path!r} holds {name!r} as {stored.dtype} {stored.shape}, but the "
                f"{get('model')} it describes has {leaf.dtype} {leaf.shape} there."
            )
        leaves.append(jnp.asarray(stored))
    return eqx.combine(jax.tree_util.tree_unflatten(treedef, leaves), static)


# options and stats: JSON, with a tag for each value JSON has no word for
def _encode_value(value, name: str, arrays: dict):
    if value is None or isinstance(value, bool | str):
        return value
    if isinstance(value, np.generic):  # keeps its NumPy type: float32 stays float32
        return {"$numpy": value.dtype.name, "value": _encode_value(value.item(), name, arrays)}
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else {"$float": repr(value)}
    if isinstance(value, complex):
        return {
            "$complex": [_encode_value(part, name, arrays) for part in (value.real, value.imag)]
        }
    if isinstance(value, list):
        return [_encode_value(v, f"{name}/{i}", arrays) for i, v in enumerate(value)]
    if isinstance(value, tuple):
        return {"$tuple": [_encode_value(v, f"{name}/{i}", arrays) for i, v in enumerate(value)]}
    if isinstance(value, dict):
        if not all(isinstance(k, str) and "/" not in k and k[:1] != "$" for k in value):
            raise ValueError(
                f"save: the keys of `{name}` must be strings, without '/' and not starting "
                f"with '$' (the file's own tags), to be saved; got {list(value)!r}."
            )
        return {key: _encode_value(v, f"{name}/{key}", arrays) for key, v in value.items()}
    if isinstance(value, np.ndarray | jax.Array):
        array = np.asarray(value)
        if array.dtype.kind not in "biufc":  # HDF5 has no NumPy strings; objects need pickle
            raise ValueError(
                f"save: `{name}` is an array of {array.dtype}; files hold arrays of numbers "
                "or booleans."
            )
        arrays[name] = array
        return {"$array": name}
    if isinstance(value, Recipe):
        fields = {f.name: getattr(value, f.name) for f in dataclasses.fields(Recipe)}
        return {"$recipe": _encode_value(fields, name, arrays)}
    if isinstance(value, Field | RiftN | RiftS | HashGrid):
        return {"$module": _encode_module(value, name, arrays)}
    raise ValueError(
        f"save: `{name}` is a {type(value).__name__}, which a file cannot hold (only numbers, "
        "strings, lists, dicts, arrays, Recipes, Fields and RiftN / RiftS / HashGrid models); "
        "give the result other options with dataclasses.replace(result, options=...)."
    )


def _decode_value(value, take: _Arrays, path: str):
    if isinstance(value, list):
        return [_decode_value(v, take, path) for v in value]
    if not isinstance(value, dict):
        return value
    tags = [key for key in value if key.startswith("$")]
    if not tags:
        return {key: _decode_value(v, take, path) for key, v in value.items()}
    tag = tags[0]
    if tag == "$numpy":
        return np.dtype(value[tag]).type(_decode_value(value["value"], take, path))
    if tag == "$float":
        return float(value[tag])
    if tag == "$complex":
        return complex(*(_decode_value(part, take, path) for part in value[tag]))
    if tag == "$tuple":
        return tuple(_decode_value(v, take, path) for v in value[tag])
    if tag == "$array":
        return take[value[tag]]
    if tag == "$recipe":
        return Recipe(**_decode_value(value[tag], take, path))
    if tag == "$module":
        return _decode_module(value[tag], take, path)
    raise ValueError(
        f"load: `path` {path!r} holds an unknown value {tag!r}: written by a newer rift_jax?"
    )


# --- The RIFT authors' public NPZ layout ------------------------------------------------

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

    rift_jax's GRT takes a `Radar` and `Viewpoints`, not raw antenna positions. So the
    viewpoints are read from the array centres (``azimuth = atan2(y, x)``, ``polar =
    arccos(z / r)``, all at one distance r), the spacing from the first TX element, and
    the file's antennas must then sit where `rift_jax.antenna_positions` puts them (an L of
    TX and RX arms starting at the array centre), to within λ_min / 1000 (a phase error
    below 2π/1000). Data whose antennas do not, such as the authors' own simulations (a
    cross of centred TX and RX arrays), are refused with a ValueError naming ``tx_pos`` or
    ``rx_pos`` and saying how far off they are.

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
    distances = np.linalg.norm(centres, axis=1)
    distance = float(np.mean(distances))
    if np.max(np.abs(distances - distance)) > tolerance:
        raise ValueError(
            f"{where}: `viewpoint_positions` lie at distances {distances.min():.6g} to "
            f"{distances.max():.6g} m from the origin; rift_jax's Radar has one `distance`."
        )
    azimuth = np.arctan2(centres[:, 1], centres[:, 0])
    polar = np.arccos(np.clip(centres[:, 2] / distances, -1.0, 1.0))
    tx_pos = np.asarray(arrays["tx_pos"], np.float64)
    rx_pos = np.asarray(arrays["rx_pos"], np.float64)
    # rift_jax's first TX element sits half a spacing from the array centre
    spacing = 2 * float(np.linalg.norm(tx_pos[0, 0] - centres[0]))
    try:
        radar = Radar(n_adc, f_min, f_max, n_tx, n_rx, spacing, distance, near_field=True)
    except ValueError as error:
        raise ValueError(
            f"{where}: `metadata_json` or the positions give no valid Radar: {error}"
        ) from error
    viewpoints = Viewpoints(azimuth, polar)
    expected_tx, expected_rx = _antennas(radar, viewpoints)
    for key, found, expected in (("tx_pos", tx_pos, expected_tx), ("rx_pos", rx_pos, expected_rx)):
        off = np.linalg.norm(found - expected, axis=-1)
        if off.max() > tolerance:
            view, element = np.unravel_index(np.argmax(off), off.shape)
            raise ValueError(
                f"{where}: `{key}` does not follow rift_jax's antenna layout: element "
                f"{element} of view {view} lies {1e3 * off.max():.4g} mm from where "
                f"rift_jax.antenna_positions puts it (tolerance {1e6 * tolerance:.3g} µm, "
                "λ_min/1000). rift_jax's Radar is an L of TX and RX arms that start at the "
                "array centre (paper Eqs. 9-11), and its GRT takes a Radar and Viewpoints, "
                "not raw antenna positions: these data cannot be reconstructed here as they are."
            )

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


# --- PLY point clouds -------------------------------------------------------------------


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
    - `scene_or_result`: a `Scene`, a `FitResult` (its `scene`), or `PointScatterers`.
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
    _write_atomic(path, lambda f: f.write(_ply_bytes(points[keep], rho[keep], peak)))
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
        f"comment rift_jax {_version()}: voxels with |rho| >= threshold * max |rho|; "
        "x y z in metres, phase in radians",
        f"element vertex {len(points)}",
        *(f"property {_PLY_TYPES[_PLY_VERTEX[n].str]} {n}" for n in _PLY_VERTEX.names),
        "end_header",
    ]
    return ("\n".join(lines) + "\n").encode("ascii") + vertices.tobytes()
