"""Join the parts of one study, run as ``--part K/N`` in several processes or machines.

    python -m experiments.merge OUT PART [PART ...] [--replace REPLAY [REPLAY ...]]
    python -m experiments.NAME --scale SCALE --resume --out OUT

Each PART is the ``--out`` folder of one part (its results.json and reconstructions.npz):
the same experiment, scale, config and seed. OUT gets every run of them together; the
experiment, resumed on OUT, then does any run no part finished and writes its report from
all of them. Parts may share runs they both resumed from (a merged folder copied into each,
then ``--part K/N --resume``): a run in two parts is kept once if its reconstruction is the
same, bit for bit; measured twice, or parts of different studies, it stops the merge.

``--replace`` takes the ``--out`` folders of `experiments.replay` runs of that study (the
stress grid): each replayed run takes the place of the grid's run of the same scene and
label, so that the report judges the grid as it stands with today's code where the
replays ran (their comparison with the grid's own rows is dropped: the report judges
anew). A replay must replace a run of the parts, and no run is replaced twice.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from .runner import check_writable, write_json, write_npz

_STUDY_KEYS = ("experiment", "scale", "config", "seed")  # what makes two parts one study
_HISTORY_KEYS = ("resumed_with", "resumed_notes", "resumed_from_configs")  # a part's own
_REPLAY_CONFIG = ("replay_method", "replay_options")  # a replay's config beyond its grid's
_REPLAY_VERDICT = ("grid", "fista", "best", "best_method", "failed")  # its rows' comparison


def merge(out: str | Path, parts: list[str | Path], replacements: list[str | Path] = ()) -> dict:
    """Write the runs of every folder in ``parts`` into ``out`` (results.json and
    reconstructions.npz), which must not hold a study yet; returns the merged results
    dict. The first part's notes and versions head the file; ``parts`` records each part's
    folder, runs, the machines that ran them (``machines``: every `versions` record, its
    resumptions' and its own parts' too) and notes; ``wall_seconds`` is the sum over the
    runs (the work, not the time it took side by side; as `execute` counts it, a support
    estimate shared by several runs once). Each of ``replacements`` (replays of the
    study's runs) then puts its runs in place of theirs, recorded in ``parts`` with
    ``replaced``: how many."""
    if not parts:
        raise ValueError("merge: `parts` is empty; expected at least one --out folder.")
    out, parts = Path(out), [Path(p) for p in parts]
    replacements = [Path(p) for p in replacements]
    folders = [p.resolve() for p in (*parts, *replacements)]
    if out.resolve() in folders:
        raise ValueError(
            f"merge: `out` {out} is one of the parts or replacements; write the merge elsewhere."
        )
    if len(set(folders)) < len(folders):
        raise ValueError("merge: a folder is named twice in `parts` and `replacements`.")
    if (out / "results.json").exists():
        raise ValueError(f"merge: `out` {out} already holds a study; choose an empty folder.")
    merged: dict | None = None
    volumes: dict[str, np.ndarray] = {}
    kept: dict[str, dict] = {}  # each run's row, by its key in volumes and histories
    for part in parts:
        results, own = _read(part)
        if merged is None:
            # judged anew; the part's own history, kept in its entry; which part it was
            dropped = ("failures", "part", *_HISTORY_KEYS)
            merged = {k: v for k, v in results.items() if k not in dropped}
            merged |= {"rows": [], "histories": {}, "wall_seconds": 0.0, "parts": []}
        for key in _STUDY_KEYS:
            if results[key] != merged[key]:
                raise ValueError(
                    f"merge: part {part} is another study ({key} {results[key]!r}, the first "
                    f"part's {merged[key]!r})."
                )
        for row in results["rows"]:
            key = _key(part, row, results, own)
            if key in kept:
                if not _same_run(kept[key], row, volumes[key], own[key]):
                    raise ValueError(f"merge: {key} was measured in two parts (again in {part}).")
                continue  # a run both parts resumed from: kept once
            kept[key], volumes[key] = row, own[key]
            merged["rows"].append(row)
            merged["histories"][key] = results["histories"][key]
            merged["wall_seconds"] += _run_seconds(row)
        volumes |= {key: value for key, value in own.items() if key.startswith("truth/")}
        earlier = [m for p in results.get("parts", []) for m in p["machines"]]
        merged["parts"].append({
            "folder": str(part),
            "runs": len(results["rows"]),
            "machines": [results["versions"], *results.get("resumed_with", []), *earlier],
            "notes": [results.get("notes", {}), *results.get("resumed_notes", [])],
        })  # fmt: skip
    replaced: set[str] = set()
    for replay in replacements:
        results, own = _read(replay)
        # a replay's config is its grid's, with the scenes it replayed and its method
        config = {k: v for k, v in results["config"].items() if k not in _REPLAY_CONFIG}
        scenes = config.pop("scenes", ())
        grid = {k: v for k, v in merged["config"].items() if k != "scenes"}
        study = (results["experiment"], results["scale"], config, results["seed"])
        if study != ("replay", merged["scale"], grid, merged["seed"]) or not set(scenes) <= set(
            merged["config"].get("scenes", ())
        ):
            raise ValueError(
                f"merge: `replacements`: {replay} is no replay of the parts' study (an "
                f"experiments.replay of its scale {merged['scale']!r}, config and seed)."
            )
        for row in results["rows"]:
            key = _key(replay, row, results, own)
            if key not in kept or key in replaced:
                again = "a run already replaced" if key in replaced else "no run of the parts"
                raise ValueError(f"merge: `replacements`: {replay}'s {key} replaces {again}.")
            if (row["method"], row["options"]) != (kept[key]["method"], kept[key]["options"]):
                raise ValueError(
                    f"merge: `replacements`: {replay}'s {key} ran {row['method']} with "
                    f"{row['options']}, the parts' run {kept[key]['method']} with "
                    f"{kept[key]['options']}: only a replay at the study's own options takes "
                    "its place."
                )
            row = {k: v for k, v in row.items() if k not in _REPLAY_VERDICT}
            index = merged["rows"].index(kept[key])
            merged["wall_seconds"] += _run_seconds(row) - _run_seconds(kept[key])
            merged["rows"][index] = kept[key] = row
            volumes[key], merged["histories"][key] = own[key], results["histories"][key]
            replaced.add(key)
        merged["parts"].append({
            "folder": str(replay),
            "runs": len(results["rows"]),
            "replaced": len(results["rows"]),  # every run of a replay replaces one
            "machines": [results["versions"], *results.get("resumed_with", [])],
            "notes": [results.get("notes", {}), *results.get("resumed_notes", [])],
        })  # fmt: skip
    check_writable(out)
    write_npz(out / "reconstructions.npz", volumes)
    write_json(out / "results.json", merged)
    return merged


def _read(folder: Path) -> tuple[dict, dict[str, np.ndarray]]:
    """A study folder's results and reconstructions."""
    for name in ("results.json", "reconstructions.npz"):
        if not (folder / name).exists():
            raise ValueError(f"merge: {folder} has no {name}.")
    with np.load(folder / "reconstructions.npz") as saved:
        own = {key: saved[key] for key in saved.files}
    return json.loads((folder / "results.json").read_text()), own


def _key(folder: Path, row: dict, results: dict, own: dict) -> str:
    """A run's key in reconstructions and histories, which ``folder`` must hold."""
    key = f"{row['scene']}/{row['run']}"
    if key not in own or key not in results["histories"]:
        raise ValueError(f"merge: {folder} lacks the reconstruction or history of {key}.")
    return key


def _same_run(row: dict, other: dict, volume: np.ndarray, other_volume: np.ndarray) -> bool:
    """Whether two parts hold one measurement (copied from the folder both resumed from):
    the same reconstruction, bit for bit, and the same times, which a rerun never repeats."""
    times = all(row.get(k) == other.get(k) for k in ("wall_seconds", "fit_seconds"))
    return times and np.array_equal(volume, other_volume)


def _run_seconds(row: dict) -> float:
    """A run's share of a study's ``wall_seconds``: its own, less a support estimate it
    reused (``execute`` counts each estimate once)."""
    reused = row.get("support_seconds", 0.0) if row.get("support_reused") else 0.0
    return row["wall_seconds"] - reused


def cli(argv=None) -> dict:
    parser = argparse.ArgumentParser(
        prog="python -m experiments.merge",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("out", type=Path, help="the folder to write the joined study to")
    parser.add_argument("parts", type=Path, nargs="+", help="each part's --out folder")
    parser.add_argument(
        "--replace", type=Path, nargs="+", default=[], metavar="REPLAY",
        help="experiments.replay --out folders whose runs take the place of the parts' runs",
    )  # fmt: skip
    args = parser.parse_args(argv)
    try:
        merged = merge(args.out, args.parts, args.replace)
    except (ValueError, OSError) as error:  # OSError: `out` cannot be written
        parser.error(str(error))
    replaced = sum(part.get("replaced", 0) for part in merged["parts"])
    print(
        f"{len(merged['rows'])} runs from {len(args.parts)} part(s) in {args.out}/"
        + (f", {replaced} of them replayed ({len(args.replace)} replays)" if replaced else "")
        + "; resume the "
        f"{merged['experiment']} study there (--scale {merged['scale']} --resume --out "
        f"{args.out}) to finish it and write its report."
    )
    return merged


if __name__ == "__main__":
    cli()
