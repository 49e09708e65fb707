"""rift_jax's own files: `save` and `load`, NPZ or HDF5.

One record, two containers. Everything an object holds is a set of named arrays (``signal``,
``viewpoints/azimuth``, ...) and one JSON header: the format's name and version, the
rift_jax version that wrote it, the units, the object's kind and its non-array fields (the
`Radar`, the scale, ...); `codec` turns objects into that record and back. An NPZ file holds
the arrays under those names and the header as the string array ``rift_jax_header``; an
HDF5 file holds them as datasets (the names' "/" are groups, each dataset with a ``units``
attribute where it has one) and the header as the root attribute ``rift_jax_header``, with
``format``, ``format_version``, ``kind`` and ``rift_jax_version`` beside it for h5dump and
HDFView. Arrays are stored as they are (no compression, no casts), so a round trip is exact
bit for bit. Nothing is pickled.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np

from .._fit import FitResult
from .._scenes import Scene
from .._synthesis import PointScatterers, RadarData
from .._version import __version__
from .atomic import write_atomic
from .codec import decode_object, encode_object, needed_version

FORMAT = "rift_jax"
FORMAT_VERSION = 2
"""Bump when a file of this version would be read wrongly by the code that reads it; every
version this module reads stays readable. Version 2 holds radars of any layout, poses or
the radar equation's spreading, which a version-1 reader would have taken for the paper's
L on its sphere; files without them are still written as version 1 (`needed_version`)."""

UNITS = {"length": "m", "frequency": "Hz", "angle": "rad", "time": "s"}
_HEADER = "rift_jax_header"
_SUFFIXES = {".npz": "npz", ".h5": "hdf5", ".hdf5": "hdf5"}
# the `units` attribute of each HDF5 dataset that has one (by the name's last part)
_DATASET_UNITS = {
    "azimuth": "rad",
    "polar": "rad",
    "positions": "m",
    "frequencies": "Hz",
    "tx": "m",
    "rx": "m",
    "points": "m",
    "seconds": "s",
}


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
    kind, content, arrays = encode_object(obj)
    header = {
        "format": FORMAT,
        "format_version": needed_version(obj),
        "rift_jax_version": __version__,
        "kind": kind,
        "units": UNITS,
        "content": content,
    }
    text = json.dumps(header, allow_nan=False)  # strict JSON: other tools read it too
    if not path.parent.is_dir():
        raise ValueError(
            f"save: `path` must be in an existing folder; {str(path.parent)!r} is not."
        )
    write_atomic(path, lambda f: _WRITERS[container](f, text, header, arrays))
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
    return decode_object(header, arrays, str(path))


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
            f"{header.get('rift_jax_version')}); this rift_jax ({__version__}) reads versions 1 "
            f"to {FORMAT_VERSION}: update rift_jax to read it."
        )
    return header


_WRITERS = {"npz": _write_npz, "hdf5": _write_hdf5}
_READERS = {"npz": _read_npz, "hdf5": _read_hdf5}
