"""Objects to a file's record and back: a `RadarData`, `Scene`, `PointScatterers` or
`FitResult` as (kind, JSON content, named arrays), with RIFT's trained fields as their
model's sizes and named weight arrays, and a FitResult's options and stats as JSON with a
tag for each value JSON has no word for. `native` writes the record in a container."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._fit import FitResult
from .._geometry import Radar, Viewpoints, every_view_antennas
from .._models import MODELS, Field, HashGrid, RiftN, RiftS
from .._scenes import Scene
from .._solvers import History, Outcome, Recipe, Stop
from .._synthesis import PointScatterers, RadarData
from .._version import __version__


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


def needed_version(obj) -> int:
    """The oldest format version that reads ``obj`` right: 2 for a radar of another layout
    than the paper's L, the radar equation's spreading, or viewpoints given as poses (a
    version-1 reader would take them for the paper's L on its sphere), else 1."""
    radar, viewpoints = getattr(obj, "radar", None), getattr(obj, "viewpoints", None)
    if radar is not None and (not radar.is_paper_array or radar.spreading != "paper"):
        return 2
    return 2 if viewpoints is not None and viewpoints.positions is not None else 1


def encode_object(obj) -> tuple[str, dict, dict[str, np.ndarray]]:
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


def decode_object(header: dict, arrays: dict, path: str):
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
        f"load: `path` {path!r} holds a {kind!r}; this rift_jax ({__version__}) reads "
        "RadarData, Scene, PointScatterers and FitResult."
    )


def _radar_record(radar: Radar) -> dict:
    return dataclasses.asdict(radar)


# Radar fields added after the format's first version: files written before hold the
# paper's L (their defaults)
_LATER_RADAR_FIELDS = ("spreading", "tx_offsets", "rx_offsets", "frequency_list")


def _radar(record: dict, path: str) -> Radar:
    fields = [f.name for f in dataclasses.fields(Radar)]
    missing = [n for n in fields if n not in record and n not in _LATER_RADAR_FIELDS]
    if missing:
        raise ValueError(f"load: the radar in `path` {path!r} lacks {missing}.")
    return Radar(**{name: record[name] for name in fields if name in record})


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
    if viewpoints.positions is not None:  # poses given, not derived from the angles
        arrays |= {
            "viewpoints/positions": np.asarray(viewpoints.positions),
            "viewpoints/orientations": np.asarray(viewpoints.orientations),
        }
    if antennas:
        tx, rx = every_view_antennas(radar, viewpoints)
        arrays |= {"antennas/tx": tx, "antennas/rx": rx}
    return arrays


def _viewpoints(take: _Arrays, path: str) -> Viewpoints:
    angles = take["viewpoints/azimuth"], take["viewpoints/polar"]
    if "viewpoints/positions" not in take.arrays:
        return Viewpoints(*angles)
    return Viewpoints(*angles, take["viewpoints/positions"], take["viewpoints/orientations"])


def _check_frequencies(radar: Radar, frequencies: np.ndarray, where: str) -> None:
    if frequencies.shape != (radar.n_frequencies,) or not np.allclose(
        frequencies, radar.frequencies, rtol=1e-12, atol=0
    ):
        raise ValueError(
            f"{where}: its `radar/frequencies` are not its radar's ({radar.n_frequencies} on "
            f"[{radar.f_min:g}, {radar.f_max:g}] Hz)."
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
    if result.points is not None:  # method="points": the scatterers themselves
        arrays["points/points"] = np.asarray(result.points.points)
        arrays["points/reflectivity"] = np.asarray(result.points.reflectivity)
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
        "points": None if result.points is None else {"extent": result.points.extent},
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
        points=_points(content.get("points"), take, path),
    )


def _points(record: dict | None, take: _Arrays, path: str) -> PointScatterers | None:
    """A result's point scatterers (files written before method="points" hold none)."""
    if record is None:
        return None
    extent = _get(record, "extent", path)
    return PointScatterers(take["points/points"], take["points/reflectivity"], extent)


# RIFT's models: the sizes that rebuild each one's skeleton, so that the stored weights
# can be put back into it (as eqx.tree_deserialise_leaves does; here each weight is a named
# array, readable by other tools, and checked against the skeleton's shape and dtype).
_MODELS = {cls.__name__: cls for cls in MODELS.values()}  # by class name, as files hold them


def _model_record(model) -> dict:
    if type(model) not in _MODELS.values() or type(model) not in _SETTINGS:
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
    return _SETTINGS[type(model)](model)


def _hash_grid_settings(model: HashGrid) -> dict:
    levels, table_size, features = model.tables.shape
    return {
        "levels": levels,
        "features": features,
        "table_size": table_size,
        "coarsest": model.resolutions[0],
        "finest": model.resolutions[-1],
    }


# each of _models.MODELS, by class (a test holds the two to the same models)
_SETTINGS = {
    RiftN: lambda model: {"negative_slope": model.negative_slope},
    RiftS: lambda model: {"omega_0": model.omega_0},
    HashGrid: _hash_grid_settings,
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
    if isinstance(value, (Field, *_MODELS.values())):
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
        fields = _decode_value(value[tag], take, path)
        # a file from before `epoch_views` existed: its run made one pass per epoch
        fields.setdefault("epoch_views", None)
        return Recipe(**fields)
    if tag == "$module":
        return _decode_module(value[tag], take, path)
    raise ValueError(
        f"load: `path` {path!r} holds an unknown value {tag!r}: written by a newer rift_jax?"
    )
